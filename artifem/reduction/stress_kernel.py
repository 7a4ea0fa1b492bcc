"""First Piola-Kirchhoff stress and its tangent at many homogeneous deformations at once.

A reduced body needs psi, P = dpsi/dF and A = dP/dF of the *same* UFL energy
densities as the full body, but only at its m integration points, each with
its own F. :class:`StressKernel` compiles, for one density,

    psi(F; a0),   P_iJ = dpsi/dF_iJ,   A_iJkL = d^2 psi / dF_iJ dF_kL

once with FFCx into a ``dolfinx.fem.Expression`` on a COMM_SELF mesh of n
disjoint reference tetrahedra, one per point. On tetrahedron p the
displacement u(X) = (F_p - I) X is linear (P1 interpolation is exact), so
grad u = F_p - I, and one kernel call over the n cells returns every point's
values. Fiber directions a0_p are a DG0 field; constants (excitations) are
read from the full body's own ``fem.Constant`` objects at every call.

:class:`PointStresses` sums several densities (the energy terms of a body),
each active at its own subset of the m points. Its coefficients are packed
here, for all terms in one vectorized pass, into the arrays the compiled
kernels read (dolfinx's generic packing, per call, costs more than the
kernels at these sizes), and the kernels are called through
``dolfinx.cpp.fem.tabulate_expression``.
"""

from __future__ import annotations

from typing import Callable

import basix.ufl
import numpy as np
import ufl
from dolfinx import cpp, fem, mesh as dmesh
from mpi4py import MPI
from scipy import sparse
from ufl.algorithms.analysis import extract_constants

from artifem.errors import InputError

__all__ = ["StressKernel", "PointStresses"]

