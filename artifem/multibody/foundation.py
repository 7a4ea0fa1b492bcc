"""An elastic-foundation (compliance) law for contact: a thin elastic layer on the surfaces.

ArtiSynth's LinearElasticContact (cartilage between bones): a layer of thickness t, Young's
modulus E and Poisson's ratio nu, confined sideways (a thin layer between stiff bodies
cannot bulge), presses back with the pressure

    p = K d / t,      K = E (1 - nu) / ((1 + nu) (1 - 2 nu))  (the confined, oedometric
                                                              modulus),

d >= 0 the penetration. A contact row that stands for the area A_k of its point's surface
is a spring of stiffness K A_k / t that pushes only in compression: the row's compliance
(:mod:`~artifem.multibody.constraint_rows`) is

    C_k = t / (K A_k)     (m/N),

its force f_k = -phi_end / C_k >= 0, phi_end the signed distance at the end of the step.
A_k is the point's share of its own surface facing the contact, projected on the row's
direction e_k (the point sets' ``facing_areas``, :func:`artifem.contact_points.facing_areas`): each
facet whose outward vector area a_f faces the contact (a_f . e_k < 0) gives
-(a_f . e_k) / (its corners) to each corner. A flat face lying on a plane gives its area
back exactly, split among its vertices. Rows with no facing area (and MeshContact's
edge-across-edge rows) stay hard (C = 0).

With a foundation the penetration is the law's: the contact's step check allows
penetration up to max(tolerance, t); deeper than the layer fails the step.
"""

from __future__ import annotations

from dataclasses import dataclass
from numbers import Real

import numpy as np

from artifem.errors import InputError

__all__ = ["ElasticFoundation"]


@dataclass(frozen=True)
class ElasticFoundation:
    """A linear elastic layer (module docstring): ``young`` E (Pa, > 0), ``poisson`` nu in
    (-1, 0.5), ``thickness`` t (m, > 0). The contact that takes it
    (``PlaneContact(..., foundation=)``, ``MeshContact(..., foundation=)``) checks it."""

    young: float
    poisson: float
    thickness: float

    def checked(self, what: str) -> ElasticFoundation:
        """Itself, or an InputError naming ``what`` (the contact) for a bad parameter."""
        E, nu, t = self.young, self.poisson, self.thickness
        if not (isinstance(E, Real) and np.isfinite(E) and E > 0):
            raise InputError(
                f"{what}: the foundation's Young's modulus must be finite and > 0, got {E!r}"
            )
        if not (isinstance(nu, Real) and -1.0 < nu < 0.5):
            raise InputError(
                f"{what}: the foundation's Poisson's ratio must be in (-1, 0.5), got {nu!r}"
            )
        if not (isinstance(t, Real) and np.isfinite(t) and t > 0):
            raise InputError(
                f"{what}: the foundation's thickness must be finite and > 0, got {t!r}"
            )
        return self

    @property
    def modulus(self) -> float:
        """K = E (1 - nu) / ((1 + nu) (1 - 2 nu)), the confined (oedometric) modulus (Pa)."""
        nu = self.poisson
        return self.young * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu))

    def compliance(self, areas: np.ndarray) -> np.ndarray:
        """C_k = t / (K A_k) of rows standing for the areas A_k (m^2); 0 (hard) where
        A_k = 0."""
        A = np.asarray(areas, dtype=float)
        return np.where(A > 0, self.thickness / (self.modulus * np.where(A > 0, A, 1.0)), 0.0)
