"""Reduced-coordinate FEM body (Lloyd et al. 2019, section 2), serial.

Displacements live in the span of a basis U (ndofs x r):

    u = u_bar + U q,

with u_bar the prescribed displacement of the full body's fixed dofs (zero
unless prescribed) and U's rows at fixed dofs zero. The online step never
touches all n nodes: the internal energy is evaluated on a *submesh* of the
m cells of the integration points only, with the same UFL energy ingredients
as the full body (``full.material.strain_energy``, each muscle's
``fiber.strain_energy`` with its DG0 directions copied to the submesh and the
*same* excitation ``fem.Constant`` objects, the element-wise incompressibility
penalty), each cell weighted by its cubature weight w_e (a DG0 function):

    Pi~(q) = sum_e w_e int_e psi(F(u_bar + U q)) dX  -  lambda q^T f~_ext,

    f~(q) = -dPi~/dq = -U_s^T R_s(u_s) + lambda f~_ext,
    K~(q) = d^2 Pi~/dq^2 = U_s^T K_s(u_s) U_s,

where U_s are the rows of U at the submesh dofs, u_s = u_bar_s + U_s q, and R_s,
K_s are assembled on the submesh (forms compiled once). The external loads
are linear in u, so their reduced force is computed exactly on the full model
once: f~_ext = U^T (int rho g . phi dX + int b . phi dX + f_nodal), with the
gravity part kept per component so that changing ``full.gravity`` acts on the
reduced body (the load factor is read from ``full.load_factor`` too). Body
forces and nodal loads are taken at construction.

Dynamics: the full body's semi-implicit Euler (ArtiSynth's
ConstrainedBackwardEuler), dense r x r:

    (M~ + h D~ + h^2 K~) dq' = h f~ - h D~ q' - h^2 K~ q',
    q' += dq',  q += h q',

with M~ = U^T M U and D~ = alpha M~ + beta K~ (Rayleigh with the current tangent).

Cost per step: O(m) assembly, O(nnz(K_s) r + m r^2) projection, O(r^3) solve;
never O(n). With the full basis (U = identity on the free dofs) and every cell
an integration point of weight 1, the reduced body reproduces the full body to
round-off.

Integration point indices are *local* cell indices of ``full.mesh`` (serial:
all cells); errors name *input* (file) element indices.
"""

from __future__ import annotations

import basix
import numpy as np
import ufl
from dolfinx import fem, la, mesh as dmesh
from dolfinx.fem import petsc as fem_petsc

from artifem.fem_body import ElementInversionError, FemBody
from artifem.reduction.cubature import IntegrationPoints

__all__ = ["ReducedFemBody", "all_points"]


def _dof_of_node(msh: dmesh.Mesh, V: fem.FunctionSpace) -> np.ndarray:
    """Block dof of each local geometry node (P1 on a linear mesh)."""
    out = np.full(msh.geometry.x.shape[0], -1, dtype=np.int64)
    out[msh.geometry.dofmaps[0].reshape(-1)] = V.dofmap.list.reshape(-1)
    return out


def all_points(full: FemBody) -> IntegrationPoints:
    """Every integration point of ``full`` with weight 1 (the full quadrature)."""
    n = full.mesh.topology.index_map(full.mesh.topology.dim).size_local
    return IntegrationPoints(np.arange(n), np.ones(n), "all")


