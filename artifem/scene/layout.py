"""The scene's coordinates and the pieces of its step (artifem.scene.scene docstring).

:class:`Layout` indexes every coordinate of a :class:`~artifem.scene.Scene` in
the "all" vector z (FEM nodal velocities, reduced q', rigid twists), sorts
masters from slaves and known coordinates, and builds what the step needs at
the current configuration: the prolongation P, the known velocities z_k, the
bodies' blocks A_all and b_all, the path and load terms, the geometric
stiffness K_geo; the constraints' rows on these coordinates are its
:class:`~artifem.scene.constraint_map.ConstraintMap` (``constraint_map``). It also
moves the scene (advance, displace, place the slaves, save and restore).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc
from scipy import sparse

from artifem.errors import InputError, SingularSystem
from artifem.fem_body import FemBody
from artifem.incompressibility import hold_linearized
from artifem.integrators import reduced_step_system, step_system
from artifem.multibody.attachments import FemPoint, NodeAttachment, dof_positions, pose_gap
from artifem.multibody.point_paths import PointPath
from artifem.multibody.rigid_body import (
    Frame,
    RigidBody,
    dexp_so3,
    exp_so3,
    orthonormalize,
    skew,
    skews,
)
from artifem.reduction.rigid_lift import RigidLift
from artifem.scene.constraint_map import ConstraintMap
from artifem.scene.direct_solver import DENSE_MAX, SINGULAR


@dataclass
class _Slaves:
    """The nodes of one NodeAttachment, as the scene indexes them."""

    attachment: NodeAttachment
    rows: np.ndarray  # all-space rows (3 per node, node-major)


class Layout:
    """The coordinates of a scene's coupled island: all-space offsets, masters, slaves,
    roots (artifem.scene.scene docstring).

    Args:
        scene: the scene (its rigid bodies, attachments, joints, paths, loads).
        fem_bodies, reduced_bodies: the deformable bodies of the island (those that an
            attachment, path or load couples; the scene steps the others on their own).
    """

    def __init__(self, scene, fem_bodies: list, reduced_bodies: list):
        self.scene = scene
        self.fem_bodies, self.reduced_bodies = list(fem_bodies), list(reduced_bodies)
        self.collapsed_frames = []  # the frame attachments place_slaves could not place
        rigid = scene.rigid_bodies
        for body in self.fem_bodies:
            if body.mesh.comm.size != 1:
                raise NotImplementedError(
                    f"FEM body {body.name!r} runs on {body.mesh.comm.size} MPI ranks and is "
                    "coupled to other bodies (attachments, paths or loads): coupled islands "
                    "run in serial only for now; a body that nothing couples runs in parallel"
                )
        self.fixed = [b.fixed_components.copy() for b in fem_bodies]  # 3 node + component
        offset = 0
        self.fem_offset: dict[int, int] = {}
        self.fem_size: dict[int, int] = {}
        for body in fem_bodies:
            n = body.V.dofmap.index_map.size_local + body.V.dofmap.index_map.num_ghosts
            self.fem_offset[id(body)], self.fem_size[id(body)] = offset, 3 * n
            offset += 3 * n
        self.reduced_offset: dict[int, int] = {}
        for body in self.reduced_bodies:
            self.reduced_offset[id(body)] = offset
            offset += body.r
        self.rigid_offset: dict[int, int] = {}
        for body in rigid:
            self.rigid_offset[id(body)] = offset
            offset += 6
        self.n_all = offset
        #: a small scene (reduced and rigid bodies, tiny FEM bodies) keeps its matrices
        #: dense: a few small arrays, without scipy.sparse's per-operation overhead
        self.dense = self.n_all <= DENSE_MAX
        self._check_references()

        # Roots of the rigid attachment chains, in dependency order (masters first).
        chains = {id(b): _chain(b, scene.rigid_attachments, "attachment cycle") for b in rigid}
        self.root: dict[int, RigidBody] = {key: c[-1] for key, c in chains.items()}
        self.rigid_attachments = sorted(
            scene.rigid_attachments, key=lambda a: len(chains[id(a.slave)])
        )
        # Embedded bodies, slaves before their masters (deepest first).
        self.embedded = sorted(
            scene.embedded_attachments,
            key=lambda a: (
                -len(_chain(a.slave, scene.embedded_attachments, "embedded attachment cycle"))
            ),
        )

        # Masters: free FEM dofs, free reduced coordinates, then the dynamic roots.
        is_slave_row = np.zeros(self.n_all, dtype=bool)
        self.slaves: list[_Slaves] = []
        for att in scene.node_attachments:
            o = self.fem_offset[id(att.fem)]
            rows = (o + 3 * att.dofs[:, None] + np.arange(3)).ravel()
            is_slave_row[rows] = True
            self.slaves.append(_Slaves(att, rows))
        for att in self.embedded:
            o = self.fem_offset[id(att.slave)]
            is_slave_row[o : o + self.fem_size[id(att.slave)]] = True
        for att in scene.lift_attachments:
            is_slave_row[self.reduced_offset[id(att.reduced)] + att.columns] = True
        framed = {id(att.slave) for att in scene.frame_attachments}
        master_rows = []
        for body, fixed in zip(fem_bodies, self.fixed):
            o = self.fem_offset[id(body)]
            known = np.zeros(self.fem_size[id(body)], dtype=bool)
            known[fixed] = True
            rows = o + np.flatnonzero(~known)
            master_rows.append(rows[~is_slave_row[rows]])
        for body in self.reduced_bodies:
            rows = self.reduced_offset[id(body)] + np.arange(body.r)
            master_rows.append(rows[~is_slave_row[rows]])
        self.roots = [
            b for b in rigid if b.dynamic and self.root[id(b)] is b and id(b) not in framed
        ]
        for body in self.roots:
            master_rows.append(self.rigid_offset[id(body)] + np.arange(6))
        self.master_rows = np.concatenate(master_rows) if master_rows else np.zeros(0, int)
        self.n_masters = self.master_rows.size
        self.master_col = {
            id(b): int(np.searchsorted(self.master_rows, self.rigid_offset[id(b)]))
            for b in self.roots
        }
        # (rows sorted: FEM, reduced, then rigid bodies in order, so searchsorted finds them)
        assert np.all(np.diff(self.master_rows) > 0)
        self.free_fem = [
            (body, rows - self.fem_offset[id(body)]) for body, rows in zip(fem_bodies, master_rows)
        ]
        self.free_reduced = [
            (body, rows - self.reduced_offset[id(body)])
            for body, rows in zip(self.reduced_bodies, master_rows[len(fem_bodies) :])
        ]
        self._embedding_map = self._embedding_matrix()
        self._rest_x: dict = {}  # id(FEM body) -> its node coordinates X
        self._place_lifts()  # lift coordinates from the bodies' poses
        #: the constraints' rows on these coordinates (joints and limits, one kind of rows)
        self.constraint_map = ConstraintMap(self)

    # ---- matrices in the layout's format (dense when small, CSR otherwise) -------------

    def matrix(self, vals, rows, cols, shape):
        """The matrix of (value, row, column) triplets, repeated entries summed."""
        if self.dense:
            out = np.zeros(shape)
            np.add.at(out, (np.asarray(rows, dtype=np.intp), np.asarray(cols, dtype=np.intp)), vals)
            return out
        return sparse.csr_matrix((vals, (rows, cols)), shape=shape)

    def triplets(self, parts: list, shape):
        """:meth:`matrix` of a list of (vals, rows, cols) parts (none: zeros)."""
        if not parts:
            return self.zeros(shape)
        vals, rows, cols = (np.concatenate(x) for x in zip(*parts))
        return self.matrix(vals, rows, cols, shape)

    def zeros(self, shape):
        return np.zeros(shape) if self.dense else sparse.csr_matrix(shape)

    def fmt(self, X):
        """X (dense or sparse) in the layout's format."""
        if self.dense:
            return X.toarray() if sparse.issparse(X) else np.asarray(X)
        return sparse.csr_matrix(X)

    def vstack(self, blocks: list):
        return (
            np.vstack([self.fmt(b) for b in blocks])
            if self.dense
            else sparse.vstack(blocks).tocsr()
        )

    def kkt(self, K, G):
        """[[K, G^T], [G, 0]] (statics)."""
        if not G.shape[0]:
            return K
        if self.dense:
            return np.block([[K, G.T], [G, np.zeros((G.shape[0], G.shape[0]))]])
        return sparse.bmat([[K, G.T], [G, None]], format="csr")

    def _embedding_matrix(self):
        """Z_e (n_all x n_all): z_slave = G z_master of every embedded body (constant): G = W
        on a full master's blocked dofs, the dense W U on a reduced master's q."""
        blocks = []
        for att in self.embedded:
            o_s, o_m = self.fem_offset[id(att.slave)], self._body_offset(att.master)
            G = sparse.coo_matrix(att.jacobian())
            blocks.append((G.data, o_s + G.row, o_m + G.col))
        return self.triplets(blocks, (self.n_all, self.n_all))

    def _lift_matrix(self):
        """Z_l (n_all x n_all): g' = G_g(R) u of every lift, at the bodies' current poses."""
        rows, cols, vals = [], [], []
        for att in self.scene.lift_attachments:
            r = self.reduced_offset[id(att.reduced)] + att.columns
            c = self.rigid_offset[id(att.body)] + np.arange(6)
            rr, cc = np.meshgrid(r, c, indexing="ij")
            rows.append(rr.ravel()), cols.append(cc.ravel())
            vals.append(RigidLift.jacobian(att.body.rotation).ravel())
        return self.triplets(list(zip(vals, rows, cols)), (self.n_all, self.n_all))

    def _frame_matrix(self):
        """Z_f (n_all x n_all): u_b = J z_nodes of every frame-attached body, at the current
        configuration (FrameAttachment)."""
        rows, cols, vals = [], [], []
        for att in self.scene.frame_attachments:
            r0 = self.rigid_offset[id(att.slave)] + np.arange(6)
            o = self._body_offset(att.frame.body)
            for c, J in att.jacobian():
                rr, cc = np.meshgrid(r0, o + c, indexing="ij")
                rows.append(rr.ravel()), cols.append(cc.ravel()), vals.append(J.ravel())
        return self.triplets(list(zip(vals, rows, cols)), (self.n_all, self.n_all))

    def _body_offset(self, body) -> int:
        """The all-space offset of an FEM (blocked dofs) or reduced body (q)."""
        return self.fem_offset.get(id(body), self.reduced_offset.get(id(body)))

    @staticmethod
    def _chain(Z, X):
        """X + Z X + Z^2 X + ... (Z nilpotent: derived rows of derived rows, in any order)."""
        out, term = X.copy(), X
        for _ in range(Z.shape[0] + 1):
            term = Z @ term
            if (term.nnz if sparse.issparse(term) else np.count_nonzero(term)) == 0:
                return out
            out = out + term
        raise AssertionError("attachment chain did not terminate (a cycle?)")

    def _check_references(self) -> None:
        scene = self.scene
        fem_ids = {id(b) for b in scene.fem_bodies}
        rigid_ids = {id(b) for b in scene.rigid_bodies}
        attached: dict[tuple[int, int], str] = {}
        for att in scene.node_attachments:
            what = f"node attachment {att.name!r}"
            if id(att.fem) not in fem_ids:
                raise InputError(f"{what}: FEM body {att.fem.name!r} is not in the scene")
            if id(att.body) not in rigid_ids:
                raise InputError(f"{what}: rigid body {att.body.name!r} is not in the scene")
            fixed = np.intersect1d(att.dofs, att.fem.fixed_components // 3)
            if fixed.size:
                inverse = {d: n for n, d in att.fem._node_to_dof.items()}
                raise InputError(
                    f"{what}: nodes {[inverse[int(d)] for d in fixed[:10]]} of "
                    f"{att.fem.name!r} are fixed; a node is either fixed or "
                    "attached"
                )
            for node in att.nodes.tolist():
                key = (id(att.fem), node)
                if key in attached:
                    raise InputError(
                        f"node {node} of FEM body {att.fem.name!r} is attached "
                        f"twice: by {attached[key]!r} and by {att.name!r}"
                    )
                attached[key] = att.name
        slaves: dict[int, str] = {}
        for att in scene.rigid_attachments:
            what = f"rigid attachment {att.name!r}"
            for b in (att.slave, att.master):
                if id(b) not in rigid_ids:
                    raise InputError(f"{what}: rigid body {b.name!r} is not in the scene")
            if att.slave.motion != "dynamic":
                raise InputError(f"{what}: the slave {att.slave.name!r} is {att.slave.motion}")
            if id(att.slave) in slaves:
                raise InputError(
                    f"rigid body {att.slave.name!r} is attached twice: by "
                    f"{slaves[id(att.slave)]!r} and by {att.name!r}"
                )
            slaves[id(att.slave)] = att.name
        # The offsets were taken when the attachment was made: if a body moved since (a
        # prescribed body is placed on its trajectory only when it is added to the scene),
        # the slaves are no longer where the attachment puts them.
        for att in scene.node_attachments:
            x = dof_positions(att.fem)[att.dofs]
            gap = float(np.abs(x - att.positions()).max())
            if gap > 1e-9 * (1.0 + float(np.abs(att.offsets).max())):
                raise InputError(
                    f"node attachment {att.name!r}: the nodes are up to {gap:.3g} from where the "
                    f"attachment puts them; {att.body.name!r} or {att.fem.name!r} moved after the "
                    "attachment was made (a prescribed body takes its trajectory's pose when "
                    "added to the scene: add it before making the attachment)"
                )
        for att in scene.rigid_attachments:
            gap = pose_gap(att)
            if gap > 1e-9 * (1.0 + float(np.abs(att.offset).max())):
                raise InputError(
                    f"rigid attachment {att.name!r}: {att.slave.name!r} is {gap:.3g} off the pose "
                    f"the attachment gives it; a body moved after the attachment was made"
                )
        reduced_ids = {id(b) for b in scene.reduced_bodies}
        embedded: dict[int, str] = {}
        for att in scene.embedded_attachments:
            what = f"embedded attachment {att.name!r}"
            for b, ids in ((att.slave, fem_ids), (att.master, fem_ids | reduced_ids)):
                if id(b) not in ids:
                    raise InputError(f"{what}: FEM body {b.name!r} is not in the scene")
            if att.slave.fixed_components.size:
                raise InputError(
                    f"{what}: the embedded body {att.slave.name!r} has fixed nodes; "
                    "its nodes are either fixed or embedded"
                )
            if any(a.fem is att.slave for a in scene.node_attachments):
                raise InputError(
                    f"{what}: nodes of {att.slave.name!r} are also attached to a rigid body"
                )
            if id(att.slave) in embedded:
                raise InputError(
                    f"FEM body {att.slave.name!r} is embedded twice: by "
                    f"{embedded[id(att.slave)]!r} and by {att.name!r}"
                )
            embedded[id(att.slave)] = att.name
        lifted: dict[int, list] = {}
        for att in scene.lift_attachments:
            what = f"lift attachment {att.name!r}"
            if id(att.reduced) not in reduced_ids:
                raise InputError(f"{what}: reduced body {att.reduced.name!r} is not in the scene")
            if id(att.body) not in rigid_ids:
                raise InputError(f"{what}: rigid body {att.body.name!r} is not in the scene")
            for other in lifted.get(id(att.reduced), []):
                if np.intersect1d(other.columns, att.columns).size:
                    raise InputError(
                        f"{what}: the coordinates of {att.reduced.name!r} it drives "
                        f"are already driven by {other.name!r}"
                    )
            lifted.setdefault(id(att.reduced), []).append(att)
        framed: dict[int, str] = {}
        for att in scene.frame_attachments:
            what = f"frame attachment {att.name!r}"
            if id(att.slave) not in rigid_ids:
                raise InputError(f"{what}: rigid body {att.slave.name!r} is not in the scene")
            if id(att.frame.body) not in fem_ids | reduced_ids:
                raise InputError(f"{what}: FEM body {att.frame.body.name!r} is not in the scene")
            if id(att.slave) in framed or id(att.slave) in slaves:
                raise InputError(
                    f"rigid body {att.slave.name!r} is attached twice: by "
                    f"{framed.get(id(att.slave), slaves.get(id(att.slave)))!r} "
                    f"and by {att.name!r}"
                )
            framed[id(att.slave)] = att.name
            gap = pose_gap(att)
            if gap > 1e-9 * (1.0 + float(np.abs(att.offset).max())):
                raise InputError(
                    f"{what}: {att.slave.name!r} is {gap:.3g} off the pose the "
                    "frame gives it; a body moved after the attachment was made"
                )
        carried = [(a.name, a.body) for a in scene.node_attachments + scene.lift_attachments] + [
            (a.name, a.master) for a in scene.rigid_attachments
        ]
        for name, body in carried:
            if id(body) in framed:
                raise InputError(
                    f"attachment {name!r}: {body.name!r} follows a frame on an FEM "
                    f"body ({framed[id(body)]!r}); attach to that FEM body instead"
                )
        for body in scene.rigid_bodies:
            if body.massless and body.dynamic and id(body) not in framed.keys() | slaves.keys():
                raise InputError(
                    f"rigid body {body.name!r} is massless (a marker) but attached "
                    "to nothing: its step would be singular"
                )
        for path in scene.paths:
            for pt in path.points:
                if isinstance(pt, FemPoint) and id(pt.fem) not in fem_ids | reduced_ids:
                    raise InputError(
                        f"path {path.name!r}: FEM body {pt.fem.name!r} is not in the scene"
                    )
                if isinstance(pt, Frame) and pt.body is not None and id(pt.body) not in rigid_ids:
                    raise InputError(
                        f"path {path.name!r}: rigid body {pt.body.name!r} is not in the scene"
                    )
        for joint in scene.joints:
            for body in joint.bodies:
                if body is not None and id(body) not in rigid_ids:
                    raise InputError(
                        f"joint {joint.name!r} connects rigid body {body.name!r}, "
                        "which is not in the scene"
                    )

    # ---- per-step pieces ---------------------------------------------------------------

    def kinematic_targets(self, t1: float) -> dict:
        """Prescribed roots: (p, R, twist) at t1."""
        out = {}
        for body in self.scene.rigid_bodies:
            if body.motion == "prescribed":
                s = body.prescribed_state(t1)
                out[body] = (
                    s.position,
                    s.rotation,
                    np.concatenate([s.velocity, s.angular_velocity]),
                )
        return out

    def prolongation(self):
        """P (n_all x n_masters) at the current poses (artifem.scene.scene docstring)."""
        rows = [self.master_rows]
        cols = [np.arange(self.n_masters)]
        vals = [np.ones(self.n_masters)]

        def carried(all_rows: np.ndarray, d: np.ndarray, root: RigidBody) -> None:
            """3 rows per point d (n, 3) relative to the root: [1, -[d]x] on its 6 columns."""
            c0 = self.master_col[id(root)]
            n = len(d)
            G = np.zeros((n, 3, 6))
            G[:, :, :3] = np.eye(3)
            G[:, :, 3:] = -skews(d)
            rows.append(np.repeat(all_rows.reshape(n, 3), 6, axis=1).ravel())
            cols.append(np.tile(c0 + np.arange(6), 3 * n))
            vals.append(G.ravel())

        for s in self.slaves:
            root = self.root[id(s.attachment.body)]
            if root.dynamic:
                carried(s.rows, s.attachment.positions() - root.position, root)
        for att in self.rigid_attachments:
            root = self.root[id(att.slave)]
            if root.dynamic:
                o = self.rigid_offset[id(att.slave)]
                carried(o + np.arange(3), (att.slave.position - root.position)[None], root)
                c0 = self.master_col[id(root)]
                rows.append(o + 3 + np.arange(3))
                cols.append(c0 + 3 + np.arange(3))
                vals.append(np.ones(3))
        P0 = self.matrix(
            np.concatenate(vals),
            np.concatenate(rows),
            np.concatenate(cols),
            (self.n_all, self.n_masters),
        )
        # rows derived from others: embedded FEM bodies (W), lift coordinates (G_g) and
        # frame-attached bodies (J)
        if self.embedded or self.scene.lift_attachments or self.scene.frame_attachments:
            Z = self._embedding_map + self._lift_matrix() + self._frame_matrix()
            return self.fmt(self._chain(self.fmt(Z), P0))
        return P0

    def known_velocities(self, h: float, targets: dict) -> np.ndarray:
        """z_k: prescribed twists at t1, secant velocities of slave nodes of prescribed roots."""
        z = np.zeros(self.n_all)
        for body, (_, _, twist) in targets.items():
            o = self.rigid_offset[id(body)]
            z[o : o + 6] = twist
        for att in self.rigid_attachments:
            root = self.root[id(att.slave)]
            if root in targets:
                p1, R1, twist = targets[root]
                d1 = R1 @ root.rotation.T @ (att.slave.position - root.position)
                o = self.rigid_offset[id(att.slave)]
                z[o : o + 3] = twist[:3] + np.cross(twist[3:], d1)
                z[o + 3 : o + 6] = twist[3:]
        for s in self.slaves:
            root = self.root[id(s.attachment.body)]
            if root in targets:
                p1, R1, _ = targets[root]
                x0 = s.attachment.positions()
                x1 = p1 + (x0 - root.position) @ (R1 @ root.rotation.T).T
                z[s.rows] = ((x1 - x0) / h).ravel()
        for att in self.scene.lift_attachments:  # g is linear in (p, R): the secant
            root = self.root[id(att.body)]
            if root in targets:
                p1, R1, _ = targets[root]
                turn = R1 @ root.rotation.T
                g1 = att.lift.coordinates(
                    p1 + turn @ (att.body.position - root.position), turn @ att.body.rotation
                )
                z[self.reduced_offset[id(att.reduced)] + att.columns] = (g1 - att.coordinates()) / h
        if self.embedded or self.scene.frame_attachments:
            z = self._chain(self.fmt(self._embedding_map + self._frame_matrix()), z)
        return z

    def _rigid_wrenches(self, t1: float, h: float | None, A, b, A_pos=None):
        """Force elements: wrenches into b (times h, or 1 for statics), Jacobian blocks into
        A (-h D - h^2 K, or -K for statics), and their position parts -h^2 K into ``A_pos``
        if given; returns the wrench per body id."""
        scene = self.scene
        forces = {}
        known = {id(x) for x in scene.rigid_bodies}
        scale = 1.0 if h is None else h
        for element in scene.forces:
            for body, wrench in element.wrenches(t1):
                wrench = _checked(element, known, body, wrench, (6,))
                o = self.rigid_offset[id(body)]
                b[o : o + 6] += scale * wrench
                forces[id(body)] = forces.get(id(body), np.zeros(6)) + wrench
            for bi, bj, K, D in getattr(element, "jacobians", lambda t: ())(t1):
                K, D = (
                    _checked(element, known, bi, np.zeros((6, 6)) if X is None else X, (6, 6), bj)
                    for X in (K, D)
                )
                i, j = self.rigid_offset[id(bi)], self.rigid_offset[id(bj)]
                if h is None:
                    A.append((i, j, -K))
                else:
                    A.append((i, j, -h * D - h * h * K))
                    b[i : i + 6] -= h * D @ bj.twist
                    if A_pos is not None:
                        A_pos.append((i, j, -h * h * K))
        return forces

    def dynamics(self, h: float, t1: float, linearized: bool = True, positional: bool = False):
        """A_all, b_all (artifem.scene.scene docstring) and the applied forces f_all (for K_geo);
        ``linearized=False`` at Newton's trial states (:func:`~artifem.integrators.step_system`).
        With ``positional``, a fourth item: the part of A_all that comes from the forces'
        position derivatives, -h^2 df/dq (FEM and reduced h^2 K, force elements' and paths'
        -h^2 K); A_all minus it is M - h df/dz (the implicit step's exact Jacobian)."""
        scene = self.scene
        blocks, b, f_all = [], np.zeros(self.n_all), np.zeros(self.n_all)
        pos_blocks: list = []
        for body in self.fem_bodies:  # integrators.step_system: A, b, f - D v
            o, n = self.fem_offset[id(body)], self.fem_size[id(body)]
            A_body, b_body, applied = step_system(body, h, linearized)
            b[o : o + n] = b_body.array[:n]
            f_all[o : o + n] = applied.array[:n]
            blocks.append(_csr(A_body))
            if positional:  # A = M + h D + h^2 K: its h^2 K
                pos_blocks.append(blocks[-1] - _mass(body) - h * _damping(body))
            b_body.destroy()
            applied.destroy()
        for body in self.reduced_bodies:  # the same, dense r x r
            o, r = self.reduced_offset[id(body)], body.r
            A_body, b[o : o + r], f_all[o : o + r] = reduced_step_system(body, h, linearized)
            blocks.append(A_body)
            if positional:
                pos_blocks.append(A_body - body.M - h * body.damping)
        rigid_blocks = []
        for body in scene.rigid_bodies:
            o = self.rigid_offset[id(body)]
            if not body.dynamic:
                rigid_blocks.append(np.zeros((6, 6)))
                continue
            M, D, u = body.mass_matrix(), body.gyroscopic_damping(), body.twist
            f = body.gyroscopic_wrench()
            f[:3] += body.mass * scene.gravity
            rigid_blocks.append(M - h * D)
            b[o : o + 6] += M @ u + h * (f - D @ u)
            f_all[o : o + 6] += f
        extra: list = []
        extra_pos: list | None = [] if positional else None
        element_wrenches = self._rigid_wrenches(t1, h, extra, b, extra_pos)
        for key, wrench in element_wrenches.items():
            o = self.rigid_offset[key]
            f_all[o : o + 6] += wrench
        A = self._stack(blocks, rigid_blocks, extra)
        if positional:
            A_pos = self._stack(pos_blocks, [np.zeros((6, 6))] * len(rigid_blocks), extra_pos)
        if scene.paths:
            F, K, D = self.path_terms(t1, h)
            z = self.current_velocities()
            b += h * F - h * (D @ z)
            A = self.fmt(A - h * D - h * h * K)
            if positional:
                A_pos = self.fmt(A_pos - h * h * K)
            f_all += F
        if scene.loads:  # explicit in the step: b += h F
            F = self.load_vector(t1)
            b += h * F
            f_all += F
        return (A, b, f_all, A_pos) if positional else (A, b, f_all)

    def gyroscopic_stiffness(self):
        """d f_gyro / dtheta of every dynamic rigid body (all-space, the rotation blocks):
        f_gyro = -w x (R I R^T w) turns with the body, [w]x ([I_w w]x - I_w [w]x)."""
        parts = []
        for body in self.scene.rigid_bodies:
            if body.dynamic and not body.massless:
                w = body.angular_velocity
                Iw = body.inertia_world()
                K = skew(w) @ (skew(Iw @ w) - Iw @ skew(w))
                o = self.rigid_offset[id(body)] + 3
                r, c = np.meshgrid(o + np.arange(3), o + np.arange(3), indexing="ij")
                parts.append((K.ravel(), r.ravel(), c.ravel()))
        return self.triplets(parts, (self.n_all, self.n_all))

    def rotation_jacobian(self, z_m: np.ndarray, h: float):
        """T (n_masters x n_masters): the master displacements of :meth:`advance` per unit
        h z_m change, identity but on each dynamic root's rotation, whose update
        R = exp(h [w]x) R_0 turns by dexp(h w) h dw (the left Jacobian)."""
        T = np.eye(self.n_masters) if self.dense else sparse.identity(self.n_masters, format="lil")
        for body in self.roots:
            c = self.master_col[id(body)] + 3
            T[c : c + 3, c : c + 3] = dexp_so3(h * z_m[c : c + 3])
        return self.fmt(T)

    @property
    def volume_constraints(self) -> list:
        """(body, its volume constraint) of the full and reduced bodies with hard
        incompressibility."""
        return [
            (b, b.volume_constraint)
            for b in self.fem_bodies + self.reduced_bodies
            if b.volume_constraint is not None
        ]

    def hold_volumes(
        self,
        z: np.ndarray,
        lam: np.ndarray,
        P,
        resolve,
        h: float,
        stop_when_indefinite: bool = False,
    ) -> int | None:
        """The linearized volume constraints of the step (:func:`~artifem.incompressibility.
        hold_linearized`) for every hard-incompressible body of the island together: a
        pressure change dp acts as the force h G^T dp on its body's coordinates (``force_rows``
        of its constraint), the island's KKT system (factored, joints' active rows kept:
        ``resolve``) gives the velocities of everything. ``z`` (all velocities) and ``lam``
        (joint impulses) are corrected in place; StepFailed when the tolerance is not
        reached (``stop_when_indefinite`` and the return value: see there). With z = 0 and
        the constraints at the step's end (:meth:`project_volumes`) it is one Newton
        iteration of the post-stabilization."""
        views = [(*self.span(body), vc) for body, vc in self.volume_constraints]
        last = {}

        def respond(d):
            rhs = np.zeros(self.n_all)
            for (o, n, vc), dk in zip(views, d):
                rhs[o : o + n] = vc.force_rows(dk, h)
            y_m, mu = resolve(np.asarray(P.T @ rhs).ravel())
            last["y"], last["mu"] = np.asarray(P @ y_m).ravel(), mu
            return [vc.rate_rows(last["y"][o : o + n], h) for o, n, vc in views]

        def accept(alpha):
            z[:] += alpha * last["y"]
            lam[:] += alpha * last["mu"]

        c0 = [vc.linearized_rows(z[o : o + n], h) for o, n, vc in views]
        return hold_linearized(
            [vc for *_, vc in views],
            c0,
            respond,
            accept,
            MPI.COMM_SELF,
            stop_when_indefinite=stop_when_indefinite,
        )

    def project_volumes(
        self, z: np.ndarray, lam: np.ndarray, P, resolve, h: float, targets: dict, start
    ) -> None:
        """Post-stabilization of the island's step (``integrators._project_volumes`` for a
        body alone): while a hard-incompressible body's volumes at the step's end are off
        by more than its ``step_tol``, at most ``Incompressible.projections`` times, the
        pressure impulses dp with g(u) + h^2 G A^-1 G^T dp = 0 (G at the end, the step's
        KKT factorization kept: :meth:`hold_volumes` on z = 0) correct z, and the step is
        redone from ``start`` (:meth:`save` before :meth:`advance`) with it. What is still
        off the scene's health check sees."""
        for _ in range(max(vc.spec.projections for _, vc in self.volume_constraints)):
            for _, vc in self.volume_constraints:
                vc.at_current_state()
            if all(vc.violation() <= vc.spec.step_tol for _, vc in self.volume_constraints):
                return
            for _, vc in self.volume_constraints:
                vc.at_current_state(rows=True)
            dz = np.zeros_like(z)
            if self.hold_volumes(dz, lam, P, resolve, h, stop_when_indefinite=True) is None:
                return
            z += dz
            self.restore(start)
            self.advance(z, h, targets)

    def mass_matrix(self):
        """M_all: the bodies' mass blocks at the current configuration (FEM lumped or
        consistent M, reduced M~, rigid [[m 1, 0], [0, I_world]]; zero for bodies that do
        not move by dynamics)."""
        blocks = [_mass(body) for body in self.fem_bodies]
        blocks += [body.M for body in self.reduced_bodies]
        rigid = [
            body.mass_matrix() if body.dynamic else np.zeros((6, 6))
            for body in self.scene.rigid_bodies
        ]
        return self._stack(blocks, rigid, [])

    def span(self, body) -> tuple[int, int] | None:
        """(offset, size) of a body's coordinates in the all vector; None if not a body of
        the scene."""
        key = id(body)
        if key in self.fem_offset:
            return self.fem_offset[key], self.fem_size[key]
        if key in self.reduced_offset:
            return self.reduced_offset[key], body.r
        if key in self.rigid_offset:
            return self.rigid_offset[key], 6
        return None

    def _load_span(self, element, body) -> tuple[int, int]:
        span = self.span(body)
        if span is None:
            raise InputError(
                f"load element {type(element).__name__} loads "
                f"{getattr(body, 'name', body)!r}, which is not a body of this "
                "scene or not among the element's ``bodies``"
            )
        return span

    def load_vector(self, t: float) -> np.ndarray:
        """The load elements' forces at time t, all-space (LoadElement)."""
        F = np.zeros(self.n_all)
        for element in self.scene.loads:
            for body, f in element.master_loads(t):
                o, n = self._load_span(element, body)
                f = np.asarray(f, dtype=float).ravel()
                if f.shape != (n,) or not np.all(np.isfinite(f)):
                    raise InputError(
                        f"load element {type(element).__name__}: expected {n} "
                        f"finite values for {body.name!r}, got shape {f.shape}"
                    )
                F[o : o + n] += f
        return F

    def load_jacobian(self, t: float):
        """dF/dx (n_all x n_all) of the load elements that give ``master_load_jacobians(t)``
        (e.g. a follower pressure); the others are explicit (LoadElement)."""
        parts = []
        for element in self.scene.loads:
            for bi, bj, K in getattr(element, "master_load_jacobians", lambda t: ())(t):
                (oi, ni), (oj, nj) = self._load_span(element, bi), self._load_span(element, bj)
                K = sparse.coo_matrix(K)
                if K.shape[0] > ni or K.shape[1] > nj:
                    raise InputError(
                        f"load element {type(element).__name__}: a "
                        f"{K.shape} Jacobian block for {bi.name!r}, {bj.name!r} "
                        f"({ni} x {nj} coordinates)"
                    )
                parts.append((K.data, oi + K.row, oj + K.col))
        return self.triplets(parts, (self.n_all, self.n_all))

    def current_velocities(self) -> np.ndarray:
        """z: the FEM nodal velocities and the rigid twists (all-space)."""
        z = np.zeros(self.n_all)
        for body in self.fem_bodies:
            o, n = self.fem_offset[id(body)], self.fem_size[id(body)]
            z[o : o + n] = body.v.x.array[:n]
        for body in self.reduced_bodies:
            o = self.reduced_offset[id(body)]
            z[o : o + body.r] = body.qdot
        for body in self.scene.rigid_bodies:
            o = self.rigid_offset[id(body)]
            z[o : o + 6] = body.twist
        return z

    def path_map(self, path: "PointPath") -> tuple[np.ndarray, np.ndarray]:
        """(idx, G): x_a' = G z[idx] for the path's points (artifem.scene.scene docstring),
        idx the all-space coordinates they move with, G (3n x len(idx)) dense."""
        rows, cols, vals = [], [], []
        for i, pt in enumerate(path.points):
            if isinstance(pt, FemPoint) and pt.reduced:
                o = self.reduced_offset[id(pt.fem)]
                r = pt.G.shape[1]
                rows.append(np.repeat(3 * i + np.arange(3), r))
                cols.append(np.tile(o + np.arange(r), 3))
                vals.append(pt.G.ravel())
            elif isinstance(pt, FemPoint):
                o = self.fem_offset[id(pt.fem)]
                w, d = pt.weights.weights, pt.weights.dofs
                for c in range(3):
                    rows.append(np.full(d.size, 3 * i + c))
                    cols.append(o + 3 * d + c)
                    vals.append(w)
            elif isinstance(pt, Frame) and pt.body is not None:
                o = self.rigid_offset[id(pt.body)]
                Gi = pt.jacobian()
                r, c = np.meshgrid(3 * i + np.arange(3), o + np.arange(6), indexing="ij")
                rows.append(r.ravel()), cols.append(c.ravel()), vals.append(Gi.ravel())
        if not vals:
            return np.zeros(0, dtype=int), np.zeros((3 * len(path.points), 0))
        idx, where = np.unique(np.concatenate(cols), return_inverse=True)
        G = np.zeros((3 * len(path.points), idx.size))
        np.add.at(G, (np.concatenate(rows), where), np.concatenate(vals))
        return idx, G

    def path_terms(self, t: float, h: float | None):
        """All paths at time t: F = G^T f (all-space), K = G^T K_p G + K_r and D = G^T D_p G
        (n_all x n_all, the derivatives of F by the positions and the velocities). A path's
        terms are small dense blocks on the coordinates its points move with
        (:meth:`path_map`), summed once."""
        shape = (self.n_all, self.n_all)
        F = np.zeros(self.n_all)
        K_parts, D_parts = [], []

        def add(parts, M, rows, cols):
            parts.append(
                (np.asarray(M).ravel(), np.repeat(rows, len(cols)), np.tile(cols, len(rows)))
            )

        for path in self.scene.paths:
            result = path.evaluate(t)
            idx, G = self.path_map(path)
            np.add.at(F, idx, G.T @ result.forces.ravel())
            add(K_parts, G.T @ result.stiffness @ G, idx, idx)
            add(D_parts, G.T @ result.damping @ G, idx, idx)
            # rigid frames: the levers turn with the body (point_force_wrenches' extra terms)
            for i, pt in enumerate(path.points):
                if not (isinstance(pt, Frame) and pt.body is not None):
                    continue
                own = self.rigid_offset[id(pt.body)] + np.arange(6)
                add(K_parts, pt.wrench_stiffness(result.forces[i]), own, own)
                # K_bc[:, 3:] -= sum_{a on b} G_a^T D_a,i [w]x [r]x for column body c = i's
                Dcol = G.T @ result.damping[:, 3 * i : 3 * i + 3]
                add(
                    K_parts,
                    -Dcol @ (skew(pt.body.angular_velocity) @ skew(pt.lever())),
                    idx,
                    own[3:],
                )
        return F, self.triplets(K_parts, shape), self.triplets(D_parts, shape)

    def static_forces(self, t: float, tangent: bool):
        """f_all (FEM -dPi/du; rigid m g plus force elements) and, if asked, K_all = -df/dq."""
        scene = self.scene
        blocks, f_all = [], np.zeros(self.n_all)
        for body in self.fem_bodies:
            o, n = self.fem_offset[id(body)], self.fem_size[id(body)]
            body.assemble(tangent=tangent)
            f_all[o : o + n] = -body.R.array[:n]
            if tangent:
                blocks.append(_csr(body.K))
        for body in self.reduced_bodies:
            o = self.reduced_offset[id(body)]
            f_all[o : o + body.r] = body.force()
            if tangent:
                blocks.append(body.tangent())
        for body in scene.rigid_bodies:
            if body.dynamic:
                o = self.rigid_offset[id(body)]
                f_all[o : o + 3] += body.mass * scene.gravity
        extra: list = []
        self._rigid_wrenches(t, None, extra, f_all)
        K_path = None
        if scene.paths:
            F, K_path, _ = self.path_terms(t, None)
            f_all += F  # statics: whole wrenches on rigid rows
        if scene.loads:
            f_all += scene.load_factor * self.load_vector(t)  # ramped with the other loads
        if not tangent:
            return f_all, None
        zeros = [np.zeros((6, 6)) for _ in scene.rigid_bodies]
        K_all = self._stack(blocks, zeros, extra)
        if K_path is not None:
            K_all = self.fmt(K_all - K_path)
        if scene.loads:
            K_all = self.fmt(K_all - scene.load_factor * self.load_jacobian(t))
        return f_all, K_all

    def _stack(self, fem_blocks, rigid_blocks, extra):
        """The block-diagonal A_all of the bodies' blocks (in all-space order) plus the
        force elements' 6 x 6 blocks ``extra`` (i, j, X), built as one COO matrix."""
        rows, cols, vals, o = [], [], [], 0
        for block in fem_blocks:  # FEM (sparse) and reduced (dense) bodies
            coo = sparse.coo_matrix(block)
            rows.append(o + coo.row), cols.append(o + coo.col), vals.append(coo.data)
            o += block.shape[0]
        six = np.arange(6)
        for block in rigid_blocks:
            r, c = np.meshgrid(o + six, o + six, indexing="ij")
            rows.append(r.ravel()), cols.append(c.ravel()), vals.append(np.ravel(block))
            o += 6
        for i, j, X in extra:
            r, c = np.meshgrid(i + six, j + six, indexing="ij")
            rows.append(r.ravel()), cols.append(c.ravel()), vals.append(X.ravel())
        return self.triplets(list(zip(vals, rows, cols)), (self.n_all, self.n_all))

    def geometric_stiffness(self, f_all: np.ndarray, P):
        """K_geo on the masters (artifem.scene.scene docstring): sum_s [f_s]x [d_s]x on each
        dynamic root's rotation block, for the applied forces f_all on the slaves (an embedded
        body's forces first moved to its master's coordinates, G^T f_s with G = W or W U; a lift
        as levers R_k)."""
        K_frames = None
        if self.scene.frame_attachments:
            f_all = f_all.copy()
            rows, cols, vals = [], [], []
            for att in self.scene.frame_attachments:  # leaves: before the embedded bodies
                wrench = f_all[self.rigid_offset[id(att.slave)] + np.arange(6)]
                o = self._body_offset(att.frame.body)
                for c, J in att.jacobian():
                    f_all[o + c] += J.T @ wrench
                c, Kf = att.stiffness(wrench)
                rr, cc = np.meshgrid(o + c, o + c, indexing="ij")
                rows.append(rr.ravel()), cols.append(cc.ravel()), vals.append(Kf.ravel())
            K_frames = self.triplets(list(zip(vals, rows, cols)), (self.n_all, self.n_all))
            K_frames = self.fmt(P.T @ K_frames @ P)
        if self.embedded:
            f_all = f_all.copy()
            for att in self.embedded:  # slaves before their masters
                o_s, o_m = self.fem_offset[id(att.slave)], self._body_offset(att.master)
                G = att.jacobian()  # f_m += G^T f_s (W, or W U)
                f_all[o_m : o_m + G.shape[1]] += G.T @ f_all[o_s : o_s + G.shape[0]]
        K = {}
        for att in self.scene.lift_attachments:
            root = self.root[id(att.body)]
            if root.dynamic:
                f = f_all[self.reduced_offset[id(att.reduced)] + att.columns].reshape(4, 3)
                levers = np.vstack([att.body.position - root.position, att.body.rotation.T])
                K[id(root)] = K.get(id(root), 0.0) + np.einsum(
                    "nij,njk->ik", skews(f), skews(levers)
                )
        for s in self.slaves:
            root = self.root[id(s.attachment.body)]
            if root.dynamic:
                f = f_all[s.rows].reshape(-1, 3)
                d = s.attachment.positions() - root.position
                K[id(root)] = K.get(id(root), 0.0) + np.einsum("nij,njk->ik", skews(f), skews(d))
        for att in self.rigid_attachments:
            root = self.root[id(att.slave)]
            if root.dynamic:
                o = self.rigid_offset[id(att.slave)]
                K[id(root)] = K.get(id(root), 0.0) + skew(f_all[o : o + 3]) @ skew(
                    att.slave.position - root.position
                )
        rows, cols, vals = [], [], []
        for key, block in K.items():
            c0 = self.master_col[key] + 3
            r, c = np.meshgrid(c0 + np.arange(3), c0 + np.arange(3), indexing="ij")
            rows.append(r.ravel()), cols.append(c.ravel()), vals.append(block.ravel())
        K_roots = self.triplets(list(zip(vals, rows, cols)), (self.n_masters, self.n_masters))
        return K_roots if K_frames is None else self.fmt(K_roots + K_frames)

    # ---- updates -----------------------------------------------------------------------

    def advance(self, z: np.ndarray, h: float, targets: dict) -> None:
        """Velocities from z; free FEM dofs, free reduced coordinates and dynamic roots move
        by h z; prescribed bodies go to their targets; slaves are set from their masters."""
        for body, free in self.free_fem:
            o, n = self.fem_offset[id(body)], self.fem_size[id(body)]
            body.v.x.array[:n] = z[o : o + n]
            body.u.x.array[free] += h * z[o + free]
        for att in self.embedded:
            o, n = self.fem_offset[id(att.slave)], self.fem_size[id(att.slave)]
            att.slave.v.x.array[:n] = z[o : o + n]
        for body, free in self.free_reduced:
            o = self.reduced_offset[id(body)]
            body.qdot = z[o : o + body.r].copy()
            body.q[free] += h * z[o + free]
        for body in self.scene.rigid_bodies:
            o = self.rigid_offset[id(body)]
            if body.motion == "prescribed":
                p1, R1, twist = targets[body]
                body.position, body.rotation = p1, R1
                body.set_twist(twist)
            elif body.dynamic:
                body.set_twist(z[o : o + 6])
                if any(body is r for r in self.roots):
                    body.advance_pose(h)
        self.place_slaves()

    def _rest_positions(self, body) -> np.ndarray:
        """The FEM body's node coordinates X (tabulated once per layout)."""
        if id(body) not in self._rest_x:
            self._rest_x[id(body)] = body.V.tabulate_dof_coordinates()
        return self._rest_x[id(body)]

    def place_slaves(self) -> None:
        for att in self.rigid_attachments:  # dependency order
            att.slave.position, att.slave.rotation = att.pose()
        for s in self.slaves:
            att = s.attachment
            u = att.fem.u.x.array.reshape(-1, 3)
            u[att.dofs] = att.positions() - self._rest_positions(att.fem)[att.dofs]
        self._place_lifts()  # a reduced master's lift columns
        for att in reversed(self.embedded):  # masters before their slaves
            att.slave.u.x.array[: att.W.shape[0]] = att.displacement()
        # leaves: after every FEM body; a frame whose support collapsed (a Newton trial
        # too long, a step too large) has no pose: its slave stays, inverted() says so
        self.collapsed_frames = [
            att for att in self.scene.frame_attachments if att.frame.collapsed()
        ]
        for att in self.scene.frame_attachments:
            if not any(att is c for c in self.collapsed_frames):
                att.slave.position, att.slave.rotation = att.pose()
        for body in self.fem_bodies:
            body.u.x.scatter_forward()
            body.v.x.scatter_forward()

    def _place_lifts(self) -> None:
        for att in self.scene.lift_attachments:
            att.reduced.q[att.columns] = att.coordinates()
        for body in self.reduced_bodies:
            body.set_q(body.q)

    def displace(self, dq: np.ndarray) -> None:
        """Master displacement (static solve, finite differences); see displace_masters."""
        if dq.shape != (self.n_masters,):
            raise InputError(f"expected {self.n_masters} master displacements, got {dq.shape}")
        for body, free in self.free_fem:
            o = self.fem_offset[id(body)]
            idx = np.searchsorted(self.master_rows, o + free)
            body.u.x.array[free] += dq[idx]
        for body, free in self.free_reduced:
            o = self.reduced_offset[id(body)]
            body.q[free] += dq[np.searchsorted(self.master_rows, o + free)]
        for body in self.roots:
            c = self.master_col[id(body)]
            body.position = body.position + dq[c : c + 3]
            body.rotation = orthonormalize(exp_so3(dq[c + 3 : c + 6]) @ body.rotation)
        self.place_slaves()

    def save(self):
        return (
            [b.u.x.array.copy() for b in self.fem_bodies],
            [(b.position.copy(), b.rotation.copy()) for b in self.scene.rigid_bodies],
            [b.q.copy() for b in self.reduced_bodies],
        )

    def restore(self, saved) -> None:
        for body, u in zip(self.fem_bodies, saved[0]):
            body.u.x.array[:] = u
        for body, (p, R) in zip(self.scene.rigid_bodies, saved[1]):
            body.position, body.rotation = p, R
        for body, q in zip(self.reduced_bodies, saved[2]):
            body.set_q(q)

    def master_scale(self) -> float:
        vals = [np.abs(b.u.x.array).max() for b in self.fem_bodies if b.u.x.array.size]
        vals += [np.abs(b.q).max() for b in self.reduced_bodies if b.r]
        vals += [np.abs(b.position).max() for b in self.roots]
        return max(vals, default=1.0)

    def describe_motions(self, N: np.ndarray) -> str:
        """The motions spanned by the orthonormal columns of ``N`` (n_masters x k: the
        :meth:`free_motions` of a singular system) in words, body by body: a rigid body's
        translations and rotations (world directions where they are one or two), a
        deformable body's nodes or reduced coordinates; bodies attached to a rigid body
        move with it."""
        parts = []
        start = 0
        for body, rows in self.free_fem:
            block = N[start : start + len(rows)]
            moved = np.linalg.norm(block, axis=1) > 1e-6
            if moved.any():
                nodes = np.unique(rows[moved] // 3).size
                parts.append(f"{nodes} node{'s' * (nodes > 1)} of {body.name!r} moving")
            start += len(rows)
        for body, rows in self.free_reduced:
            moved = np.linalg.norm(N[start : start + len(rows)], axis=1) > 1e-6
            if moved.any():
                parts.append(f"reduced coordinates {rows[moved].tolist()} of {body.name!r} moving")
            start += len(rows)
        for body in self.roots:
            c = self.master_col[id(body)]
            motions = [_directions(N[c + k : c + k + 3], noun) for k, noun in ((0, "t"), (3, "r"))]
            if any(motions):
                parts.append(f"{body.name!r} " + " and ".join(m for m in motions if m))
        return "; ".join(parts) if parts else "no body's coordinates (the constraint rows)"

    def unresisted(self, error: SingularSystem, A, advice: str) -> SingularSystem:
        """``error`` with the motions nothing resists named (:meth:`describe_motions` of
        :meth:`free_motions`), ``advice`` after them; ``error`` itself where they are not
        known."""
        N = self.free_motions(error, A)
        if N is None:
            return error
        what = str(error).removesuffix(f"; {SINGULAR}")
        return SingularSystem(
            f"{what}; nothing resists {self.describe_motions(N)}: {advice}",
            iterations=error.iterations,
        )

    def free_motions(self, error: SingularSystem, A) -> np.ndarray | None:
        """Orthonormal master motions (n_masters x k) that the singular system of ``error``
        leaves free: its null space's master part, when its matrix is the masters' ``A``
        or a KKT matrix bordering it; else None (a Schur complement, a sparse system)."""
        N = error.null_space()
        n = self.n_masters
        if N is None or N.shape[0] < n:
            return None
        A = A.toarray() if sparse.issparse(A) else np.asarray(A)
        scale = max(np.abs(A).max(initial=0.0), 1e-300)
        if not np.allclose(error.matrix[:n, :n], A, rtol=0.0, atol=1e-12 * scale):
            return None
        U, sigma, _ = np.linalg.svd(N[:n], full_matrices=False)
        U = U[:, sigma > 1e-6 * max(sigma.max(initial=0.0), 1e-300)]
        return U if U.shape[1] else None

    def neutral_stiffness(self, error: SingularSystem, A, F: np.ndarray):
        """eps N N^T over the :meth:`free_motions` N of ``error``'s system when the forces
        ``F`` do no work along them (|N^T F| <= 1e-10 |F|): neutral motions, along which
        every position is an equilibrium (a rod on a ball joint spinning about its own
        axis); with it the step stays put along them. eps = 1e-6 max |A|. None where
        there are none, or ``F`` pushes along them (no equilibrium)."""
        N = self.free_motions(error, A)
        if N is None or np.abs(N.T @ F).max() > 1e-10 * max(np.linalg.norm(F), 1e-300):
            return None
        A = A.toarray() if sparse.issparse(A) else np.asarray(A)
        return self.fmt(1e-6 * np.abs(A).max() * (N @ N.T))

    def inverted(self) -> bool:
        """True when an element inverted or a frame's support collapsed (place_slaves)."""
        if self.collapsed_frames:
            return True
        for body in self.reduced_bodies:
            detF = body.det_F()
            if detF.size and not np.nanmin(detF) > 0:
                return True
        for body in self.fem_bodies:
            detF = body.det_F()
            if detF.size and not np.nanmin(detF) > 0:
                return True
        return False


#: What a step whose matrix leaves motions free may have met (Layout.unresisted).
STEP_ADVICE = "no mass or inertia there, or a negative stiffness that cancels it (a smaller step?)"
#: What a static solve should try when its loads push along motions nothing resists.
STATICS_ADVICE = (
    "the loads push that way, so there is no static equilibrium: hold it (a joint, a "
    "spring, a second path point), or run the dynamics (Scene.step)"
)


def _directions(block: np.ndarray, kind: str) -> str:
    """The span of a rigid body's translation (``kind`` "t") or rotation ("r") rows of
    orthonormal motions ``block`` (3 x k) in words; "" when they do not move it."""
    U, sigma, _ = np.linalg.svd(block)
    rank = int(np.count_nonzero(sigma > 1e-6))
    verb, on = ("translating", "along") if kind == "t" else ("rotating", "about")
    if rank == 0:
        return ""
    if rank == 3:
        return f"{verb} {on} any axis"
    d = U[:, 0] if rank == 1 else U[:, 2]  # the direction, or the plane's normal
    d = np.round(d * np.sign(d[np.argmax(np.abs(d))]), 3) + 0.0
    where = f"({d[0]:g}, {d[1]:g}, {d[2]:g})"
    if rank == 1:
        return f"{verb} {on} {where}"
    if kind == "t":
        return f"{verb} in the plane normal to {where}"
    return f"{verb} about any axis normal to {where}"


def _chain(body, attachments, cycle: str) -> list:
    """[body, its master, its master's master, ..., the root] through ``attachments``
    (objects with .slave and .master); a cycle is a ValueError starting with ``cycle``."""
    master_of = {id(a.slave): a.master for a in attachments}
    chain = [body]
    while id(chain[-1]) in master_of:
        b = master_of[id(chain[-1])]
        if any(b is c for c in chain):
            raise InputError(f"{cycle}: " + " -> ".join(c.name for c in chain + [b]))
        chain.append(b)
    return chain


def _checked(element, known, body, array, shape, other=None) -> np.ndarray:
    """``array`` as a finite float array of ``shape``, on bodies of the scene."""
    what = f"force element {type(element).__name__}"
    for b in (body, other or body):
        if id(b) not in known:
            raise InputError(f"{what} acts on {b!r}, which is not a rigid body of this scene")
    array = np.asarray(array, dtype=float)
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise InputError(
            f"{what}: expected a finite array of shape {shape} for body "
            f"{body.name!r}, got shape {array.shape}"
        )
    return array


def _csr(mat: PETSc.Mat) -> sparse.csr_matrix:
    """A serial PETSc AIJ matrix as scipy CSR (copied)."""
    indptr, indices, data = mat.getValuesCSR()
    return sparse.csr_matrix((data.copy(), indices.copy(), indptr.copy()), shape=mat.getSize())


def _mass(body: FemBody) -> sparse.csr_matrix:
    body.compile()
    if body.M_consistent is not None:
        return _csr(body.M_consistent)
    return sparse.diags(body.M_lumped.array.copy(), format="csr")


def _damping(body: FemBody) -> sparse.csr_matrix:
    """D = alpha M + beta K_0 (FemBody.rest_stiffness)."""
    D = body.alpha * _mass(body)
    return D + body.beta * _csr(body.rest_stiffness()) if body.beta else D
