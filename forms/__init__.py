"""UFL strain energies and kinematics: pure functions of F and parameters.

Materials are frozen dataclasses with ``strain_energy(F, **fields)`` returning
a UFL scalar; stresses and tangents come from ``ufl.diff`` / ``ufl.derivative``.
This package imports nothing of artifem; ``artifem.material_response`` evaluates
the materials at homogeneous deformations (``point_response``,
``stress_stretch_curves``).
"""

from .combined import CombinedMaterial, field_names
from .fiber_activation import BlemkerFiber, force_length, passive_force_length
from .kinematics import (
    fiber_stretch,
    green_lagrange,
    invariants,
    isochoric_invariants,
    jacobian,
    right_cauchy_green,
    small_strain,
)
from .linear_elastic import LinearElastic
from .mooney_rivlin import MooneyRivlin
from .neo_hookean import NeoHookean
from .saint_venant_kirchhoff import StVenantKirchhoff

__all__ = [
    "BlemkerFiber",
    "CombinedMaterial",
    "LinearElastic",
    "MooneyRivlin",
    "NeoHookean",
    "StVenantKirchhoff",
    "fiber_stretch",
    "field_names",
    "force_length",
    "green_lagrange",
    "invariants",
    "isochoric_invariants",
    "jacobian",
    "passive_force_length",
    "right_cauchy_green",
    "small_strain",
]
