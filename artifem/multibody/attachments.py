"""Attachments: a component's coordinates as a function of master coordinates.

Lloyd et al. 2019, section 3: x_a = f(x_m), v_a = G v_m with G = df/dx_m, and
forces on the attached (slave) coordinates act on the masters as f_m = G^T f_a
(virtual work). Each class here says what it attaches and gives its G; the
scene (:mod:`artifem.scene`) eliminates the slaves with the prolongation P.

- :class:`NodeAttachment`: FEM nodes carried by a rigid body, x_i = p + R r_i.
- :class:`RigidAttachment`: a rigid body welded to another.
- :class:`FrameAttachment`: a rigid body on a frame of a full or reduced FEM body.
- :class:`EmbeddedFemAttachment`: every node of an FEM body inside a full or reduced one,
  x_s = W x_m + c.
- :class:`LiftAttachment`: the 12 rigid-lift coordinates of a reduced body follow a bone.
- :class:`FemPoint`: a point on a full or reduced FEM body (a path's end), x_a = sum w_j x_j.
"""

from __future__ import annotations

import numpy as np

from artifem.embedding.embedded_mesh import EmbeddedMesh
from artifem.errors import InputError
from artifem.fem_body import FemBody
from artifem.multibody.frame_attachments import FemFrame
from artifem.multibody.point_attachments import FemPointWeights
from artifem.multibody.rigid_body import RigidBody, orthonormalize, skew, skews
from artifem.reduction.reduced_body import ReducedFemBody
from artifem.reduction.rigid_lift import RigidLift

__all__ = [
    "EmbeddedFemAttachment",
    "FemPoint",
    "FrameAttachment",
    "LiftAttachment",
    "NodeAttachment",
    "RigidAttachment",
    "dof_positions",
    "pose_gap",
]


def dof_positions(fem: FemBody) -> np.ndarray:
    """Current positions X + u of the body's local blocked dofs (P1: its nodes), (n, 3)."""
    return fem.V.tabulate_dof_coordinates() + fem.u.x.array.reshape(-1, 3)


