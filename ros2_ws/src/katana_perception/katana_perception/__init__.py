"""Perception for the Katana blocks world (Ngo et al. 2013, sections 2.1-2.3)."""
