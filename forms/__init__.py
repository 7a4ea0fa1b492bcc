"""UFL strain energies and kinematics: pure functions of F and parameters.

Materials are frozen dataclasses with ``strain_energy(F, **fields)`` returning
a UFL scalar; stresses and tangents come from ``ufl.diff`` / ``ufl.derivative``.
``point_response`` and ``stress_stretch_curves`` evaluate them at homogeneous
deformations (compiled lazily through artifem.pointwise).
"""

from .combined import CombinedMaterial, field_names
from .fiber_activation import BlemkerFiber, force_length, passive_force_length
from .kinematics import (fiber_stretch, green_lagrange, invariants, isochoric_invariants, jacobian,
                         right_cauchy_green, small_strain)
from .linear_elastic import LinearElastic
from .mooney_rivlin import MooneyRivlin
from .neo_hookean import NeoHookean
from .response import plot_stress_stretch, point_response, stress_stretch_curves
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
    "plot_stress_stretch",
    "point_response",
    "right_cauchy_green",
    "small_strain",
    "stress_stretch_curves",
]
