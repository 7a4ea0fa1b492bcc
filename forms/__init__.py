"""UFL strain energies and kinematics: pure functions of F and parameters."""
