"""weldcell sim_fakes package."""
