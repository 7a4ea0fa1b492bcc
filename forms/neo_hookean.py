"""Compressible neo-Hookean material."""

from dataclasses import dataclass

import ufl

from .kinematics import invariants, jacobian
from .parameters import LameParameters


@dataclass(frozen=True)
class NeoHookean(LameParameters):
    """Compressible neo-Hookean energy W = mu/2 (I1 - 3) - mu ln J + lmbda/2 (ln J)^2.

    P = mu (F - F^-T) + lmbda ln(J) F^-T; linearizes to Hooke's law with Lame mu, lmbda.
    """

    def strain_energy(self, F):
        """W(F) = mu/2 (I1 - 3) - mu ln J + lmbda/2 (ln J)^2."""
        I1, _, _ = invariants(F)
        lnJ = ufl.ln(jacobian(F))
        return 0.5 * self.mu * (I1 - 3.0) - self.mu * lnJ + 0.5 * self.lmbda * lnJ**2
