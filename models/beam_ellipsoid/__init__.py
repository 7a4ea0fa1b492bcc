"""An FEM beam carrying a rigid ellipsoid at its end: the seed paper's Fig. 11."""
