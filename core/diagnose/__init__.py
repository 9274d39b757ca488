"""mtcomp.diagnose."""
