"""FMUs of the compensation core and a machine model (FMI 2.0/3.0)."""
