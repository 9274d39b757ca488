"""Tool and workpiece setting errors: calibration procedures and estimators."""
