"""Compressible neo-Hookean material."""

from dataclasses import dataclass

import ufl

from .kinematics import invariants, jacobian
from .parameters import check_lame, lame_from_young_poisson


@dataclass(frozen=True)
class NeoHookean:
    """Compressible neo-Hookean energy W = mu/2 (I1 - 3) - mu ln J + lmbda/2 (ln J)^2.

    P = mu (F - F^-T) + lmbda ln(J) F^-T; linearizes to Hooke's law with Lame mu, lmbda.
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
        """W(F) = mu/2 (I1 - 3) - mu ln J + lmbda/2 (ln J)^2."""
        I1, _, _ = invariants(F)
        lnJ = ufl.ln(jacobian(F))
        return 0.5 * self.mu * (I1 - 3.0) - self.mu * lnJ + 0.5 * self.lmbda * lnJ**2
