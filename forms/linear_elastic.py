"""Small-strain (linear) isotropic elasticity written as an energy of F."""

from dataclasses import dataclass

import ufl

from .kinematics import small_strain
from .parameters import LameParameters


@dataclass(frozen=True)
class LinearElastic(LameParameters):
    """Hooke's law W = lmbda/2 tr(eps)^2 + mu tr(eps^2), eps = sym(F) - I = sym(grad u).

    P = dW/dF = sigma(eps) = lmbda tr(eps) I + 2 mu eps, so the stress is linear in
    the displacement gradient and the tangent is constant. NOT rotation invariant:
    a rigid rotation F = R gives eps = sym(R) - I != 0 and a spurious stress, so it
    is valid only for small rotations (use StVenantKirchhoff or NeoHookean otherwise).
    """

    def strain_energy(self, F):
        """W(F) = lmbda/2 tr(eps)^2 + mu tr(eps^2)."""
        eps = small_strain(F)
        return 0.5 * self.lmbda * ufl.tr(eps) ** 2 + self.mu * ufl.tr(eps * eps)
