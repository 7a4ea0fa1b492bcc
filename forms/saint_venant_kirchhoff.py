"""Saint Venant-Kirchhoff material."""

from dataclasses import dataclass

import ufl

from .kinematics import green_lagrange
from .parameters import LameParameters


@dataclass(frozen=True)
class StVenantKirchhoff(LameParameters):
    """St Venant-Kirchhoff energy W = lmbda/2 tr(E)^2 + mu tr(E^2), E = (F^T F - I)/2.

    S = lmbda tr(E) I + 2 mu E, P = F S. Rotation invariant, but softens and
    loses stability in strong compression.
    """

    def strain_energy(self, F):
        """W(F) = lmbda/2 tr(E)^2 + mu tr(E^2)."""
        E = green_lagrange(F)
        return 0.5 * self.lmbda * ufl.tr(E) ** 2 + self.mu * ufl.tr(E * E)
