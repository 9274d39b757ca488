"""CadQuery CAM plugin: calibration features, parts, toolpaths. Imports cadquery lazily."""
