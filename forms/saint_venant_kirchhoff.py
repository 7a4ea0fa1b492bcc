"""Saint Venant-Kirchhoff material."""

from dataclasses import dataclass

import ufl

from .kinematics import green_lagrange
from .parameters import check_lame, lame_from_young_poisson


@dataclass(frozen=True)
class StVenantKirchhoff:
    """St Venant-Kirchhoff energy W = lmbda/2 tr(E)^2 + mu tr(E^2), E = (F^T F - I)/2.

    S = lmbda tr(E) I + 2 mu E, P = F S. Rotation invariant, but softens and
    loses stability in strong compression.
    """

    mu: float
    lmbda: float

    def __post_init__(self):
        check_lame(type(self).__name__, self.mu, self.lmbda)
        object.__setattr__(self, "mu", float(self.mu))
        object.__setattr__(self, "lmbda", float(self.lmbda))

    @classmethod
    def from_young_poisson(cls, E, nu):
        """Build from Young's modulus E and Poisson ratio nu."""
        return cls(*lame_from_young_poisson(cls.__name__, E, nu))

    def strain_energy(self, F):
        """W(F) = lmbda/2 tr(E)^2 + mu tr(E^2)."""
        E = green_lagrange(F)
        return 0.5 * self.lmbda * ufl.tr(E) ** 2 + self.mu * ufl.tr(E * E)
