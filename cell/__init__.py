"""weldcell cell package."""
