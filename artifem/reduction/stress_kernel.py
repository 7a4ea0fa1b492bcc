"""First Piola-Kirchhoff stress and its tangent of a body's energy at many points at once.

A reduced body needs psi, P = dpsi/dF and A = dP/dF of the *same* UFL energy
densities as the full body, but only at its m integration points, each with
its own F. :class:`StressKernel` compiles, for a sum of densities,

    psi(F) = sum_t psi_t(F; a0_t, c_t),   P_iJ = dpsi/dF_iJ,   A_iJkL = d^2 psi / dF_iJ dF_kL

once with FFCx into a ``dolfinx.fem.Expression`` on a COMM_SELF mesh of n
disjoint reference tetrahedra, one per point. On tetrahedron p the
displacement u(X) = (F_p - I) X is linear (P1 interpolation is exact), so
grad u = F_p - I, and one kernel call over the n cells returns every point's
values. Fiber directions a0_t and the cell-wise fields c_t a density reads on the
full mesh (a muscle layer's excitations and fiber constants) are DG0 fields of the
point mesh whose values the caller sets; constants are read from the full body's own
``fem.Constant`` objects at every call. A is a Hessian (A_iJkL = A_kLiJ): the kernel
computes its 45 entries with iJ <= kL (a third less work than all 81, measured).

:class:`PointStresses` evaluates a body's energy terms at m points with one *fused*
kernel per signature: the points where the same terms are active (the material and
two muscle layers, say) share one kernel of the sum of those terms, so every term of a
point is evaluated in the same call, on the same kinematics. The signatures of a body
are few (a tongue: the penalty's points, and the material's points under 0 to 3 muscle
layers) and their kernels do not depend on which points hold them, so the JIT cache
serves every point set of a model. Coefficients are packed here, for all kernels in one
vectorized pass, into the arrays the compiled kernels read (dolfinx's generic packing,
per call, costs more than the kernels at these sizes), and the kernels are called
through ``dolfinx.cpp.fem.tabulate_expression``.
"""

from __future__ import annotations

from typing import Callable

import basix.ufl
import numpy as np
import ufl
from dolfinx import cpp, fem, mesh as dmesh
from mpi4py import MPI
from scipy import sparse
from ufl.algorithms.analysis import extract_coefficients, extract_constants

import artifem.jit  # noqa: F401  (waits for another process's compile of a form)
from artifem.errors import InputError

__all__ = ["StressKernel", "PointStresses"]

_REFERENCE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
#: The entries (iJ, kL) of A the kernels compute: iJ <= kL.
UPPER = np.triu_indices(9)
#: psi, P (9), A's 45 independent entries per point.
VALUES = 1 + 9 + UPPER[0].size


def _tetrahedra(n: int) -> dmesh.Mesh:
    """n disjoint copies of the reference tetrahedron (the same place, no shared vertices)."""
    element = basix.ufl.element("Lagrange", "tetrahedron", 1, shape=(3,))
    cells = np.arange(4 * n, dtype=np.int64).reshape(n, 4)
    return dmesh.create_mesh(MPI.COMM_SELF, cells, element, np.tile(_REFERENCE, (n, 1)))


#: Entry (iJ, kL) of A (row-major 81) is entry FULL[iJ, kL] of the 45 computed ones.
FULL = np.zeros((9, 9), dtype=np.int64)
FULL[UPPER] = np.arange(UPPER[0].size)
FULL[UPPER[1], UPPER[0]] = np.arange(UPPER[0].size)
FULL = FULL.ravel()


