"""Stress of an FEM body's bulk material at its current displacement.

With F = I + grad u, the first Piola-Kirchhoff stress P = d psi / dF of the strain energy
psi (UFL derives it: the material's own energy, no hand-written stress), the Cauchy stress
and its von Mises value

    sigma = P F^T / J,   s = sigma - tr(sigma) I / 3,   sigma_vM = sqrt(3/2 s : s),

evaluated per cell (DG0, at the cell's midpoint) for rendering and reports.
"""

from __future__ import annotations

from collections.abc import Callable

import ufl
from dolfinx import fem

import artifem.jit  # noqa: F401  (waits for another process's compile of a form)

__all__ = ["von_mises"]


def von_mises(body, extra_energy: Callable | None = None) -> fem.Function:
    """The DG0 von Mises stress of ``body``'s bulk material (module docstring), plus
    ``extra_energy(F)`` when given (e.g. a volumetric penalty the body's scene adds)."""
    F = ufl.variable(ufl.Identity(3) + ufl.grad(body.u))
    psi = body.material.strain_energy(F)
    if extra_energy is not None:
        psi = psi + extra_energy(F)
    sigma = ufl.diff(psi, F) * F.T / ufl.det(F)
    dev = sigma - ufl.tr(sigma) / 3 * ufl.Identity(3)
    Q = fem.functionspace(body.mesh, ("DG", 0))
    out = fem.Function(Q, name="von_mises")
    out.interpolate(
        fem.Expression(ufl.sqrt(1.5 * ufl.inner(dev, dev)), Q.element.interpolation_points)
    )
    return out