class NodeAttachment:
    """FEM nodes attached to a rigid body: x_i = p + R r_i (artifem.scene.scene docstring).

    Args:
        fem: the FEM body.
        nodes: input (mesh file) indices of its nodes; each at most once.
        body: the rigid body that carries them.
        name: used in errors.

    The body-frame offsets r_i = R^T (x_i - p) are taken *now*, from the
    current node positions and the body's current pose. The node velocities
    are v_i = G_i u with G_i = [1, -[R r_i]x] (3 x 6), and forces f_i on the
    nodes act on the body as the wrench G^T f = [sum f_i; sum R r_i x f_i].
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "node_attachments"

    def __init__(self, fem: FemBody, nodes, body: RigidBody, *, name: str = ""):
        if not isinstance(fem, FemBody):
            raise TypeError(f"NodeAttachment: expected a FemBody, got {type(fem).__name__}")
        if not isinstance(body, RigidBody):
            raise TypeError(f"NodeAttachment: expected a RigidBody, got {type(body).__name__}")
        self.name = name or f"{fem.name}->{body.name}"
        what = f"node attachment {self.name!r}"
        nodes = np.asarray(nodes)
        if nodes.size == 0 or not np.issubdtype(nodes.dtype, np.integer):
            raise InputError(f"{what}: nodes must be a non-empty array of integer node indices")
        try:
            nodes = fem._check_nodes(nodes, what)
        except ValueError as exc:
            raise InputError(f"{what}: unknown nodes: {exc}") from None
        unique, counts = np.unique(nodes, return_counts=True)
        if np.any(counts > 1):
            raise InputError(
                f"{what}: nodes {unique[counts > 1][:10].tolist()} are listed more than once"
            )
        self.fem, self.body, self.nodes = fem, body, nodes
        self.dofs = fem.local_dofs(nodes).astype(np.int64)  # this rank's (owned, ghost)
        x = dof_positions(fem)[self.dofs]
        self.offsets = (x - body.position) @ body.rotation  # r_i = R^T (x_i - p), rows

    @property
    def bodies(self) -> tuple:
        """The scene bodies this attachment couples."""
        return (self.fem, self.body)

    def __repr__(self) -> str:
        return f"NodeAttachment({self.name!r}, {self.nodes.size} nodes)"

    def carried_nodes(self, fem) -> tuple[np.ndarray, RigidBody] | None:
        """(input node indices, the rigid body carrying them) when they are nodes of
        ``fem``, else None: what a reductor puts into a reduced basis as rigid-lift columns
        (:mod:`artifem.reduction.rigid_lift`)."""
        return (self.nodes, self.body) if fem is self.fem else None

    def onto_reduced(self, reduced: ReducedFemBody, lift) -> LiftAttachment:
        """This attachment for ``reduced``, the reduced body of ``self.fem`` whose basis
        holds ``lift``'s columns: the same nodes ride on the same rigid body."""
        return LiftAttachment(reduced, lift, self.body, name=self.name)

    def levers(self) -> np.ndarray:
        """R r_i (n, 3): the nodes relative to the body's COM, world axes."""
        return self.offsets @ self.body.rotation.T

    def positions(self) -> np.ndarray:
        """x_i = p + R r_i (n, 3)."""
        return self.body.position + self.levers()

    def jacobian(self) -> np.ndarray:
        """G (3n x 6), rows [1, -[R r_i]x] per node: v = G u."""
        n = len(self.offsets)  # the nodes on this rank
        G = np.zeros((n, 3, 6))
        G[:, :, :3] = np.eye(3)
        G[:, :, 3:] = -skews(self.levers())
        return G.reshape(3 * n, 6)

    def velocities(self, twist=None) -> np.ndarray:
        """v_i = v + w x R r_i (n, 3) for the body's twist (or ``twist``)."""
        u = self.body.twist if twist is None else np.asarray(twist, dtype=float)
        return (self.jacobian() @ u).reshape(-1, 3)

    def wrench(self, forces) -> np.ndarray:
        """G^T f = [sum f_i; sum R r_i x f_i] for forces (n, 3) on the nodes."""
        f = np.asarray(forces, dtype=float).reshape(-1, 3)
        return np.concatenate([f.sum(axis=0), np.cross(self.levers(), f).sum(axis=0)])

    def wrench_stiffness(self, forces) -> np.ndarray:
        """d(G^T f)/dq at fixed f (6 x 6, q = [p; theta]): [[0, 0], [0, sum [f_i]x [R r_i]x]]."""
        f = np.asarray(forces, dtype=float).reshape(-1, 3)
        K = np.zeros((6, 6))
        K[3:, 3:] = np.einsum("nij,njk->ik", skews(f), skews(self.levers()))
        return K


