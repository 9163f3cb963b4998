"""weldcell perception package."""
