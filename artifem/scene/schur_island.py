"""FEM bodies carried by rigid bodies, stepped with distributed FEM blocks (MPI).

The coupled island's step (artifem.scene.scene docstring) on masters z_m = [v_f; u]:
the free FEM dofs v_f of each body and the twists u of the rigid roots (few:
6 per root). An FEM node attached to a rigid body moves with it, v_s = G_s u, so
the FEM velocity is z = v_f + W u, W's columns w_j the nodal velocities of a
unit twist j (the rows of P on the FEM dofs). With A = M + h D + h^2 K
(D = alpha M + beta K_0) and b = M v + h f of a body (its semi-implicit step,
``integrators.step_system``), the master equations are

    A_ff v_f + (A W)_f u                        = b_f,
    W^T A (v_f + W u) + A_r u - G_m^T lambda    = W^T b + b_r,         G_m u = c,

A_r, b_r the rigid bodies' block (joints, force elements, gravity, K_geo with the
FEM slaves' forces) mapped to the roots. Eliminating v_f (A symmetric),

    S u - G_m^T lambda = W^T b + b_r - (A W)_f^T y,
    S = A_r + W^T A W - (A W)_f^T Z,      A_ff y = b_f,   A_ff Z = (A W)_f,

a small dense system solved with the joints and limits as in the direct step
(:func:`~artifem.scene.constraints.solve_constrained`), then v_f = y - Z u. The
FEM matrices stay distributed PETSc matrices; A_ff (A with the attached and fixed
rows and columns replaced by the identity) is solved by the scene's
:class:`~artifem.linear_solver.LinearSolver` (CG with algebraic multigrid by
default, or MUMPS), 1 + 6 x roots solves per body and step, y in increment form
(y = v_0 + A_ff^{-1} (b - A v_0)_f, so an iterative solver's tolerance bounds the
change, not the velocity). The rigid coordinates are replicated on every rank.

It takes the same step as the direct one (to the linear solver's tolerance:
tests/test_scene_schur.py, serial and on 2 ranks). Covered: FEM bodies, rigid
bodies (rigid attachments, joints and limits, force elements between rigid
frames), FEM nodes attached to dynamic or fixed rigid bodies. Not yet: nodes on a
prescribed body, reduced or embedded bodies, frame and lift attachments, paths
through FEM points and load elements in the island, the implicit integrator and
statics (each a clear error).
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc
from scipy import sparse

from artifem.errors import InputError
from artifem.integrators import step_system
from artifem.multibody.attachments import dof_positions
from artifem.multibody.rigid_body import skews
from artifem.scene.constraints import impulses_by_constraint, solve_constrained
from artifem.scene.layout import Layout

__all__ = ["SchurIsland"]


class _RigidPart:
    """The scene without its FEM bodies: what the rigid bodies' layout reads."""

    node_attachments = embedded_attachments = lift_attachments = frame_attachments = ()
    paths = loads = fem_bodies = reduced_bodies = ()

    def __init__(self, scene):
        self._scene = scene

    def __getattr__(self, name):
        return getattr(self._scene, name)


