"""Meshes embedded in FEM bodies and embedded (voxel) FEM (Lloyd et al. 2019, section 4)."""

from artifem.errors import OutsideMeshError
from artifem.embedding.embedded_mesh import EmbeddedMesh, PointLocation, locate_points

__all__ = ["EmbeddedMesh", "OutsideMeshError", "PointLocation", "locate_points"]
