"""Meshes embedded in FEM bodies and embedded (voxel) FEM (Lloyd et al. 2019, section 4)."""
