"""Shipped machine presets (TOML); see docs/machine-format.md."""
