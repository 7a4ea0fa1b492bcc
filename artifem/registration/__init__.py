"""Registration of models to target data: the rigid tools (Kabsch's rotation, closest
points on a triangle surface, trimmed point-to-surface ICP) in :mod:`.rigid`."""

from artifem.registration.rigid import RigidFit, TriangleSurface, icp, kabsch

__all__ = ["RigidFit", "TriangleSurface", "icp", "kabsch"]