class SchurIsland:
    """The coupled island of FEM bodies and rigid bodies (module docstring)."""

    def __init__(self, scene, fem_bodies: list):
        unsupported = {
            "reduced bodies": [b for b in scene.reduced_bodies],
            "embedded attachments": scene.embedded_attachments,
            "lift attachments": scene.lift_attachments,
            "frame attachments": scene.frame_attachments,
            "point paths": scene.paths,
            "load elements": scene.loads,
        }
        unsupported["bodies with the hard incompressibility"] = [
            b for b in fem_bodies if b.volume_constraint is not None
        ]
        # the FEM bodies' rows stay on their ranks here: constraints act on rigid bodies only
        unsupported["constraints on FEM bodies (contact)"] = [
            c for c in scene.constraints if any(b is f for b in c.bodies for f in fem_bodies)
        ]
        found = [what for what, items in unsupported.items() if items]
        if found:
            raise InputError(
                f"the distributed (Schur) island takes FEM bodies, rigid bodies, "
                f"node attachments, joints and force elements; this scene also "
                f"has {', '.join(found)} (run it in serial with "
                f"island_solver='direct')"
            )
        self.scene, self.fem_bodies = scene, list(fem_bodies)
        self.rigid = Layout(_RigidPart(scene), [], [])
        known = {id(b) for b in self.fem_bodies}
        for att in scene.node_attachments:
            if id(att.fem) not in known:
                raise InputError(
                    f"node attachment {att.name!r}: FEM body {att.fem.name!r} is not in the scene"
                )
            if not any(att.body is b for b in scene.rigid_bodies):
                raise InputError(
                    f"node attachment {att.name!r}: rigid body {att.body.name!r} "
                    "is not in the scene"
                )
            root = self.rigid.root[id(att.body)]
            if root.motion == "prescribed":
                raise InputError(
                    f"node attachment {att.name!r}: nodes on the prescribed body "
                    f"{root.name!r} are not supported by the distributed island "
                    "yet (fix them, or run in serial with island_solver='direct')"
                )
        self._Aff: dict[int, PETSc.Mat] = {}

    # ---- one step ----------------------------------------------------------------------

    def step(self, h: float) -> dict:
        """Advance the island from t to t + h (module docstring); returns the constraints'
        impulses, as the direct step records them."""
        scene, R = self.scene, self.rigid
        t1 = scene.t + h
        targets = R.kinematic_targets(t1)
        for body, (_, _, twist) in targets.items():
            body.set_twist(twist)
        P = R.prolongation()
        P = P.toarray() if sparse.issparse(P) else np.asarray(P)
        z_k = R.known_velocities(h, targets)
        A_r, b_r, f_r = R.dynamics(h, t1)
        A_r = A_r.toarray() if sparse.issparse(A_r) else A_r
        S = P.T @ A_r @ P
        rhs = P.T @ (b_r - A_r @ z_k)
        if scene.geometric_stiffness:
            K_geo = R.geometric_stiffness(scene._with_reactions(f_r), P)
            S = S - h * h * (K_geo.toarray() if sparse.issparse(K_geo) else K_geo)
        parts = [self._fem_part(body, h, P) for body in self.fem_bodies]
        for part in parts:
            S, rhs = S + part["S"], rhs + part["rhs"]
            if scene.geometric_stiffness:
                S = S - h * h * part["K_geo"]
        rows = R.constraint_map.rows(P, z_k, h, scene.stabilization)
        u_m, lam, active = solve_constrained(
            scene._solver, S, rhs, rows, f"t = {scene.t:g}", memory=scene._active_sets
        )
        scene.last_solve = {
            "masters": u_m.size,
            "constraint_rows": active,
            "fem_solves": sum(p["solves"] for p in parts),
        }
        R.advance(P @ u_m + z_k, h, targets)
        for part in parts:
            self._advance_fem(part, u_m, h)
        return impulses_by_constraint(rows, lam)

    def _fem_part(self, body, h: float, P: np.ndarray) -> dict:
        """One body's contributions to S and the right-hand side, and what its update
        needs (module docstring)."""
        scene, R = self.scene, self.rigid
        n_m = P.shape[1]
        n_owned = body.V.dofmap.index_map.size_local
        A, b, applied = step_system(body, h)  # A: body.K, until the next assembly
        v = body.v.x.petsc_vec
        f_applied = applied.array.copy()  # f - D v, for K_geo
        # W: the nodal velocities of unit master twists, on the owned attached dofs
        W_local = np.zeros((3 * n_owned, n_m))
        non_free = np.zeros(3 * n_owned, dtype=bool)
        ones = v.duplicate()
        ones.set(1.0)
        body.zero_fixed(ones)
        non_free[ones.array == 0.0] = True
        K_geo = np.zeros((n_m, n_m))
        for att in scene.node_attachments:
            if att.fem is not body:
                continue
            owned = att.dofs < n_owned
            rows = (3 * att.dofs[owned][:, None] + np.arange(3)).ravel()
            non_free[rows] = True
            root = R.root[id(att.body)]
            if id(root) not in R.master_col:
                continue  # a fixed root: the nodes stay put
            o = R.rigid_offset[id(att.body)]
            G = att.jacobian().reshape(-1, 3, 6)[owned].reshape(-1, 6)
            W_local[rows] = G @ P[o : o + 6]
            # K_geo: sum_s [f_s]x [d_s]x on the root's rotation block (levers from the root)
            f = f_applied.reshape(-1, 3)[att.dofs[owned]]
            d = dof_positions(body)[att.dofs[owned]] - root.position
            block = np.einsum("nij,njk->ik", skews(f), skews(d)) if len(f) else np.zeros((3, 3))
            block = body.mesh.comm.allreduce(block, op=MPI.SUM)
            c0 = R.master_col[id(root)]
            K_geo[c0 + 3 : c0 + 6, c0 + 3 : c0 + 6] += block
        A_ff = self._free_matrix(body, A, non_free)
        solver = scene.linear_solver_for(body)
        # y = v_0 + A_ff^{-1} (b - A v_0)_f: the increment form
        v0 = v.copy()
        v0.array[non_free] = 0.0
        r = b.copy()
        A.mult(v0, applied)
        r.axpy(-1.0, applied)
        r.array[non_free] = 0.0
        y = v.duplicate()
        solver.solve(A_ff, r, y)
        y.array[non_free] = 0.0
        y.axpy(1.0, v0)
        Ws, Ys, Zs = [], [], []
        for j in range(n_m):
            w = v.duplicate()
            w.array[:] = W_local[:, j]
            Y = v.duplicate()
            A.mult(w, Y)
            Yf = Y.copy()
            Yf.array[non_free] = 0.0
            Z = v.duplicate()
            if Yf.norm() > 0.0:
                solver.solve(A_ff, Yf, Z)
                Z.array[non_free] = 0.0
            else:
                Z.set(0.0)
            Ws.append(w), Ys.append(Y), Zs.append(Z)
            Yf.destroy()
        # Y_i . Z_j: Z_j vanishes off the free rows, so this is (A W)_f^T Z
        S = np.array(
            [[Ws[i].dot(Ys[j]) - Ys[i].dot(Zs[j]) for j in range(n_m)] for i in range(n_m)]
        )
        rhs = np.array([Ws[i].dot(b) - Ys[i].dot(y) for i in range(n_m)])
        for vec in (applied, ones, r, v0, *Ys):
            vec.destroy()
        b.destroy()
        return {
            "body": body,
            "S": S,
            "rhs": rhs,
            "K_geo": K_geo,
            "y": y,
            "W": Ws,
            "Z": Zs,
            "solves": 1 + sum(1 for Z in Zs if Z.norm() > 0.0),
        }

    def _free_matrix(self, body, A: PETSc.Mat, non_free: np.ndarray) -> PETSc.Mat:
        """A with the attached and fixed rows and columns replaced by the identity, in one
        matrix per body kept across steps (the linear solver's operator)."""
        A_ff = self._Aff.get(id(body))
        if A_ff is None:
            A_ff = A.duplicate(copy=True)
            self._Aff[id(body)] = A_ff
        else:
            A.copy(A_ff, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        start = 3 * body.V.dofmap.index_map.local_range[0]
        A_ff.zeroRowsColumns((start + np.flatnonzero(non_free)).astype(PETSc.IntType), diag=1.0)
        return A_ff

    def _advance_fem(self, part: dict, u_m: np.ndarray, h: float) -> None:
        """v = y - Z u on the free dofs, W u on the attached ones, 0 on the fixed; the free
        dofs move by h v, the attached nodes to their bodies' new poses."""
        body = part["body"]
        v = body.v.x.petsc_vec
        v.set(0.0)
        v.axpy(1.0, part["y"])
        for w, Z, coefficient in zip(part["W"], part["Z"], u_m):
            v.axpy(-coefficient, Z)
            v.axpy(coefficient, w)
        body.zero_fixed(v)
        body.u.x.petsc_vec.axpy(h, v)
        n_owned = 3 * body.V.dofmap.index_map.size_local
        for att in self.scene.node_attachments:
            if att.fem is body:
                keep = (3 * att.dofs[att.dofs < n_owned // 3][:, None] + np.arange(3)).ravel()
                x = att.positions() - body.V.tabulate_dof_coordinates()[att.dofs]
                local = np.flatnonzero(att.dofs < n_owned // 3)
                body.u.x.petsc_vec.array[keep] = x[local].ravel()
        body.u.x.scatter_forward()
        body.v.x.scatter_forward()
        for vec in (part["y"], *part["W"], *part["Z"]):
            vec.destroy()
