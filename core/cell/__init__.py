"""mtcomp.cell."""
