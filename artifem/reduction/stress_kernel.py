"""First Piola-Kirchhoff stress and its tangent at many homogeneous deformations at once.

A reduced body needs P = dpsi/dF and A = dP/dF of the *same* UFL energy
density as the full body, but only at its m integration points, each with its
own F. :class:`StressKernel` compiles

    P_iJ = dpsi/dF_iJ (F; a0),    A_iJkL = d^2 psi / dF_iJ dF_kL

(with psi itself) once with FFCx into a ``dolfinx.fem.Expression`` on a COMM_SELF mesh of N
disjoint reference tetrahedra, one per point. On tetrahedron p the
displacement u(X) = (F_p - I) X is linear (P1 interpolation is exact), so
grad u = F_p - I and one ``Expression.eval`` over the N cells returns every
point's (psi_p, P_p, A_p). The coefficients are packed here by one gather
(dolfinx's generic packing costs more than the kernel at these sizes) and
the compiled kernel is called through ``dolfinx.cpp.fem.tabulate_expression``. Fiber directions a0_p are a DG0 field; constants
(excitations) are read from the full body's own ``fem.Constant`` objects at
every evaluation.
"""

from __future__ import annotations

from typing import Callable

import basix.ufl
import numpy as np
import ufl
from dolfinx import cpp, fem, mesh as dmesh
from mpi4py import MPI
from ufl.algorithms.analysis import extract_constants

__all__ = ["StressKernel"]

_REFERENCE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def _tetrahedra(n: int) -> dmesh.Mesh:
    """n disjoint copies of the reference tetrahedron (the same place, no shared vertices)."""
    element = basix.ufl.element("Lagrange", "tetrahedron", 1, shape=(3,))
    cells = np.arange(4 * n, dtype=np.int64).reshape(n, 4)
    return dmesh.create_mesh(MPI.COMM_SELF, cells, element, np.tile(_REFERENCE, (n, 1)))


class StressKernel:
    """(psi, P, A) of ``density(F, a0)`` at n points, evaluated in one compiled call.

    Args:
        density: ``density(F, a0) -> UFL scalar`` (``a0`` is None when
            ``directed`` is False), e.g. an ``EnergyTerm.density`` of a FemBody.
        n: number of points (fixed; the kernel is compiled for any n).
        directed: whether the density takes a per-point direction a0.
        out: optional C-contiguous (n, 1, 91) buffer the results are written to
            (e.g. rows of one buffer shared by several kernels).
    """

    def __init__(self, density: Callable, n: int, *, directed: bool,
                 out: np.ndarray | None = None):
        if n < 1:
            raise ValueError(f"StressKernel needs at least one point, got {n}")
        self.n = int(n)
        self._mesh = _tetrahedra(self.n)
        V = fem.functionspace(self._mesh, ("Lagrange", 1, (3,)))
        u = fem.Function(V)
        a0 = None
        if directed:
            a0 = fem.Function(fem.functionspace(self._mesh, ("DG", 0, (3,))))
        # A Variable with a fixed Label: ufl.variable's global label counter would
        # enter FFCx's signature and defeat the JIT cache across kernels and runs.
        F = ufl.classes.Variable(ufl.Identity(3) + ufl.grad(u), ufl.classes.Label(0))
        psi = density(F, a0)
        # The density's constants (excitations) belong to the full body's mesh; an
        # Expression must live on one mesh, so each gets a local twin whose value
        # is copied from the original before every evaluation.
        self._twins = [(c, fem.Constant(self._mesh, np.asarray(c.value).copy()))
                       for c in extract_constants(psi)]
        psi = ufl.replace(psi, {c: twin for c, twin in self._twins})
        P = ufl.diff(psi, F)
        A = ufl.diff(P, F)
        packed = ufl.as_vector([psi] + [P[i, J] for i in range(3) for J in range(3)]
                               + [A[i, J, k, L] for i in range(3) for J in range(3)
                                  for k in range(3) for L in range(3)])
        self._expression = fem.Expression(packed, np.array([[0.25, 0.25, 0.25]]),
                                          comm=MPI.COMM_SELF)
        self._cells = np.arange(self.n, dtype=np.int32)
        if out is None:
            out = np.zeros((self.n, 1, 91))
        if out.shape != (self.n, 1, 91) or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous ({self.n}, 1, 91) array")
        self._values = out
        # The kernel's packed coefficient array is filled here directly, by a gather
        # from [u dofs, a0 dofs]: tag every source value with its position once and
        # see where dolfinx's own packing puts it.
        n_u = u.x.array.size
        u.x.array[:] = np.arange(n_u)
        if a0 is not None:
            a0.x.array[:] = n_u + np.arange(a0.x.array.size)
        expr = self._expression._cpp_object
        tags = cpp.fem.pack_coefficients(expr, self._mesh._cpp_object, self._cells)
        self._gather = np.rint(tags).astype(np.int64)
        self._source = np.zeros(n_u + (a0.x.array.size if a0 is not None else 0))
        # u at a dof is (F_p - I) X_dof, with p the dof's cell and X_dof its vertex.
        dofs = V.dofmap.list.reshape(-1)
        self._u_dofs = dofs
        self._dof_cell = np.repeat(np.arange(self.n), 4)
        self._dof_x = V.tabulate_dof_coordinates()[dofs]
        self._a0_rows = a0.function_space.dofmap.list[:, 0] if a0 is not None else None
        self._n_u = n_u

    def set_directions(self, a0: np.ndarray) -> None:
        """Per-point fiber directions, shape (n, 3)."""
        a0 = np.asarray(a0, dtype=float)
        if self._a0_rows is None or a0.shape != (self.n, 3):
            raise ValueError(f"directions must have shape ({self.n}, 3) for a directed kernel")
        self._source[self._n_u:].reshape(-1, 3)[self._a0_rows] = a0

    def __call__(self, grad_u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """psi (n,), P (n, 9), A (n, 9, 9) (row-major iJ, kL) at F_p = I + grad_u[p].

        grad_u has shape (n, 3, 3). The results are views of the kernel's output
        buffer, valid until the next call.
        """
        for original, twin in self._twins:
            twin.value = original.value
        H = grad_u[self._dof_cell]                              # (4n, 3, 3)
        self._source[:self._n_u].reshape(-1, 3)[self._u_dofs] = \
            np.einsum("dij,dj->di", H, self._dof_x)
        expr = self._expression._cpp_object
        cpp.fem.tabulate_expression(self._values, expr, cpp.fem.pack_constants(expr),
                                    self._source[self._gather], self._mesh._cpp_object,
                                    self._cells)
        out = self._values[:, 0]
        return out[:, 0], out[:, 1:10], out[:, 10:].reshape(self.n, 9, 9)