class ReducedFemBody:
    """A reduced FEM body u = u_bar + U q (see the module docstring).

    Args:
        full: the full-order body (muscles, fixed nodes, loads already defined).
        U: basis, shape (ndofs, r), rows = block-interleaved dofs of ``full.V``
            (like ``full.u.x.array[:ndofs]``); zero rows at fixed dofs (entries up to
            1e-10 max|U| there are taken as round-off and zeroed, larger ones raise).
        points: integration points (local cell indices of ``full.mesh``, weights > 0).
        name: component name.
    """

    def __init__(self, full: FemBody, U: np.ndarray, points: IntegrationPoints, *,
                 name: str | None = None):
        if full.mesh.comm.size != 1:
            raise NotImplementedError("ReducedFemBody runs in serial only for now")
        self.full, self.points = full, points
        self.name = name or f"{full.name}_reduced"
        self.alpha, self.beta = full.alpha, full.beta
        full.compile()
        tdim = full.mesh.topology.dim
        bs = 3
        n_owned = full.V.dofmap.index_map.size_local
        ndofs = bs * n_owned
        U = np.asarray(U, dtype=float)
        if U.ndim != 2 or U.shape[0] != ndofs:
            raise ValueError(f"ReducedFemBody {self.name!r}: U must have shape ({ndofs}, r), "
                             f"got {U.shape}")
        if U.shape[1] == 0 or not np.all(np.isfinite(U)):
            raise ValueError(f"ReducedFemBody {self.name!r}: U must have r >= 1 finite columns")
        # Rows at fixed dofs must vanish; round-off (<= 1e-10 max|U|, e.g. from a QR
        # or an eigensolver) is set to exactly zero.
        fixed_rows = (bs * full.fixed_dofs[:, None] + np.arange(bs)).ravel()
        tol = 1e-10 * np.abs(U).max()
        if fixed_rows.size and np.any(np.abs(U[fixed_rows]) > tol):
            bad = np.unique(fixed_rows[np.any(np.abs(U[fixed_rows]) > tol, axis=1)] // bs)
            raise ValueError(f"ReducedFemBody {self.name!r}: rows of U at fixed dofs must be "
                             f"zero; nonzero at {bad.size} fixed node(s), local dofs "
                             f"{bad[:10].tolist()}")
        n_cells = full.mesh.topology.index_map(tdim).size_local
        cells = np.asarray(points.indices, dtype=np.int64)
        if cells.size == 0 or cells.max() >= n_cells:
            raise ValueError(f"ReducedFemBody {self.name!r}: integration point indices must be "
                             f"a non-empty subset of the {n_cells} cells")
        if fixed_rows.size:
            U = U.copy()
            U[fixed_rows] = 0.0
        self.U = U
        self.r = U.shape[1]
        self.q = np.zeros(self.r)
        self.qdot = np.zeros(self.r)
        self.time = 0.0
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
        v = ufl.TestFunction(full.V)
        dx = ufl.Measure("dx", domain=full.mesh,
                         metadata={"quadrature_degree": full.quadrature_degree})
        self.G = np.zeros((self.r, 3))          # U^T int rho e_k . phi dX
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1.0
            ek = fem.Constant(full.mesh, e)
            vec = fem_petsc.assemble_vector(fem.form(full.density * ufl.dot(ek, v) * dx))
            self.G[:, k] = U.T @ vec.array[:ndofs]
            vec.destroy()
        f_const = full.nodal_load.array[:ndofs].copy()
        if full.body_force is not None:
            vec = fem_petsc.assemble_vector(fem.form(ufl.dot(full.body_force, v) * dx))
            f_const += vec.array[:ndofs]
            vec.destroy()
        self.f_const = U.T @ f_const

        # ---- online: submesh of the integration cells --------------------------
        sub, entity_map, _, node_map = dmesh.create_submesh(
            full.mesh, tdim, np.sort(cells).astype(np.int32))
        self.submesh = sub
        n_sub = sub.topology.index_map(tdim).size_local
        self.parent_cells = np.asarray(entity_map.sub_topology_to_topology(
            np.arange(n_sub, dtype=np.int32), False), dtype=np.int64)
        weight_of = dict(zip(cells.tolist(), np.asarray(points.weights).tolist()))
        self.Vs = fem.functionspace(sub, ("Lagrange", 1, (3,)))
        self.us = fem.Function(self.Vs, name="displacement")
        W0 = fem.functionspace(sub, ("DG", 0))
        self.weight = fem.Function(W0, name="cubature_weight")
        self.weight.x.array[W0.dofmap.list[:, 0]] = [weight_of[c] for c in
                                                     self.parent_cells.tolist()]

        # Rows of U at the submesh dofs.
        sub_dof = _dof_of_node(sub, self.Vs)
        parent_dof = _dof_of_node(full.mesh, full.V)
        ndofs_s = self.Vs.dofmap.index_map.size_local
        parent_of_sub = np.empty(ndofs_s, dtype=np.int64)
        parent_of_sub[sub_dof] = parent_dof[np.asarray(node_map)]
        rows = (bs * parent_of_sub[:, None] + np.arange(bs)).ravel()
        self.U_s = np.ascontiguousarray(U[rows])
        self.u_bar_s = self.u_bar[rows]
        self._sub_rows = rows

        # The same energy on the submesh, weighted per cell.
        F = ufl.Identity(3) + ufl.grad(self.us)
        md = {"quadrature_degree": full.quadrature_degree}
        w = self.weight
        dxs = ufl.Measure("dx", domain=sub, metadata=md)
        Pi = w * full.material.strain_energy(F) * dxs
        self.directions = {}
        if full.muscles:
            parent_to_sub = {c: i for i, c in enumerate(self.parent_cells.tolist())}
            data, terms = [], []
            Wd = fem.functionspace(sub, ("DG", 0, (3,)))
            for i, mus in enumerate(full.muscles.values()):
                local = np.array([parent_to_sub[c] for c in mus.cells.tolist()
                                  if c in parent_to_sub], dtype=np.int32)
                if local.size == 0:
                    continue
                a0 = fem.Function(Wd, name=f"fiber_{mus.name}")
                Wfull = mus.direction.function_space
                full_rows = Wfull.dofmap.list[self.parent_cells[local], 0]
                a0.x.array.reshape(-1, 3)[Wd.dofmap.list[local, 0]] = \
                    mus.direction.x.array.reshape(-1, 3)[full_rows]
                self.directions[mus.name] = a0
                data.append((i + 1, np.sort(local)))
                terms.append((i + 1, mus, a0))
            if terms:
                dxm = ufl.Measure("dx", domain=sub, metadata=md, subdomain_data=data)
                for tag, mus, a0 in terms:
                    Pi += w * mus.fiber.strain_energy(F, a0, mus.excitation) * dxm(tag)
        if full.incompressibility is not None:
            centre = ufl.Measure("dx", domain=sub, metadata={"quadrature_degree": 1})
            Pi += w * 0.5 * full.incompressibility * (ufl.det(F) - 1) ** 2 * centre
        vs, dus = ufl.TestFunction(self.Vs), ufl.TrialFunction(self.Vs)
        R = ufl.derivative(Pi, self.us, vs)
        self._R_form = fem.form(R)
        self._K_form = fem.form(ufl.derivative(R, self.us, dus))
        self._Pi_form = fem.form(Pi)
        self._K_mat = fem.create_matrix(self._K_form)
        pts, _ = basix.make_quadrature(getattr(basix.CellType, full.cell_name),
                                       full.quadrature_degree)
        self._detF = fem.Expression(ufl.det(F), pts)
        self._sub_cells = np.arange(n_sub, dtype=np.int32)
        self.set_q(self.q)

    # ---- evaluation --------------------------------------------------------

    @property
    def m(self) -> int:
        return int(self.parent_cells.size)

    def set_q(self, q) -> None:
        """Set the reduced coordinates (and the submesh displacement u_s)."""
        self.q = np.array(q, dtype=float).reshape(self.r)
        self._update_submesh()

    def _update_submesh(self) -> None:
        n = self.U_s.shape[0]
        self.us.x.array[:n] = self.u_bar_s + self.U_s @ self.q

    def external_force(self) -> np.ndarray:
        """f~_ext = lambda (G g + U^T (b, f_nodal)) (constant in q)."""
        lf = float(self.full.load_factor.value)
        return lf * (self.G @ np.asarray(self.full.gravity.value, dtype=float) + self.f_const)

    def internal_residual(self) -> np.ndarray:
        """U_s^T R_s(u_s): the gradient of the weighted internal energy in q."""
        vec = fem.assemble_vector(self._R_form)
        vec.scatter_reverse(la.InsertMode.add)
        n = self.U_s.shape[0]
        return self.U_s.T @ vec.array[:n]

    def force(self) -> np.ndarray:
        """f~(q) = -U_s^T R_s(u_s) + f~_ext."""
        return -self.internal_residual() + self.external_force()

    def tangent(self) -> np.ndarray:
        """K~(q) = U_s^T K_s(u_s) U_s (dense r x r, symmetric)."""
        A = self._K_mat
        A.set_value(0.0)
        fem.assemble_matrix(A, self._K_form)
        A.scatter_reverse()
        K = A.to_scipy()            # block sparse (3x3 blocks); serial: no ghost rows
        KU = K @ self.U_s
        Kr = self.U_s.T @ KU
        return 0.5 * (Kr + Kr.T)

    def potential_energy(self) -> float:
        """Pi~(q) = weighted internal energy - q^T f~_ext (up to the constant u_bar work)."""
        return float(fem.assemble_scalar(self._Pi_form)) - float(self.q @ self.external_force())

    def kinetic_energy(self) -> float:
        return 0.5 * float(self.qdot @ self.M @ self.qdot)

    def det_F(self) -> np.ndarray:
        """det F at the energy quadrature points of the submesh cells, (m, points)."""
        return self._detF.eval(self.submesh, self._sub_cells)

    def inverted_elements(self) -> tuple[np.ndarray, float]:
        """(input indices of integration cells with det F <= 0 or NaN, min det F)."""
        detF = self.det_F()
        detF = np.where(np.isnan(detF), -np.inf, detF)      # NaN counts as inverted
        low = detF.min(axis=1) if detF.size else np.zeros(0)
        bad = np.sort(self.full.input_cell_index(self.parent_cells[low <= 0]))
        gmin = float(low.min()) if low.size else np.inf
        return np.asarray(bad, dtype=np.int64), gmin

    # ---- dynamics ----------------------------------------------------------

    def step(self, h: float) -> None:
        """One semi-implicit Euler step of size h (dense r x r).

        Raises ElementInversionError (state kept at the start of the step) if
        det F <= 0 at an integration cell's quadrature point after the step.
        """
        if not np.isfinite(h) or h <= 0:
            raise ValueError(f"time step must be > 0, got {h}")
        K = self.tangent()
        f = self.force()
        c = h * self.beta + h * h
        b = h * f - c * (K @ self.qdot) - h * self.alpha * (self.M @ self.qdot)
        A = c * K + (1.0 + h * self.alpha) * self.M
        dqdot = np.linalg.solve(A, b)
        q0, qdot0 = self.q.copy(), self.qdot.copy()
        self.qdot = self.qdot + dqdot
        self.q = self.q + h * self.qdot
        self._update_submesh()
        bad, min_det = self.inverted_elements()
        if bad.size or not (np.all(np.isfinite(self.q)) and np.all(np.isfinite(self.qdot))):
            self.q, self.qdot = q0, qdot0
            self._update_submesh()
            raise ElementInversionError(self.time + h, bad, min_det,
                                        f"reduced body {self.name!r}")
        self.time += h

    # ---- state -------------------------------------------------------------

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        return self.q.copy(), self.qdot.copy()

    def set_state(self, state) -> None:
        q, qdot = state
        self.qdot = np.array(qdot, dtype=float).reshape(self.r)
        self.set_q(q)

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
