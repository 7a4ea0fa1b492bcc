"""Reduced-coordinate FEM body (Lloyd et al. 2019, section 2), serial.

Displacements live in the span of a basis U (ndofs x r):

    u = u_bar + U q,

with u_bar the prescribed displacement of the full body's fixed dofs (zero
unless prescribed) and U's rows at fixed dofs zero. The internal energy is a
cubature over m of the full body's energy integration points
(:mod:`artifem.reduction.quadrature_points`), point p with weight w_p (1 for
the full quadrature) times its quadrature volume V_p:

    Pi~(q) = sum_p w_p V_p sum_{t at p} psi_t(F_p; a0_p)  -  q^T f~_ext,
    F_p = I + H_p,   vec(H_p) = vec(H_bar_p) + D_p q,

where D_p (9 x r) = B_p U_e is the point's strain-displacement matrix times the
basis rows of its cell, precomputed once. psi_t are the full body's own
:class:`~artifem.fem_body.EnergyTerm` densities (bulk material, its muscle layers'
fiber energies read live from the muscles' *same* excitation ``fem.Constant``
objects, the element-wise incompressibility penalty), compiled by FFCx into
:class:`~artifem.reduction.stress_kernel.PointStresses` evaluations of P and
A = dP/dF at the m points, one fused kernel per set of terms a point holds. Then

    f~(q) = -sum_p w_p V_p D_p^T vec(P_p) + f~_ext,
    K~(q) =  sum_p w_p V_p D_p^T A_p D_p,

O(m r^2) per evaluation, never O(n). The external loads are linear in u, so
their reduced force is exact and computed on the full model:
f~_ext = lambda (U^T int rho g . phi dX + U^T (int b . phi dX + f_nodal)), the
gravity part per component so that changing ``full.gravity`` acts here too, the
body-force and nodal part again whenever the full body's loads change (a new nodal
load or body force, or a constant of the body force set to another value); a
dead traction t of the full body (:mod:`artifem.surface_loads`) adds
lambda U^T int phi dA t, per component, with t read at every evaluation. A
surface load added to the full body after this one was built is projected at
the next evaluation, so no load of the full body is silently left out.

Follower pressures of the full body are not linear in u: they are assembled on
a :class:`~artifem.surface_loads.SurfacePatch`, the cells next to their facets
only, at u_s = u_bar_s + U_s q (U_s the basis rows of the patch's dofs):

    f~_p = -U_s^T R_s(u_s),   K~_p = U_s^T K_s(u_s) U_s,

O(patch r^2) per evaluation (unsymmetric for an open pressure); a closed
pressure's potential -lambda p V enters Pi~.

A full body with the hard incompressibility keeps it in a reduced pressure space
(``pressure_basis``, :mod:`artifem.reduction.reduced_volume_constraint`): its augmented
energy W~(q; lambda) enters Pi~, its multipliers the state, and the integrators hold the
constraint in every solve.

Dynamics: a reduced body is a Scene body like a full one; the
integrators of :mod:`artifem.integrators` advance it with dense r x r
matrices, M~ = U^T M U and D~ = U^T D U = alpha M~ + beta U^T K_0 U (K_0 the full body's
stiffness at rest, ``FemBody.rest_stiffness``; both offline), ``advance_reduced``.

With the full basis and every point at weight 1 the reduced body reproduces
the full body to round-off. Point indices refer to
:func:`~artifem.reduction.quadrature_points.quadrature_points` of the full
body; errors name *input* (file) element indices.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import ufl
from dolfinx import fem, mesh as dmesh
from dolfinx.fem import petsc as fem_petsc
from ufl.algorithms.analysis import extract_constants

from artifem.contact_points import ReducedNodes
from artifem.errors import InputError
from artifem.fem_body import FemBody
from artifem.reduction.cubature import IntegrationPoints
from artifem.reduction.quadrature_points import QuadraturePoints, quadrature_points
from artifem.reduction.reduced_volume_constraint import ReducedVolumeConstraint
from artifem.reduction.stress_kernel import PointStresses
from artifem.surface_loads import SurfacePatch

__all__ = ["ReducedFemBody", "all_points"]


def all_points(full: FemBody) -> IntegrationPoints:
    """Every energy integration point of ``full`` with weight 1 (the full quadrature)."""
    n = quadrature_points(full).size
    return IntegrationPoints(np.arange(n), np.ones(n), "all")


def strain_displacement(table: QuadraturePoints, points: np.ndarray, V: np.ndarray) -> np.ndarray:
    """D_p = B_p V_e at the given points, shape (m, 9, cols): vec(H_p) = D_p x for u = V x.

    Row 3 i + J of D_p is d u_i / d X_J.
    """
    cols = V.shape[1]
    Ve = V.reshape(-1, 3, cols)[table.dofs[points]]  # (m, k, 3, cols)
    D = np.einsum("pkJ,pkic->piJc", table.grad_N[points], Ve)
    return np.ascontiguousarray(D.reshape(points.size, 9, cols))


class ReducedFemBody:
    """A reduced FEM body u = u_bar + U q (see the module docstring).

    Args:
        full: the full-order body (muscles, fixed nodes, loads already defined).
        U: basis, shape (ndofs, r), rows = block-interleaved dofs of ``full.V``
            (like ``full.u.x.array[:ndofs]``); zero rows at fixed dofs (entries up to
            1e-10 max|U| there are taken as round-off and zeroed, larger ones raise).
        points: integration points: indices into ``quadrature_points(full)`` and weights > 0
            (multiplying each point's quadrature volume; ``all_points(full)`` is the full rule).
        pressure_basis: the reduced pressure space Pi (n_p x s, s < r) of a full body with
            the hard incompressibility (:mod:`~artifem.reduction.reduced_volume_constraint`);
            required for such a body, refused for any other.
        pressure_weights: the constraint's cubature weights at the m points (default: the
            energy's, ``points.weights``).
        hold_volume: False leaves a hard body's volume constraint out (its material forces
            only, e.g. to train a cubature).
        leave_out: names of the full body's energy terms (``FemBody.energy_terms(merged=True)``,
            e.g. ``"incompressibility"``) the reduced energy leaves out (a diagnosis:
            :mod:`artifem.reduction.galerkin_gap`).
        name: component name.
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "reduced_bodies"

    def __init__(
        self,
        full: FemBody,
        U: np.ndarray,
        points: IntegrationPoints,
        *,
        pressure_basis: np.ndarray | None = None,
        pressure_weights: np.ndarray | None = None,
        hold_volume: bool = True,
        leave_out: Sequence[str] = (),
        name: str | None = None,
    ):
        if full.mesh.comm.size != 1:
            raise NotImplementedError("ReducedFemBody runs in serial only for now")
        self.full, self.points = full, points
        self.name = name or f"{full.name}_reduced"
        hard = full.volume_constraint is not None and hold_volume
        if hard and pressure_basis is None:
            raise InputError(
                f"ReducedFemBody {self.name!r}: {full.name!r} has the hard incompressibility "
                "(Incompressible); give its reduced pressure space, pressure_basis (n_p x s, "
                "e.g. reduced_volume_constraint.pressure_basis of training pressures)"
            )
        if pressure_basis is not None and not hard:
            raise InputError(
                f"ReducedFemBody {self.name!r}: a pressure_basis needs a full "
                "body with the hard incompressibility (Incompressible)"
            )
        self.alpha, self.beta = full.alpha, full.beta
        full.compile()
        bs = 3
        n_owned = full.V.dofmap.index_map.size_local
        ndofs = bs * n_owned
        U = np.asarray(U, dtype=float)
        if U.ndim != 2 or U.shape[0] != ndofs:
            raise InputError(
                f"ReducedFemBody {self.name!r}: U must have shape ({ndofs}, r), got {U.shape}"
            )
        if U.shape[1] == 0 or not np.all(np.isfinite(U)):
            raise InputError(f"ReducedFemBody {self.name!r}: U must have r >= 1 finite columns")
        # Rows at fixed dofs must vanish; round-off (<= 1e-10 max|U|, e.g. from a QR
        # or an eigensolver) is set to exactly zero.
        fixed_rows = full.fixed_components  # every fixed component
        tol = 1e-10 * np.abs(U).max()
        if fixed_rows.size and np.any(np.abs(U[fixed_rows]) > tol):
            bad = np.unique(fixed_rows[np.any(np.abs(U[fixed_rows]) > tol, axis=1)] // bs)
            raise InputError(
                f"ReducedFemBody {self.name!r}: rows of U at fixed dofs must be "
                f"zero; nonzero at {bad.size} fixed node(s), local dofs "
                f"{bad[:10].tolist()}"
            )
        self.table = quadrature_points(full)
        idx = np.asarray(points.indices, dtype=np.int64)
        if idx.size == 0 or idx.max() >= self.table.size:
            raise InputError(
                f"ReducedFemBody {self.name!r}: integration point indices must be "
                f"a non-empty subset of the {self.table.size} quadrature points "
                f"of {full.name!r}"
            )
        if fixed_rows.size:
            U = U.copy()
            U[fixed_rows] = 0.0
        self.U = U
        self.r = U.shape[1]
        self.q = np.zeros(self.r)
        self.qdot = np.zeros(self.r)
        self.u_bar = full._fixed_values.x.array[:ndofs].copy()

        # ---- offline: mass and external loads on the full model (O(n r^2), once) ----
        if full.mass_kind == "lumped":
            m = full.M_lumped.array[:ndofs]
            self.M = U.T @ (m[:, None] * U)
        else:
            Mc = full.M_consistent
            MU = np.empty_like(U)
            x, y = Mc.createVecs()
            for j in range(self.r):
                x.array[:] = U[:, j]
                Mc.mult(x, y)
                MU[:, j] = y.array
            self.M = U.T @ MU
        self.M = 0.5 * (self.M + self.M.T)
        #: D~ = U^T (alpha M + beta K_0) U, the Rayleigh damping (FemBody.rest_stiffness)
        self.damping = self.alpha * self.M
        if self.beta:
            K0 = full.rest_stiffness()
            x, y = K0.createVecs()
            K0U = np.empty_like(U)
            for j in range(self.r):
                x.array[:] = U[:, j]
                K0.mult(x, y)
                K0U[:, j] = y.array
            self.damping = self.damping + self.beta * 0.5 * (U.T @ K0U + K0U.T @ U)
        v = ufl.TestFunction(full.V)
        dx = ufl.Measure(
            "dx", domain=full.mesh, metadata={"quadrature_degree": full.quadrature_degree}
        )
        self.G = np.zeros((self.r, 3))  # U^T int rho e_k . phi dX
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1.0
            ek = fem.Constant(full.mesh, e)
            vec = fem_petsc.assemble_vector(fem.form(full.density * ufl.dot(ek, v) * dx))
            self.G[:, k] = U.T @ vec.array[:ndofs]
            vec.destroy()
        self._loads: dict = {}  # U^T (b, f_nodal), refreshed when they change
        self._project_surface_loads()

        # ---- online: the m points, their D_p and one stress kernel per energy term ----
        self.point_index = idx
        self.cells = self.table.cell[idx]
        self.weights = np.asarray(points.weights, dtype=float) * self.table.volume[idx]
        self.D = strain_displacement(self.table, idx, U)
        self.H_bar = strain_displacement(self.table, idx, self.u_bar[:, None])[:, :, 0]
        m = idx.size
        self._blocks = np.zeros((m, 9, 9))  # w_p A_p
        self._AD = np.zeros((m, 9, self.r))  # w_p A_p D_p
        self._Dt = np.ascontiguousarray(self.D.reshape(-1, self.r).T)
        # Each energy term's density at the points where it is integrated.
        terms = []
        energy_terms = full.energy_terms(merged=True)
        unknown = sorted(set(leave_out) - {t.name for t in energy_terms})
        if unknown:
            raise InputError(
                f"ReducedFemBody {self.name!r}: leave_out names {unknown}, not "
                f"energy terms of {full.name!r}: "
                f"{[t.name for t in energy_terms]}"
            )
        for term in energy_terms:
            if term.name in leave_out:
                continue
            at = np.flatnonzero(np.isin(idx, self.table.of_term(term)))
            if at.size == 0:
                continue
            directions = None
            if term.direction is not None:
                W = term.direction.function_space
                if W.dofmap.list.shape[1] != 1:
                    raise NotImplementedError(
                        f"reduced body of {full.name!r}: energy term {term.name!r} has fiber "
                        "directions per quadrature point; reduced bodies take one per cell "
                        "(DG0) for now"
                    )
                directions = term.direction.x.array.reshape(-1, 3)[W.dofmap.list[self.cells[at], 0]]
            fields = None if term.fields_at is None else term.fields_at(self.cells[at])
            terms.append((term.density, at, directions, fields))
        self._stresses = PointStresses(terms, m)
        # Views of the excitation values (updated in place when a controller sets them).
        self._excitations = [mus.excitation.value for mus in full.muscles.values()]
        self.set_q(self.q)
        #: the hard incompressibility in a reduced pressure space, or None
        self.volume_constraint = (
            ReducedVolumeConstraint(self, pressure_basis, pressure_weights) if hard else None
        )

    # ---- evaluation --------------------------------------------------------

    @property
    def m(self) -> int:
        """Number of integration points."""
        return int(self.point_index.size)

    @property
    def gravity(self):
        """The full body's gravity constant (g; read live by the external force)."""
        return self.full.gravity

    def set_q(self, q) -> None:
        """Set the reduced coordinates and evaluate F at the integration points."""
        self.q = np.array(q, dtype=float).reshape(self.r)
        self._H = (self.H_bar.ravel() + self.D.reshape(-1, self.r) @ self.q).reshape(-1, 3, 3)
        self._stress = None

    def _evaluate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(psi, P, A) summed over the energy terms at every point.

        Cached until q or an excitation changes (force and tangent of one step
        share one evaluation).
        """
        key = tuple(float(v) for v in self._excitations)
        if self._stress is None or self._stress_key != key:
            self._stress_key = key
            self._stress = self._stresses(self._H)
        return self._stress

    def _body_and_nodal_loads(self) -> np.ndarray:
        """U^T (int b . phi dX + f_nodal), recomputed on the full model (O(n r)) only when
        the full body's nodal loads or body force were changed (``loads_version``) or a
        ``fem.Constant`` of the body force took another value: loads changed after this body
        was built act on it as on the full body."""
        full, loads = self.full, self._loads
        b = full.body_force
        if loads.get("version") != full.loads_version:  # a new body force or load
            loads.clear()
            loads["version"] = full.loads_version
            loads["constants"] = [] if b is None else extract_constants(b)
            if b is not None:
                v = ufl.TestFunction(full.V)
                dx = ufl.Measure(
                    "dx", domain=full.mesh, metadata={"quadrature_degree": full.quadrature_degree}
                )
                loads["form"] = fem.form(ufl.dot(b, v) * dx)
        values = tuple(np.asarray(c.value).tobytes() for c in loads["constants"])
        if loads.get("values") != values:
            n = self.U.shape[0]
            f = full.nodal_load.array[:n].copy()
            if b is not None:
                vec = fem_petsc.assemble_vector(loads["form"])
                f += vec.array[:n]
                vec.destroy()
            loads["values"], loads["value"] = values, self.U.T @ f
        return loads["value"]

    def _project_surface_loads(self) -> None:
        """Project the full body's surface loads (O(n r), at construction and again when a
        load was added to the full body since): a dead traction t gives
        T = U^T int e_k . phi dA (r x 3), times t at every evaluation; the follower
        pressures are assembled on the cells next to their facets (module docstring)."""
        full, U, ndofs = self.full, self.U, self.U.shape[0]
        v = ufl.TestFunction(full.V)
        self._surface_names = tuple(full.surface_loads)
        self._tractions = []
        pressures = []
        for load in full.surface_loads.values():
            if load.follower:
                pressures.append(load)
                continue
            tags = dmesh.meshtags(
                full.mesh, full.mesh.topology.dim - 1, load.facets, np.ones_like(load.facets)
            )
            ds = ufl.Measure(
                "ds",
                domain=full.mesh,
                subdomain_data=tags,
                metadata={"quadrature_degree": load.degree},
            )(1)
            T = np.zeros((self.r, 3))
            for k in range(3):
                vec = fem_petsc.assemble_vector(fem.form(v[k] * ds))
                T[:, k] = U.T @ vec.array[:ndofs]
                vec.destroy()
            self._tractions.append((load, T))
        self._patch = None
        if pressures:
            self._patch = SurfacePatch(full.V, pressures, full.load_factor)
            self._U_patch = U[self._patch.dofs]
            self._u_bar_patch = self.u_bar[self._patch.dofs]
        self._pressure_cache: dict = {}

    def _surface_loads(self):
        """(dead tractions with their T, follower-pressure patch or None), projected again
        if a surface load was added to the full body after this body was built."""
        if self._surface_names != tuple(self.full.surface_loads):
            self._project_surface_loads()
        return self._tractions, self._patch

    def external_force(self) -> np.ndarray:
        """f~_ext = lambda (G g + U^T (b, f_nodal) + sum_t T_t t) (constant in q)."""
        lf = float(self.full.load_factor.value)
        f = self.G @ np.asarray(self.full.gravity.value, dtype=float) + self._body_and_nodal_loads()
        for load, T in self._surface_loads()[0]:
            f = f + T @ np.asarray(load.value.value, dtype=float)
        return lf * f

    def _pressure(self, what: str):
        """The follower pressures' f~_p ("force") or K~_p ("tangent") at the current q
        (module docstring); cached until q, a pressure or the load factor changes."""
        patch = self._patch
        key = (
            self.q.tobytes(),
            float(self.full.load_factor.value),
            tuple(float(load.value.value) for load in patch.loads),
        )
        if self._pressure_cache.get("key") != key:
            self._pressure_cache = {"key": key}
        cache = self._pressure_cache
        if what not in cache:
            u = self._u_bar_patch + self._U_patch @ self.q
            Us = self._U_patch
            if what == "force":
                cache[what] = -Us.T @ patch.residual(u)
            elif what == "tangent":
                cache[what] = Us.T @ (patch.tangent(u) @ Us)
            else:
                cache[what] = patch.potential(u)
        return cache[what]

    def point_forces(self) -> np.ndarray:
        """Each point's unweighted internal force V_p D_p^T vec(P_p), shape (m, r).

        sum_p w_p (row p) is U^T R_int; the training matrix of trained cubature
        stacks these over snapshots.
        """
        _, P, _ = self._evaluate()
        V = self.table.volume[self.point_index]
        return V[:, None] * np.einsum("pir,pi->pr", self.D, P)

    def internal_residual(self) -> np.ndarray:
        """dPi~_int/dq = sum_p w_p V_p D_p^T vec(P_p) (with a hard body's constraint term
        -C^T pi~ as point stresses, :meth:`ReducedVolumeConstraint.add_point_stress`)."""
        _, P, _ = self._evaluate()
        weighted = self.weights[:, None] * P
        if self.volume_constraint is not None:
            self.volume_constraint.add_point_stress(weighted)
        return self.D.reshape(-1, self.r).T @ weighted.reshape(-1)

    def force(self) -> np.ndarray:
        """f~(q) = -dPi~_int/dq + f~_ext (+ f~_p of the follower pressures)."""
        f = -self.internal_residual() + self.external_force()
        return f if self._surface_loads()[1] is None else f + self._pressure("force")

    def tangent(self, linearized: bool = False) -> np.ndarray:
        """K~(q) = sum_p w_p V_p D_p^T A_p D_p (dense r x r, symmetric) (+ K~_p of the
        follower pressures, unsymmetric for an open one; + the volume constraint's, its
        geometric part with the multipliers in a ``linearized`` step)."""
        _, _, A = self._evaluate()
        np.multiply(A, self.weights[:, None, None], out=self._blocks)
        if self.volume_constraint is not None:
            self.volume_constraint.add_point_tangent(self._blocks, linearized)
        # (w_p A_p) D_p for all p in one batched product (5x faster than a block-diagonal
        # sparse matrix times D), then one dense (r x 9m)(9m x r) product.
        np.matmul(self._blocks, self.D, out=self._AD)
        K = self._Dt @ self._AD.reshape(-1, self.r)
        K = 0.5 * (K + K.T)
        if self.volume_constraint is not None:
            K = K + self.volume_constraint.augmentation()
        return K if self._surface_loads()[1] is None else K + self._pressure("tangent")

    def potential_energy(self) -> float:
        """Pi~(q) = sum_p w_p V_p psi(F_p) - q^T f~_ext (up to the constant u_bar work),
        plus a closed pressure's -lambda p V (an open one has no potential)."""
        psi, _, _ = self._evaluate()
        Pi = float(self.weights @ psi) - float(self.q @ self.external_force())
        if self.volume_constraint is not None:
            Pi += self.volume_constraint.energy()
        return Pi if self._surface_loads()[1] is None else Pi + self._pressure("potential")

    def kinetic_energy(self) -> float:
        return 0.5 * float(self.qdot @ self.M @ self.qdot)

    def det_F(self) -> np.ndarray:
        """det F at the m integration points."""
        F = np.eye(3) + self._H
        return (
            F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
            - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
            + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0])
        )

    def full_mesh_inversion(self) -> tuple[np.ndarray, float]:
        """The full body's inverted_elements() at u = u_bar + U q (O(n r), for output).

        The reduced energy sees only its m points; elements elsewhere can invert
        in the rebuilt mesh without the reduced dynamics noticing.
        """
        saved = self.full.state()
        try:
            self.to_full()
            return self.full.inverted_elements()
        finally:
            self.full.set_state(saved)

    def constraint_failure(self) -> str | None:
        """After a step (the body interface): None, or the reduced volume constraint left
        off by more than its ``step_tol`` (FemBody.constraint_failure)."""
        vc = self.volume_constraint
        return None if vc is None else vc.step_failure()

    def inverted_elements(self) -> tuple[np.ndarray, float]:
        """(input indices of cells with an integration point at det F <= 0 or NaN, min det F)."""
        detF = self.det_F()
        low = float(detF.min())  # NaN if any is NaN
        if low > 0:
            return np.zeros(0, dtype=np.int64), low
        detF = np.where(np.isnan(detF), -np.inf, detF)  # NaN counts as inverted
        bad = np.unique(self.cells[detF <= 0])
        return np.sort(self.full.input_cell_index(bad)).astype(np.int64), float(detF.min())

    # ---- state -------------------------------------------------------------

    def state(self) -> tuple[np.ndarray, ...]:
        """(q, q') and, with the hard incompressibility, its multipliers lambda."""
        if self.volume_constraint is None:
            return self.q.copy(), self.qdot.copy()
        return self.q.copy(), self.qdot.copy(), self.volume_constraint.lam.copy()

    def set_state(self, state) -> None:
        q, qdot = state[:2]
        self.qdot = np.array(qdot, dtype=float).reshape(self.r)
        self.set_q(q)
        if self.volume_constraint is not None and len(state) > 2:
            self.volume_constraint.lam = np.array(state[2], dtype=float)

    def contact_points(self, nodes=None) -> ReducedNodes:
        """The full body's nodes contact may push (:meth:`FemBody.contact_points`), as
        they move with q: rows U_j^T e on q (:mod:`artifem.contact_points`)."""
        return ReducedNodes(self, *self.full.contact_node_dofs(nodes))

    def contact_surface(self) -> tuple[ReducedNodes, np.ndarray]:
        """(the boundary nodes, the full body's exterior triangles into them)."""
        return self.contact_points(None), self.full.contact_surface()[1]

    def nodal_displacement(self) -> np.ndarray:
        """u = u_bar + U q on all full dofs (O(n r), on demand), block-interleaved."""
        return self.u_bar + self.U @ self.q

    def nodal_velocity(self) -> np.ndarray:
        return self.U @ self.qdot

    def to_full(self) -> None:
        """Write u and v into the full body's functions (for output)."""
        n = self.U.shape[0]
        self.full.u.x.array[:n] = self.nodal_displacement()
        self.full.v.x.array[:n] = self.nodal_velocity()
        self.full.u.x.scatter_forward()
        self.full.v.x.scatter_forward()