class RigidAttachment:
    """A rigid body welded to another: its pose follows ``master``'s (a slave body).

    The relative pose (offset d_b = R_m^T (p_s - p_m), R_rel = R_m^T R_s) is
    taken now. The slave keeps its own mass, inertia and loads, which act on
    the master through u_s = [[1, -[d]x], [0, 1]] u_m, d = p_s - p_m (world).
    Attachments chain; a cycle is an error of the scene.
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "rigid_attachments"

    def __init__(self, slave: RigidBody, master: RigidBody, *, name: str = ""):
        for b in (slave, master):
            if not isinstance(b, RigidBody):
                raise TypeError(
                    f"RigidAttachment: expected RigidBody objects, got {type(b).__name__}"
                )
        self.name = name or f"{slave.name}->{master.name}"
        if slave is master:
            raise InputError(
                f"rigid attachment {self.name!r}: a body cannot be attached to "
                "itself (an attachment cycle)"
            )
        if slave.motion != "dynamic":
            raise InputError(
                f"rigid attachment {self.name!r}: the slave {slave.name!r} is "
                f"{slave.motion}; only a dynamic body can follow another"
            )
        self.slave, self.master = slave, master
        self.offset = master.rotation.T @ (slave.position - master.position)
        self.relative_rotation = master.rotation.T @ slave.rotation

    @property
    def bodies(self) -> tuple:
        """The scene bodies this attachment couples."""
        return (self.slave, self.master)

    def __repr__(self) -> str:
        return f"RigidAttachment({self.name!r})"

    def pose(self, position=None, rotation=None) -> tuple[np.ndarray, np.ndarray]:
        """The slave's pose for the master's pose (default: the master's current pose)."""
        p = self.master.position if position is None else position
        R = self.master.rotation if rotation is None else rotation
        return p + R @ self.offset, orthonormalize(R @ self.relative_rotation)


class FrameAttachment:
    """A rigid body attached to a frame on an FEM body, full or reduced (Lloyd et al. 2019,
    section 3.2, Fig. 11 right: the rigid body follows the deformable one).

    The frame (:class:`~artifem.multibody.frame_attachments.FemFrame`) has origin
    o = sum_j w_j x_j and rotation R_f = polar(sum_j x_j c_j^T) R_rest^T. The body's pose
    relative to it (r_b = R_f^T (p - o), R_rel = R_f^T R) is taken now, and

        p = o + R_f r_b,   R = R_f R_rel,   u = [v; w] = J v_nodes,
        J = [[G_x - [d]x G_w], [G_w]],   d = p - o = R_f r_b,

    G_x the origin's weights and G_w the frame's angular-velocity Jacobian (on a reduced
    body both times the support's rows of U). The body's rows of P are J times its
    nodes' (derived rows), so its mass, gravity, joints and paths act on the nodes
    through J^T. K_geo: at fixed wrench [f; tau], d(J^T [f; tau])/dx = H(tau_o) +
    G_w^T [f]x [d]x G_w, tau_o = tau + d x f, H the frame's ``torque_stiffness``.

    The body may be massless (``RigidBody.marker``): a frame on the FEM body for joints
    (joints between frames on deformable bodies) and paths. Nothing may be attached to
    the body itself (attach to the FEM body instead).
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "frame_attachments"

    def __init__(self, slave: RigidBody, frame: FemFrame, *, name: str = ""):
        if not isinstance(slave, RigidBody):
            raise TypeError(f"FrameAttachment: expected a RigidBody, got {type(slave).__name__}")
        if not isinstance(frame, FemFrame):
            raise TypeError(f"FrameAttachment: expected a FemFrame, got {type(frame).__name__}")
        self.name = name or f"{slave.name}->{frame.body.name}"
        if slave.motion != "dynamic":
            raise InputError(
                f"frame attachment {self.name!r}: the slave {slave.name!r} is "
                f"{slave.motion}; only a dynamic body can follow a frame"
            )
        if frame.full.mesh.comm.size != 1:
            raise NotImplementedError(
                f"frame attachment {self.name!r}: coupled scenes run in serial only for now"
            )
        self.slave, self.frame = slave, frame
        R_f = frame.rotation()
        self.offset = R_f.T @ (slave.position - frame.position())
        self.relative_rotation = R_f.T @ slave.rotation

    @property
    def bodies(self) -> tuple:
        """The scene bodies this attachment couples."""
        return (self.slave, self.frame.body)

    def __repr__(self) -> str:
        return f"FrameAttachment({self.name!r}, {self.frame.method})"

    def onto_reduced(self, reduced, lift=None) -> FrameAttachment:
        """This attachment for ``reduced``, the reduced body of the frame's FEM body (a
        reductor swaps it at rest): the same frame on it, the same body on the frame.
        ``lift``: unused, the frame carries no nodes."""
        return FrameAttachment(self.slave, self.frame.onto(reduced), name=self.name)

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(p, R) the frame gives the body now."""
        R_f = self.frame.rotation()
        return self.frame.position() + R_f @ self.offset, orthonormalize(
            R_f @ self.relative_rotation
        )

    def _blocks(self):
        """[(rows, J_part)] on the FEM body's blocked dofs (origin, support), and d."""
        f = self.frame
        d = f.rotation() @ self.offset
        G_w = f.angular_velocity_jacobian()
        k_o = f.origin.dofs.size
        J_o = np.zeros((6, 3 * k_o))
        J_o[:3] = np.kron(f.origin.weights, np.eye(3))
        J_s = np.vstack([-skew(d) @ G_w, G_w])
        return [(f.rows(f.origin.dofs), J_o), (f.rows(f.dofs), J_s)], d, G_w

    def jacobian(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """u = J v: [(columns, block)] on the master body's coordinates (its blocked dofs,
        or q on a reduced body: one block J U)."""
        blocks, _, _ = self._blocks()
        if not self.frame.reduced:
            return blocks
        U = self.frame.body.U
        return [(np.arange(U.shape[1]), sum(J @ U[rows] for rows, J in blocks))]

    def stiffness(self, wrench: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(columns, K) with K = d(J^T wrench)/dx at a fixed wrench [f; tau] (class docstring)."""
        f, tau = wrench[:3], wrench[3:]
        _, d, G_w = self._blocks()
        K = self.frame.torque_stiffness(tau + np.cross(d, f)) + G_w.T @ skew(f) @ skew(d) @ G_w
        rows = self.frame.rows(self.frame.dofs)
        if not self.frame.reduced:
            return rows, K
        U = self.frame.body.U[rows]
        return np.arange(U.shape[1]), U.T @ K @ U


class EmbeddedFemAttachment:
    """Every node of FEM body ``slave`` follows FEM body ``master``, full or reduced (Lloyd
    et al. 2019, section 4.2: the masseter's aponeurosis membranes, attached node by node
    to the primary FEM they lie in, non-conforming).

    With W (3 n_s x 3 n_m) the shape functions of the master element that contains
    each slave node's rest position (:class:`~artifem.embedding.EmbeddedMesh`),

        x_s = W x_m + c,     v_s = W v_m,     f_m = W^T f_s,

    c = x_s - W x_m taken now (0 for nodes inside the master at rest; the snapping
    offset of nodes snapped from outside, ``snap=True``, ``distance`` per node).
    On a reduced master (u_m = u_bar + U q, W on its full body's dofs) the same weights give

        x_s = W (X_m + u_bar + U q) + c,     v_s = (W U) q',     f_q = (W U)^T f_s,

    O(n_s r) per evaluation. The slave's dofs leave the solve (its rows of P are
    G = W, or W U, times the master's), so its mass, stiffness and loads act on the
    master: P^T A P holds G^T A_s G. Embedded bodies chain (a slave may be the master of
    another); a cycle is an error of the scene. The slave is a full body with no fixed dofs.
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "embedded_attachments"

    def __init__(
        self,
        slave: FemBody,
        master: FemBody | ReducedFemBody,
        *,
        snap: bool = False,
        name: str = "",
    ):
        if not isinstance(slave, FemBody):
            raise TypeError(
                f"EmbeddedFemAttachment: expected a FemBody slave, got {type(slave).__name__}"
            )
        if not isinstance(master, (FemBody, ReducedFemBody)):
            raise TypeError(
                f"EmbeddedFemAttachment: expected a FemBody or ReducedFemBody "
                f"master, got {type(master).__name__}"
            )
        self.name = name or f"{slave.name}->{master.name}"
        full = master.full if isinstance(master, ReducedFemBody) else master
        if slave is full:
            raise InputError(
                f"embedded attachment {self.name!r}: a body cannot be embedded "
                "in itself (an attachment cycle)"
            )
        for b in (slave, full):
            if b.mesh.comm.size != 1:
                raise NotImplementedError(
                    f"embedded attachment {self.name!r}: coupled scenes run in serial only for now"
                )
        self.slave, self.master, self.snap = slave, master, snap
        rest = slave.V.tabulate_dof_coordinates()
        self._rest = rest.ravel()
        self.embedded = EmbeddedMesh(master, rest, snap=snap, name=self.name)
        self.W = self.embedded.G.tocsr()  # on the full master's blocked dofs
        self.distance = self.embedded.distance
        self.offset = dof_positions(slave).ravel() - self.embedded.positions().ravel()

    @property
    def bodies(self) -> tuple:
        """The scene bodies this attachment couples."""
        return (self.slave, self.master)

    def __repr__(self) -> str:
        return f"EmbeddedFemAttachment({self.name!r}, {self.W.shape[0] // 3} nodes)"

    def refusal(self, body) -> str | None:
        """Why this attachment cannot follow ``body`` onto a reduced body (a reductor asks
        before any training), else None: only its master can be reduced."""
        if body is self.slave:
            return (
                f"embedded attachment {self.name!r} embeds {body.name!r} in "
                f"{self.master.name!r}: its slave cannot be reduced (only its master)"
            )
        return None

    def onto_reduced(self, reduced: ReducedFemBody, lift=None) -> EmbeddedFemAttachment:
        """This attachment for ``reduced``, the reduced body of its master (a reductor swaps
        it at rest): the same slave on the same weights W, x_s = W (X_m + u_bar + U q) + c.
        ``lift``: unused, the attachment carries no node of the master on a rigid body."""
        reason = self.refusal(reduced.full)
        if reason is not None:
            raise InputError(reason)
        if reduced.full is not self.master:
            raise InputError(
                f"embedded attachment {self.name!r}: {reduced.name!r} is not a "
                f"reduced body of its master {self.master.name!r}"
            )
        return EmbeddedFemAttachment(self.slave, reduced, snap=self.snap, name=self.name)

    def jacobian(self):
        """G with v_s = G v_m on the master body's coordinates: W (sparse, 3 n_s x 3 n_m) on
        its blocked dofs, or W U (dense, 3 n_s x r) on q of a reduced master."""
        return self.embedded.jacobian

    def positions(self) -> np.ndarray:
        """x_s = W x_m + c (n_s, 3), from the master's current state."""
        return self.embedded.positions() + self.offset.reshape(-1, 3)

    def displacement(self) -> np.ndarray:
        """u_s = W x_m + c - X_s (block-interleaved, the slave's dof layout)."""
        return self.positions().ravel() - self._rest


class LiftAttachment:
    """The 12 rigid-lift coordinates of a reduced body follow a rigid body's pose
    (:mod:`artifem.reduction.rigid_lift`): g = [p - p_0; vec(R - R_0)], g' = G_g u.

    Args:
        reduced: the reduced body; its basis holds ``lift.columns`` as 12 consecutive
            columns, and its other columns vanish on the carried nodes (so the nodes
            ride on the body exactly).
        lift: the RigidLift the basis was built with.
        body: the rigid body that carries the nodes (at the lift's pose or moved since:
            the coordinates g are set from its pose when the scene is checked).
        name: used in errors.

    Forces on the lift coordinates reach the body as the wrench G_g^T f_g; its
    lever stiffness is sum_k [f_gRk]x [R_k]x (the columns R_k turn with the body
    like a node's lever), plus [f_gp]x [p - p_root]x on a body carried by another.
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "lift_attachments"

    def __init__(
        self, reduced: ReducedFemBody, lift: RigidLift, body: RigidBody, *, name: str = ""
    ):
        if not isinstance(reduced, ReducedFemBody):
            raise TypeError(
                f"LiftAttachment: expected a ReducedFemBody, got {type(reduced).__name__}"
            )
        if not isinstance(lift, RigidLift):
            raise TypeError(f"LiftAttachment: expected a RigidLift, got {type(lift).__name__}")
        if not isinstance(body, RigidBody):
            raise TypeError(f"LiftAttachment: expected a RigidBody, got {type(body).__name__}")
        self.name = name or f"{reduced.name}->{body.name}"
        what = f"lift attachment {self.name!r}"
        U, L = reduced.U, lift.columns
        if U.shape[0] != L.shape[0]:
            raise InputError(f"{what}: the lift has {L.shape[0]} rows, the basis {U.shape[0]}")
        scale = float(np.abs(L).max())
        match = [
            k for k in range(U.shape[1] - 11) if np.abs(U[:, k : k + 12] - L).max() <= 1e-12 * scale
        ]
        if not match:
            raise InputError(
                f"{what}: the basis of {reduced.name!r} does not contain the lift's 12 columns"
            )
        self.first = match[0]
        rows = (3 * lift.dofs[:, None] + np.arange(3)).ravel()
        others = np.delete(U[rows], np.s_[self.first : self.first + 12], axis=1)
        if others.size and np.abs(others).max() > 1e-9 * max(1.0, float(np.abs(U).max())):
            raise InputError(
                f"{what}: basis columns other than the lift move the carried "
                f"nodes (up to {np.abs(others).max():.3g}); they would not "
                "follow the body"
            )
        self.reduced, self.lift, self.body = reduced, lift, body
        self.columns = np.arange(self.first, self.first + 12)
        self._rest = reduced.full.V.tabulate_dof_coordinates()[lift.dofs]

    @property
    def bodies(self) -> tuple:
        """The scene bodies this attachment couples."""
        return (self.reduced, self.body)

    def __repr__(self) -> str:
        return f"LiftAttachment({self.name!r}, {self.lift.nodes.size} nodes)"

    def coordinates(self) -> np.ndarray:
        """g of the body's current pose."""
        return self.lift.coordinates(self.body.position, self.body.rotation)

    def positions(self) -> np.ndarray:
        """Where the body carries the nodes, x_j = p + R r_j (k, 3)."""
        return self.body.position + self.lift.offsets @ self.body.rotation.T

    def node_positions(self) -> np.ndarray:
        """The carried nodes as the reduced body has them, X_j + u_bar_j + U_j q (k, 3)."""
        rows = (3 * self.lift.dofs[:, None] + np.arange(3)).ravel()
        u = self.reduced.u_bar[rows] + self.reduced.U[rows] @ self.reduced.q
        return self._rest + u.reshape(-1, 3)


class FemPoint:
    """A point on a FEM body, x_a = sum_j w_j (X_j + u_j) (``FemPointWeights``: the shape
    functions of its element, or a support of k nodes: the paper's 4 versus 24).

    On a reduced body (weights on its full body's dofs) u = u_bar + U q, so
    x_a' = G q' with G = sum_j w_j U_j (3 x r), the paper's reduced point attachment.
    """

    def __init__(self, fem: FemBody | ReducedFemBody, weights: FemPointWeights, *, name: str = ""):
        if not isinstance(fem, (FemBody, ReducedFemBody)):
            raise TypeError(
                f"FemPoint: expected a FemBody or ReducedFemBody, got {type(fem).__name__}"
            )
        if not isinstance(weights, FemPointWeights):
            raise TypeError(f"FemPoint: expected FemPointWeights, got {type(weights).__name__}")
        full = fem.full if isinstance(fem, ReducedFemBody) else fem
        n = full.V.dofmap.index_map.size_local + full.V.dofmap.index_map.num_ghosts
        if weights.dofs.min() < 0 or weights.dofs.max() >= n:
            raise InputError(f"FemPoint {name!r}: support dofs outside FEM body {fem.name!r}")
        self.fem, self.weights, self.name = fem, weights, name or f"point on {fem.name}"
        if isinstance(fem, ReducedFemBody):
            rows = (3 * weights.dofs[:, None] + np.arange(3)).ravel()
            k = weights.dofs.size
            self.G = np.einsum("j,jcr->cr", weights.weights, fem.U[rows].reshape(k, 3, -1))
            self._x_bar = weights.rest_position + weights.weights @ fem.u_bar[rows].reshape(k, 3)

    def __repr__(self) -> str:
        return f"FemPoint({self.name!r}, {self.weights.dofs.size} support nodes)"

    @property
    def reduced(self) -> bool:
        return isinstance(self.fem, ReducedFemBody)

    def position(self) -> np.ndarray:
        if self.reduced:
            return self._x_bar + self.G @ self.fem.q
        u = self.fem.u.x.array.reshape(-1, 3)[self.weights.dofs]
        return self.weights.rest_position + self.weights.weights @ u

    def velocity(self) -> np.ndarray:
        if self.reduced:
            return self.G @ self.fem.qdot
        return self.weights.weights @ self.fem.v.x.array.reshape(-1, 3)[self.weights.dofs]


def pose_gap(att) -> float:
    """max |p - p_s|, |R - R_s| between the pose an attachment gives its slave body and the
    body's own pose (m and rad-like; round-off when in place)."""
    p, R = att.pose()
    return max(
        float(np.abs(p - att.slave.position).max()), float(np.abs(R - att.slave.rotation).max())
    )
