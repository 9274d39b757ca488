"""mtcomp.geometric."""