_REFERENCE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
#: psi, P (9), A (81) per point.
VALUES = 91


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
        n: number of points.
        directed: whether the density takes a per-point direction a0.

    After construction the packed coefficient layout is known: row p of
    ``coefficients`` (n, columns) is what the kernel reads for point p;
    ``u_columns``, ``u_component`` and ``u_position`` say which columns hold
    u and that column k holds component ``u_component[p, k]`` of u at the
    reference position ``u_position[p, k]``; ``a0_columns`` hold a0.
    """

    def __init__(self, density: Callable, n: int, *, directed: bool):
        if n < 1:
            raise InputError(f"StressKernel needs at least one point, got {n}")
        self.n = int(n)
        self._mesh = _tetrahedra(self.n)
        V = fem.functionspace(self._mesh, ("Lagrange", 1, (3,)))
        u = fem.Function(V)
        a0 = fem.Function(fem.functionspace(self._mesh, ("DG", 0, (3,)))) if directed else None
        # A Variable with a fixed Label: ufl.variable's global label counter would
        # enter FFCx's signature and defeat the JIT cache across kernels and runs.
        F = ufl.classes.Variable(ufl.Identity(3) + ufl.grad(u), ufl.classes.Label(0))
        psi = density(F, a0)
        # The density's constants (excitations) belong to the full body's mesh; an
        # Expression lives on one mesh, so each gets a local twin.
        originals = extract_constants(psi)
        twins = [fem.Constant(self._mesh, np.asarray(c.value, dtype=float).copy())
                 for c in originals]
        psi = ufl.replace(psi, dict(zip(originals, twins)))
        P = ufl.diff(psi, F)
        A = ufl.diff(P, F)
        packed = ufl.as_vector([psi] + [P[i, J] for i in range(3) for J in range(3)]
                               + [A[i, J, k, L] for i in range(3) for J in range(3)
                                  for k in range(3) for L in range(3)])
        self._expression = fem.Expression(packed, np.array([[0.25, 0.25, 0.25]]),
                                          comm=MPI.COMM_SELF)
        self._cells = np.arange(self.n, dtype=np.int32)
        expr = self._expression._cpp_object
        # Where the packing puts each value: tag every source value with its index.
        for k, twin in enumerate(twins):
            twin.value = np.full(np.shape(twin.value), float(k))
        # Views of the originals' values (a Constant's value array is updated in place).
        self._constant_values = [c.value for c in originals]
        self._constant_order = np.rint(cpp.fem.pack_constants(expr)).astype(np.int64)
        n_u = u.x.array.size
        u.x.array[:] = np.arange(n_u)
        if a0 is not None:
            a0.x.array[:] = n_u + np.arange(a0.x.array.size)
        tags = np.rint(cpp.fem.pack_coefficients(expr, self._mesh._cpp_object, self._cells))
        tags = tags.astype(np.int64).reshape(self.n, -1)
        is_u = tags[0] < n_u
        self.u_columns = np.flatnonzero(is_u)
        self.a0_columns = np.flatnonzero(~is_u)
        dof_x = V.tabulate_dof_coordinates()
        self.u_component = tags[:, is_u] % 3
        self.u_position = dof_x[tags[:, is_u] // 3]                 # (n, 12, 3)
        self._a0_tags = tags[:, ~is_u] - n_u
        self.coefficients = np.zeros(tags.shape)
        self.values = np.zeros((self.n, 1, VALUES))

    def set_directions(self, a0: np.ndarray) -> None:
        """Per-point fiber directions, shape (n, 3)."""
        a0 = np.asarray(a0, dtype=float)
        if self.a0_columns.size == 0 or a0.shape != (self.n, 3):
            raise InputError(f"directions must have shape ({self.n}, 3) for a directed kernel")
        # Column k of row p holds component (tag % 3) of the direction of point p.
        self.coefficients[:, self.a0_columns] = a0[np.arange(self.n)[:, None],
                                                   self._a0_tags % 3]

    def set_grad_u(self, grad_u: np.ndarray) -> None:
        """Pack u(X) = grad_u[p] X for every point p, grad_u of shape (n, 3, 3)."""
        rows = np.arange(self.n)[:, None]
        H = grad_u[rows, self.u_component]                          # (n, 12, 3)
        self.coefficients[:, self.u_columns] = np.einsum("pkj,pkj->pk", H, self.u_position)

    def tabulate(self) -> None:
        """Run the compiled kernel on the packed coefficients into ``values``."""
        constants = np.concatenate([np.ravel(v) for v in self._constant_values]) \
            if self._constant_values else np.zeros(0)
        cpp.fem.tabulate_expression(self.values, self._expression._cpp_object,
                                    constants[self._constant_order], self.coefficients,
                                    self._mesh._cpp_object, self._cells)

    def __call__(self, grad_u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """psi (n,), P (n, 9), A (n, 9, 9) (row-major iJ, kL) at F_p = I + grad_u[p].

        The results are views of the kernel's buffer, valid until the next call.
        """
        self.set_grad_u(grad_u)
        self.tabulate()
        out = self.values[:, 0]
        return out[:, 0], out[:, 1:10], out[:, 10:].reshape(self.n, 9, 9)


class PointStresses:
    """sum_t (psi_t, P_t, A_t) at m points, term t active at the points ``at_t``.

    Args:
        terms: (density, at, directions) per term: ``density(F, a0)``, the indices
            of its points among the m, and their directions ((len(at), 3) or None).
        m: number of points.
    """

    def __init__(self, terms, m: int):
        self.m = int(m)
        self.kernels = []
        rows, comps, positions, targets = [], [], [], []
        offset = 0
        sizes = [np.size(at) for _, at, _ in terms]
        for (density, at, directions), size in zip(terms, sizes):
            at = np.asarray(at, dtype=np.int64)
            kernel = StressKernel(density, size, directed=directions is not None)
            if directions is not None:
                kernel.set_directions(directions)
            self.kernels.append(kernel)
            cols = kernel.coefficients.shape[1]
            # This kernel's u entries: point, component, position, flat target index.
            rows.append(np.repeat(at, kernel.u_columns.size))
            comps.append(kernel.u_component.ravel())
            positions.append(kernel.u_position.reshape(-1, 3))
            targets.append(offset + (np.arange(size)[:, None] * cols
                                     + kernel.u_columns[None, :]).ravel())
            offset += size * cols
        # One flat buffer holds every kernel's coefficients (each a contiguous block).
        flat = np.zeros(offset)
        offset = 0
        for kernel in self.kernels:
            block = flat[offset:offset + kernel.coefficients.size].reshape(
                kernel.coefficients.shape)
            block[:] = kernel.coefficients
            kernel.coefficients = block
            offset += block.size
        # flat = Q vec(grad_u) + a0 entries, Q sparse: u_i(X) = sum_J grad_u[p, i, J] X_J.
        rows, comps = np.concatenate(rows), np.concatenate(comps)
        positions, targets = np.concatenate(positions), np.concatenate(targets)
        columns = 9 * rows[:, None] + 3 * comps[:, None] + np.arange(3)[None, :]
        self._pack = sparse.csr_matrix(
            (positions.ravel(), (np.repeat(targets, 3), columns.ravel())),
            shape=(flat.size, 9 * self.m))
        self._fixed = flat.copy()                   # the a0 entries (u entries are zero)
        self._flat = flat
        # Every kernel writes into its rows of one buffer; S sums them per point.
        self._values = np.zeros((sum(sizes), 1, VALUES))
        start = 0
        for kernel, size in zip(self.kernels, sizes):
            kernel.values = self._values[start:start + size]
            start += size
        at_all = np.concatenate([np.asarray(at, dtype=np.int64) for _, at, _ in terms])
        self._sum = sparse.csr_matrix((np.ones(at_all.size), (at_all, np.arange(at_all.size))),
                                      shape=(self.m, at_all.size))

    def __call__(self, grad_u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Summed psi (m,), P (m, 9), A (m, 9, 9) at F_p = I + grad_u[p], grad_u (m, 3, 3)."""
        self._flat[:] = self._pack @ grad_u.reshape(-1)
        self._flat += self._fixed
        for kernel in self.kernels:
            kernel.tabulate()
        total = self._sum @ self._values.reshape(-1, VALUES)
        return total[:, 0], total[:, 1:10], total[:, 10:].reshape(self.m, 9, 9)