class StressKernel:
    """(psi, P, A) of ``density(F, directions)`` at n points, evaluated in one compiled call.

    Args:
        density: ``density(F, directions) -> UFL scalar``, ``directions`` a list of
            ``directions`` DG0 vector fields of the point mesh (one per fiber term), e.g.
            a sum of ``EnergyTerm.density`` of a FemBody.
        n: number of points.
        directions: how many direction fields the density takes.

    The density may also read fields of another mesh (the full body's cell-wise muscle
    layer fields); each must be cell-wise (DG0) and becomes a DG0 field of the point
    mesh, ``fields[j]`` its original. After construction the packed coefficient layout is
    known: row p of ``coefficients`` (n, columns) is what the kernel reads for point p;
    ``u_columns``, ``u_component`` and ``u_position`` say which columns hold u and that
    column k holds component ``u_component[p, k]`` of u at the reference position
    ``u_position[p, k]``; ``slots[j] = (columns, component)``: column k of row p holds
    component ``component[p, k]`` of the j-th field (the directions first, then
    ``fields``) at point p.
    """

    def __init__(self, density: Callable, n: int, *, directions: int = 0):
        if n < 1:
            raise InputError(f"StressKernel needs at least one point, got {n}")
        self.n = int(n)
        self._mesh = _tetrahedra(self.n)
        V = fem.functionspace(self._mesh, ("Lagrange", 1, (3,)))
        u = fem.Function(V)
        a0 = [
            fem.Function(fem.functionspace(self._mesh, ("DG", 0, (3,)))) for _ in range(directions)
        ]
        # A Variable with a fixed Label: ufl.variable's global label counter would
        # enter FFCx's signature and defeat the JIT cache across kernels and runs.
        F = ufl.classes.Variable(ufl.Identity(3) + ufl.grad(u), ufl.classes.Label(0))
        psi = density(F, a0)
        # The density's constants (excitations) and cell-wise fields belong to the full
        # body's mesh; an Expression lives on one mesh, so each gets a local twin.
        originals = extract_constants(psi)
        twins = [
            fem.Constant(self._mesh, np.asarray(c.value, dtype=float).copy()) for c in originals
        ]
        self.fields = [
            c for c in extract_coefficients(psi) if c.function_space.mesh is not self._mesh
        ]
        field_twins = []
        for field in self.fields:
            if field.function_space.dofmap.list.shape[1] != 1:
                raise InputError(
                    f"a reduced body's densities read cell-wise fields only; "
                    f"{field.name!r} is not one (DG0)"
                )
            field_twins.append(
                fem.Function(fem.functionspace(self._mesh, ("DG", 0, field.ufl_shape)))
            )
        psi = ufl.replace(
            psi, {**dict(zip(originals, twins)), **dict(zip(self.fields, field_twins))}
        )
        P = ufl.diff(psi, F)
        A = ufl.diff(P, F)
        index = [(i, J) for i in range(3) for J in range(3)]
        packed = ufl.as_vector(
            [psi] + [P[i, J] for i, J in index] + [A[index[a] + index[b]] for a, b in zip(*UPPER)]
        )
        #: (UFL expression, reference point) the kernel is compiled from
        self.ufl_expression = (packed, np.array([[0.25, 0.25, 0.25]]))
        self._expression = fem.Expression(*self.ufl_expression, comm=MPI.COMM_SELF)
        self._cells = np.arange(self.n, dtype=np.int32)
        expr = self._expression._cpp_object
        # Where the packing puts each value: tag every source value with its index.
        for k, twin in enumerate(twins):
            twin.value = np.full(np.shape(twin.value), float(k))
        # Views of the originals' values (a Constant's value array is updated in place).
        self._constant_values = [c.value for c in originals]
        self._constant_order = np.rint(cpp.fem.pack_constants(expr)).astype(np.int64)
        starts, start = [], u.x.array.size
        u.x.array[:] = np.arange(start)
        for twin in a0 + field_twins:
            starts.append(start)
            twin.x.array[:] = start + np.arange(twin.x.array.size)
            start += twin.x.array.size
        tags = np.rint(cpp.fem.pack_coefficients(expr, self._mesh._cpp_object, self._cells))
        tags = tags.astype(np.int64).reshape(self.n, -1)
        is_u = tags[0] < u.x.array.size
        self.u_columns = np.flatnonzero(is_u)
        dof_x = V.tabulate_dof_coordinates()
        self.u_component = tags[:, is_u] % 3
        self.u_position = dof_x[tags[:, is_u] // 3]  # (n, 12, 3)
        self.slots = []
        for twin, first in zip(a0 + field_twins, starts):
            columns = np.flatnonzero((tags[0] >= first) & (tags[0] < first + twin.x.array.size))
            bs = twin.function_space.dofmap.index_map_bs
            self.slots.append((columns, (tags[:, columns] - first) % bs))
        self.coefficients = np.zeros(tags.shape)
        self.values = np.zeros((self.n, 1, VALUES))

    def set_slot(self, j: int, values: np.ndarray) -> None:
        """Per-point values (n,) or (n, 3) of the j-th field (directions first)."""
        columns, component = self.slots[j]
        values = np.asarray(values, dtype=float).reshape(self.n, -1)
        if values.shape[1] <= component.max(initial=0):
            raise InputError(
                f"field {j}: values of shape {values.shape} for a field of "
                f"{component.max() + 1} components"
            )
        self.coefficients[:, columns] = values[np.arange(self.n)[:, None], component]

    def set_grad_u(self, grad_u: np.ndarray) -> None:
        """Pack u(X) = grad_u[p] X for every point p, grad_u of shape (n, 3, 3)."""
        rows = np.arange(self.n)[:, None]
        H = grad_u[rows, self.u_component]  # (n, 12, 3)
        self.coefficients[:, self.u_columns] = np.einsum("pkj,pkj->pk", H, self.u_position)

    def tabulate(self) -> None:
        """Run the compiled kernel on the packed coefficients into ``values``."""
        constants = (
            np.concatenate([np.ravel(v) for v in self._constant_values])
            if self._constant_values
            else np.zeros(0)
        )
        cpp.fem.tabulate_expression(
            self.values,
            self._expression._cpp_object,
            constants[self._constant_order],
            self.coefficients,
            self._mesh._cpp_object,
            self._cells,
        )


class PointStresses:
    """sum_t (psi_t, P_t, A_t) at m points, term t active at the points ``at_t``; one
    fused kernel per signature (module docstring).

    Args:
        terms: (density, at, directions, fields) per term: ``density(F, a0)``, the
            indices of its points among the m, their directions ((len(at), 3), or None
            for a density without), and None or the values of the cell-wise fields it
            reads at those points: ``(static, live)``, {field: values} and a callable
            returning {field: current values} (``EnergyTerm.fields_at``).
        m: number of points.
    """

    def __init__(self, terms, m: int):
        self.m = int(m)
        at = [np.asarray(a, dtype=np.int64) for _, a, _, _ in terms]
        active = np.zeros((self.m, len(terms)), dtype=bool)
        for t, a in enumerate(at):
            active[a, t] = True
        signatures, group_of = np.unique(active, axis=0, return_inverse=True)
        group_of = group_of.ravel()
        self.kernels, self.points = [], []
        rows, comps, positions, targets = [], [], [], []
        slot_values = []  # (kernel, slot, values at its points) fixed
        live = []  # (kernel index, slot, term, field, rows in at_t)
        offset, offsets = 0, []
        for g, signature in enumerate(signatures):
            points = np.flatnonzero(group_of == g)
            members = np.flatnonzero(signature)
            if members.size == 0:
                raise InputError(f"{points.size} point(s) are integration points of no energy term")
            directed = [t for t in members if terms[t][2] is not None]
            kernel = StressKernel(
                _fused(
                    [terms[t][0] for t in members],
                    [directed.index(t) if t in directed else None for t in members],
                ),
                points.size,
                directions=len(directed),
            )
            # row of each of the group's points in each member's at_t
            where = {t: np.searchsorted(at[t], points) for t in members}
            for j, t in enumerate(directed):
                slot_values.append((kernel, j, terms[t][2][where[t]]))
            for j, field in enumerate(kernel.fields, start=len(directed)):
                owner = next(
                    (
                        t
                        for t in members
                        if terms[t][3] is not None
                        and (field in terms[t][3][0] or field in terms[t][3][1]())
                    ),
                    None,
                )
                if owner is None:
                    raise InputError(
                        f"a density reads the cell-wise field {field.name!r} "
                        "but its energy term gives no values for it (fields_at)"
                    )
                static, current = terms[owner][3]
                if field in static:
                    slot_values.append((kernel, j, static[field][where[owner]]))
                else:
                    live.append((len(self.kernels), j, owner, field, where[owner]))
            self.kernels.append(kernel)
            self.points.append(points)
            cols = kernel.coefficients.shape[1]
            rows.append(np.repeat(points, kernel.u_columns.size))
            comps.append(kernel.u_component.ravel())
            positions.append(kernel.u_position.reshape(-1, 3))
            targets.append(
                offset
                + (np.arange(points.size)[:, None] * cols + kernel.u_columns[None, :]).ravel()
            )
            offsets.append(offset)
            offset += points.size * cols
        # One flat buffer holds every kernel's coefficients (each a contiguous block).
        flat = np.zeros(offset)
        for kernel, start in zip(self.kernels, offsets):
            kernel.coefficients = flat[start : start + kernel.coefficients.size].reshape(
                kernel.coefficients.shape
            )
        for kernel, j, values in slot_values:
            kernel.set_slot(j, values)
        # flat = Q vec(grad_u) + the fixed fields, Q sparse: u_i(X) = sum_J grad_u[p, i, J] X_J.
        rows, comps = np.concatenate(rows), np.concatenate(comps)
        positions, targets = np.concatenate(positions), np.concatenate(targets)
        columns = 9 * rows[:, None] + 3 * comps[:, None] + np.arange(3)[None, :]
        self._pack = sparse.csr_matrix(
            (positions.ravel(), (np.repeat(targets, 3), columns.ravel())),
            shape=(flat.size, 9 * self.m),
        )
        self._fixed = flat.copy()  # the fixed fields (u entries are zero)
        self._flat = flat
        # Live fields (excitations): flat[target] = current values of (term, field)[source].
        self._live = {}
        for k, j, owner, field, where in live:
            kernel = self.kernels[k]
            columns, component = kernel.slots[j]
            target = offsets[k] + (
                np.arange(kernel.n)[:, None] * kernel.coefficients.shape[1] + columns[None, :]
            )
            bs = max(1, int(np.prod(field.ufl_shape)))
            source = where[:, None] * bs + component
            key = (owner, field)
            t0, s0 = self._live.get(key, (np.zeros(0, np.int64), np.zeros(0, np.int64)))
            self._live[key] = (
                np.concatenate([t0, target.ravel()]),
                np.concatenate([s0, source.ravel()]),
            )
        self._current = {t: terms[t][3][1] for t, _ in self._live}
        # Every kernel writes into its rows of one buffer, in the order of the points.
        self._order = np.concatenate(self.points)
        self._values = np.zeros((self.m, 1, VALUES))
        start = 0
        for kernel in self.kernels:
            kernel.values = self._values[start : start + kernel.n]
            start += kernel.n
        # psi, P and A of point p gathered from its kernel's row in one take each
        row = np.empty(self.m, dtype=np.int64)
        row[self._order] = VALUES * np.arange(self.m)
        self._take = (row, row[:, None] + 1 + np.arange(9), row[:, None] + 10 + FULL)

    def __call__(self, grad_u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Summed psi (m,), P (m, 9), A (m, 9, 9) at F_p = I + grad_u[p], grad_u (m, 3, 3)."""
        self._flat[:] = self._pack @ grad_u.reshape(-1)
        self._flat += self._fixed
        current = {t: get() for t, get in self._current.items()}
        for (t, field), (target, source) in self._live.items():
            self._flat[target] = np.ravel(current[t][field])[source]
        for kernel in self.kernels:
            kernel.tabulate()
        values = self._values.reshape(-1)
        psi, P, A = (values.take(index) for index in self._take)
        return psi, P, A.reshape(self.m, 9, 9)


def _fused(densities: list[Callable], slots: list[int | None]) -> Callable:
    """density(F, directions) = sum_t densities[t](F, directions[slots[t]] or None)."""

    def density(F, directions):
        return sum(d(F, None if s is None else directions[s]) for d, s in zip(densities, slots))

    return density
