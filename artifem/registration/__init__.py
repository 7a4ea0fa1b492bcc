"""Registration of models to target data: the rigid and affine tools (Kabsch's rotation,
the affine least-squares fit, closest points on a triangle surface, trimmed
point-to-surface ICP) in :mod:`.rigid`, and the
forces that pull a model surface (on any bodies) toward a target in :mod:`.forces`, and
the loop of static solves under a rising weight in :mod:`.register`."""

from artifem.registration.forces import RegistrationForces
from artifem.registration.register import RegistrationResult, register
from artifem.registration.rigid import RigidFit, TriangleSurface, affine_fit, icp, kabsch

__all__ = [
    "RegistrationForces",
    "RegistrationResult",
    "RigidFit",
    "TriangleSurface",
    "affine_fit",
    "icp",
    "kabsch",
    "register",
]
