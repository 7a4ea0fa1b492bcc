"""Rigid bodies, joints, point-to-point springs and muscles (Lloyd et al. 2019, section 3)."""
