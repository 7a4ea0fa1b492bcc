"""Reduced-coordinate models (Lloyd et al. 2019, section 2): bases, integration points, reduced bodies."""
