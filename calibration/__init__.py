"""weldcell calibration package."""
