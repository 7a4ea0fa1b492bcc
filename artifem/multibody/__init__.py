"""Rigid bodies, joints, springs and muscles, attachments, and the coupled FEM-rigid step
(Lloyd et al. 2019, section 3)."""
