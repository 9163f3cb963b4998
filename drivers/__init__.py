"""weldcell drivers package."""
