"""FEM bodies and rigid bodies coupled by attachments and joints, advanced in one step.

Lloyd et al. 2019, section 3 (ArtiSynth's MechModel advanced by its
ConstrainedBackwardEuler): every attachment is x_s = f(x_m) with G = df/dx_m,
the attached (slave) coordinates leave the solve, forces come back to the
masters as G^T f_s, and joints are bilateral constraints solved in the same
linear system. Serial.

Coordinates
-----------
The "all" velocity vector z stacks every FEM body's nodal velocities (3 per
node, the body's local blocked dofs) and every rigid body's twist u = [v; w]
(rigid_body: COM velocity and angular velocity, world). Each coordinate is

- a *master*: a free FEM dof, or the twist of a dynamic rigid body attached to
  nothing (a *root*);
- a *slave*: an FEM node attached to a rigid body (:class:`NodeAttachment`,
  bones inside soft tissue), or a rigid body welded to another one
  (:class:`RigidAttachment`);
- *known*: a fixed FEM dof (velocity 0), a fixed or prescribed rigid body.

Attachments chain (node -> body B -> body A); every slave is rigidly carried
by the root of its chain (the rigid body at its end that is attached to
nothing; a cycle is an error). With x_s the slave's position (the node, or a
slave body's COM) and p, R, u = [v; w] its root's pose and twist,

    node:        v_s = v + w x d_s = G_s u,       G_s = [1, -[d_s]x],        d_s = x_s - p,
    slave body:  u_s = [[1, -[d_s]x], [0, 1]] u,

so z = P z_m + z_k with the sparse prolongation P (identity on the masters,
the rows above on the slaves of dynamic roots, zero elsewhere) and z_k the
known velocities: 0 on fixed dofs and bodies, the trajectory's twist at t + h
on prescribed bodies, and, on a slave node of a prescribed root, the secant
(x_s(t + h) - x_s(t)) / h of its exact motion (so that the FEM force
linearized about x_s(t) sees exactly the displacement the node will have).

The step
--------
Each component gives a linear system A_c z+ = b_c for the velocities at the
end of the step (backward Euler linearized at its start, one solve):

    FEM:    A = (1 + h alpha) M + (h beta + h^2) K,     b = M v + h f,     f = -dPi/du,
            (``SemiImplicitEuler``, written for v+ = v + dv instead of dv)
    rigid:  A = M - h D - h^2 K_e,                      b = M u + h (f - D u),
            (``RigidSystem``: gravity m g, the gyroscopic wrench, force elements; D and
            K_e the velocity and pose Jacobians of the wrenches)

stacked into A_all, b_all (force elements add their off-diagonal blocks) and
reduced by P, with the joint rows as Lagrange multipliers:

    [ P^T A_all P - h^2 K_geo    G_m^T ] [ z_m+ ]   [ P^T (b_all - A_all z_k) ]
    [ G_m                        0     ] [ mu   ] = [ -beta phi / h - G z_k   ],

G the joint rows on the all-space twists (joints.py), G_m = G P, beta the
Baumgarte stabilization (RigidSystem) and lambda = -mu the joint impulses
(A z+ - G^T lambda = b, as in RigidSystem). Joint limits are unilateral rows
solved by an active set (add the most violated limit row, drop the most
negative multiplier), each trial a new factorization.

K_geo is the attachment's consistent (geometric) stiffness. The master wrench
of the slave forces, sum_s [f_s; d_s x f_s] (node) or [f_s; d_s x f_s + tau_s]
(slave body), changes with the root's rotation at fixed f_s because the levers
d_s turn with it: d(d x f)/dtheta = [f]x [d]x (``Frame.wrench_stiffness``), so

    K_geo(root) = sum_s [[0, 0], [0, [f_s]x [d_s]x]],

f_s the applied force on the slave (an FEM node: -dPi/du - (D v) at the node,
gravity included; a slave body: m g plus the force part of its force-element
wrenches). P^T K P alone misses this term of size |f| |d|, and a heavily
loaded attachment then goes unstable; the dynamic and the static tangent
include it (tested by finite differences in tests/test_multibody_coupled.py).

Update. z+ = P z_m+ + z_k. Free FEM dofs: u += h v+; dynamic roots:
p += h v+, R = exp(h [w+]x) R; prescribed bodies take their trajectory's pose
at t + h; then slave bodies and slave nodes are set *exactly* from their
master's pose (x_s = p + R r_s, r_s fixed at attachment time: no drift).
Fixed dofs keep their (prescribed) displacement. The slaves keep the step's
velocities z+ = P z_m+ (not G at the new pose times u+): P^T M z then carries
each slave's momentum into the next step, so the linear momentum of a free
scene (no Rayleigh mass damping, no fixed dofs) is conserved to round-off, and
the next step, which solves for the velocity in the span of the attachments
at the new pose, can only remove kinetic energy from that mismatch (M-
orthogonal projection), an O(h) dissipation like backward Euler's.

Linear solver. The KKT matrix is sparse, indefinite (the zero block) and not
symmetric (gyroscopic and geometric terms), so it is factored by a direct LU,
MUMPS through petsc4py (one process, COMM_SELF), every step.

Statics (:meth:`CoupledSystem.solve_static`): Newton on the master forces
F_m = P^T f_all = 0 and phi = 0 with the same tangent without the inertia,

    [ P^T K_all P - K_geo   G_m^T ] [ dq ]   [ F_m  ]
    [ G_m                   0     ] [ mu ] = [ -phi ],

K_all = d^2 Pi/du^2 on the FEM dofs and -K_e on the rigid ones, master
displacements dq = free FEM du and [dp; dtheta] of each dynamic root
(p += dp, R = exp([dtheta]x) R), slaves set from the poses; a backtracking
line search on |[F_m; phi]| refuses inverted elements.

Path elements (:class:`PointPath`): a spring or muscle of
:mod:`artifem.multibody.muscles` through points that are FEM points
(:class:`FemPoint`: x_a = sum_j w_j x_j, the weights of point_attachments, e.g.
4 or 24 support nodes), rigid frames, or fixed world points. With G the
all-space map of the path points (x_a' = G z: [w_j I] on an FEM point's
nodes, [1, -[r]x] on a frame's body, nothing for a world point), the
element's point forces f, K = df/dx and D = df/dv enter as

    b += h G^T f - h G^T D G z,     A -= h G^T D G + h^2 (G^T K G + K_r),

K_r the rigid frames' lever terms (``point_force_wrenches``: [f]x [r]x and
the D [w]x [r]x term), i.e. the same backward-Euler linearization as the
rigid force elements (A = M - h D - h^2 K); statics adds G^T f to the forces
and -(G^T K G + K_r) to K_all. The forces also enter f_all, so a path on
slave nodes adds to their root's K_geo. Excitation schedules and activation
as in FramePath (advanced once per new time t).

Reduced bodies (:class:`~artifem.reduction.reduced_body.ReducedFemBody`): their
coordinates q are all-space rows like an FEM body's nodal velocities, with the
same backward-Euler block, dense r x r: A = (1 + h alpha) M~ + (h beta + h^2) K~,
b = M~ q' + h f~ (``advance_reduced``). A point on a reduced body
(:class:`FemPoint` with a reduced body) maps as G = sum_j w_j U_j. Nodes of a
reduced body ride on a bone through the basis: 12 rigid-lift columns whose
coordinates g = [p - p_0; vec(R - R_0)] are linear in the pose
(:mod:`artifem.reduction.rigid_lift`) and slaves of the body
(:class:`LiftAttachment`): P rows G_g = [[1, 0], [0, -[R_k]x]] on the body's
twist, z_k the exact secant of g on prescribed bodies, and K_geo the lever term
sum_k [f_gRk]x [R_k]x (the columns of R turn like node levers).

Embedded FEM bodies (:class:`EmbeddedFemAttachment`): every node of a slave
body follows the master element containing it, z_s = W z_m, so its P rows are
W times the master's (P = P_0 + Z P_0 + Z^2 P_0 + ... over the chain of derived
rows Z, lifts included); its forces reach K_geo as W^T f_s.

Load elements (:class:`LoadElement`, ``master_loads(t)``): explicit forces on
FEM nodes, reduced coordinates and rigid bodies (a skin pressure through G^T),
b += h F, and in the static residual.

Rigid bodies on frames of FEM bodies (:class:`FrameAttachment`, the paper's
section 3.2 and Fig. 11): a body follows a frame (origin and polar or Procrustes
rotation, :mod:`~artifem.multibody.frame_attachments`) on a full or reduced body,
u = J v_nodes; its rows of P are J times the nodes' (derived rows, like the
embedded ones), and K_geo adds d(J^T [f; tau])/dx. A massless body
(``RigidBody.marker``) on a frame carries joints: joints between frames on
deformable bodies. The joints' reactions load such attachments like any force;
they enter K_geo lagged by one step (or one Newton iteration).

Statics with joints use the exact-penalty merit E + rho |phi|_1 (rho = 2 max |mu|)
when every force has an energy, and otherwise the force residual left after the
least-squares joint reactions.

Systems of at most ``_MumpsLU.DENSE_MAX`` unknowns (reduced and rigid bodies)
are solved by a dense LU instead of MUMPS. Not here yet: MPI.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from petsc4py import PETSc
from scipy import sparse

from artifem.errors import CoupledStepFailed, InputError, UnknownNameError
from artifem.embedding.embedded_mesh import EmbeddedMesh
from artifem.fem_body import FemBody
from artifem.multibody.frame_attachments import FemFrame
from artifem.multibody.frame_paths import TimedPath
from artifem.multibody.joints import Joint
from artifem.multibody.point_attachments import FemPointWeights
from artifem.multibody.rigid_body import Frame, RigidBody, exp_so3, orthonormalize, skew
from artifem.multibody.rigid_system import ForceElement
from artifem.reduction.reduced_body import ReducedFemBody
from artifem.reduction.rigid_lift import RigidLift

__all__ = ["CoupledStepFailed", "CoupledSystem", "EmbeddedFemAttachment", "FemPoint",
           "FrameAttachment", "LiftAttachment", "LoadElement", "NodeAttachment", "PointPath",
           "RigidAttachment"]


def _skews(d: np.ndarray) -> np.ndarray:
    """[d_i]x for each row of d (n, 3) -> (n, 3, 3)."""
    S = np.zeros((len(d), 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -d[:, 2], d[:, 1]
    S[:, 1, 0], S[:, 1, 2] = d[:, 2], -d[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -d[:, 1], d[:, 0]
    return S


def _dof_positions(fem: FemBody) -> np.ndarray:
    """Current positions X + u of the body's local blocked dofs (P1: its nodes), (n, 3)."""
    return fem.V.tabulate_dof_coordinates() + fem.u.x.array.reshape(-1, 3)


class NodeAttachment:
    """FEM nodes attached to a rigid body: x_i = p + R r_i (module docstring).

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

    def __init__(self, fem: FemBody, nodes, body: RigidBody, *, name: str = ""):
        if not isinstance(fem, FemBody):
            raise TypeError(f"NodeAttachment: expected a FemBody, got {type(fem).__name__}")
        if not isinstance(body, RigidBody):
            raise TypeError(f"NodeAttachment: expected a RigidBody, got {type(body).__name__}")
        self.name = name or f"{fem.name}->{body.name}"
        what = f"node attachment {self.name!r}"
        if fem.mesh.comm.size != 1:
            raise NotImplementedError(f"{what}: coupled scenes run in serial only for now")
        nodes = np.asarray(nodes)
        if nodes.size == 0 or not np.issubdtype(nodes.dtype, np.integer):
            raise InputError(f"{what}: nodes must be a non-empty array of integer node indices")
        try:
            nodes = fem._check_nodes(nodes, what)
        except ValueError as exc:
            raise InputError(f"{what}: unknown nodes: {exc}") from None
        unique, counts = np.unique(nodes, return_counts=True)
        if np.any(counts > 1):
            raise InputError(f"{what}: nodes {unique[counts > 1][:10].tolist()} are listed "
                             "more than once")
        self.fem, self.body, self.nodes = fem, body, nodes
        self.dofs = fem.local_dofs(nodes).astype(np.int64)
        x = _dof_positions(fem)[self.dofs]
        self.offsets = (x - body.position) @ body.rotation        # r_i = R^T (x_i - p), rows

    def __repr__(self) -> str:
        return f"NodeAttachment({self.name!r}, {self.nodes.size} nodes)"

    def levers(self) -> np.ndarray:
        """R r_i (n, 3): the nodes relative to the body's COM, world axes."""
        return self.offsets @ self.body.rotation.T

    def positions(self) -> np.ndarray:
        """x_i = p + R r_i (n, 3)."""
        return self.body.position + self.levers()

    def jacobian(self) -> np.ndarray:
        """G (3n x 6), rows [1, -[R r_i]x] per node: v = G u."""
        n = self.nodes.size
        G = np.zeros((n, 3, 6))
        G[:, :, :3] = np.eye(3)
        G[:, :, 3:] = -_skews(self.levers())
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
        K[3:, 3:] = np.einsum("nij,njk->ik", _skews(f), _skews(self.levers()))
        return K


class RigidAttachment:
    """A rigid body welded to another: its pose follows ``master``'s (a slave body).

    The relative pose (offset d_b = R_m^T (p_s - p_m), R_rel = R_m^T R_s) is
    taken now. The slave keeps its own mass, inertia and loads, which act on
    the master through u_s = [[1, -[d]x], [0, 1]] u_m, d = p_s - p_m (world).
    Attachments chain; a cycle is an error of the scene.
    """

    def __init__(self, slave: RigidBody, master: RigidBody, *, name: str = ""):
        for b in (slave, master):
            if not isinstance(b, RigidBody):
                raise TypeError(f"RigidAttachment: expected RigidBody objects, got "
                                f"{type(b).__name__}")
        self.name = name or f"{slave.name}->{master.name}"
        if slave is master:
            raise InputError(f"rigid attachment {self.name!r}: a body cannot be attached to "
                             "itself (an attachment cycle)")
        if slave.motion != "dynamic":
            raise InputError(f"rigid attachment {self.name!r}: the slave {slave.name!r} is "
                             f"{slave.motion}; only a dynamic body can follow another")
        self.slave, self.master = slave, master
        self.offset = master.rotation.T @ (slave.position - master.position)
        self.relative_rotation = master.rotation.T @ slave.rotation

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

    def __init__(self, slave: RigidBody, frame: FemFrame, *, name: str = ""):
        if not isinstance(slave, RigidBody):
            raise TypeError(f"FrameAttachment: expected a RigidBody, got {type(slave).__name__}")
        if not isinstance(frame, FemFrame):
            raise TypeError(f"FrameAttachment: expected a FemFrame, got {type(frame).__name__}")
        self.name = name or f"{slave.name}->{frame.body.name}"
        if slave.motion != "dynamic":
            raise InputError(f"frame attachment {self.name!r}: the slave {slave.name!r} is "
                             f"{slave.motion}; only a dynamic body can follow a frame")
        if frame.full.mesh.comm.size != 1:
            raise NotImplementedError(f"frame attachment {self.name!r}: coupled scenes run in "
                                      "serial only for now")
        self.slave, self.frame = slave, frame
        R_f = frame.rotation()
        self.offset = R_f.T @ (slave.position - frame.position())
        self.relative_rotation = R_f.T @ slave.rotation

    def __repr__(self) -> str:
        return f"FrameAttachment({self.name!r}, {self.frame.method})"

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(p, R) the frame gives the body now."""
        R_f = self.frame.rotation()
        return self.frame.position() + R_f @ self.offset, \
            orthonormalize(R_f @ self.relative_rotation)

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
    """Every node of FEM body ``slave`` follows FEM body ``master`` (Lloyd et al. 2019,
    section 4.2: the masseter's aponeurosis membranes, attached node by node to the
    primary FEM they lie in, non-conforming).

    With W (3 n_s x 3 n_m) the shape functions of the master element that contains
    each slave node's rest position (:class:`~artifem.embedding.EmbeddedMesh`),

        x_s = W x_m + c,     v_s = W v_m,     f_m = W^T f_s,

    c = x_s - W x_m taken now (0 for nodes inside the master at rest; the snapping
    offset of nodes snapped from outside, ``snap=True``, ``distance`` per node).
    The slave's dofs leave the solve (its rows of P are W times the master's), so
    its mass, stiffness and loads act on the master: P^T A P holds W^T A_s W.
    Embedded bodies chain (a slave may be the master of another); a cycle is an
    error of the scene. The slave may have no fixed dofs.
    """

    def __init__(self, slave: FemBody, master: FemBody, *, snap: bool = False,
                 name: str = ""):
        for b in (slave, master):
            if not isinstance(b, FemBody):
                raise TypeError(f"EmbeddedFemAttachment: expected FemBody objects, got "
                                f"{type(b).__name__}")
        self.name = name or f"{slave.name}->{master.name}"
        if slave is master:
            raise InputError(f"embedded attachment {self.name!r}: a body cannot be embedded "
                             "in itself (an attachment cycle)")
        for b in (slave, master):
            if b.mesh.comm.size != 1:
                raise NotImplementedError(f"embedded attachment {self.name!r}: coupled scenes "
                                          "run in serial only for now")
        self.slave, self.master = slave, master
        rest = slave.V.tabulate_dof_coordinates()
        self._rest = rest.ravel()
        embedded = EmbeddedMesh(master, rest, snap=snap, name=self.name)
        self.W = embedded.G.tocsr()
        self.distance = embedded.distance
        x_m = _dof_positions(master).ravel()
        self.offset = _dof_positions(slave).ravel() - self.W @ x_m[:self.W.shape[1]]

    def __repr__(self) -> str:
        return f"EmbeddedFemAttachment({self.name!r}, {self.W.shape[0] // 3} nodes)"

    def displacement(self) -> np.ndarray:
        """u_s = W x_m + c - X_s (block-interleaved, the slave's dof layout)."""
        x_m = _dof_positions(self.master).ravel()[:self.W.shape[1]]
        return self.W @ x_m + self.offset - self._rest


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

    def __init__(self, reduced: ReducedFemBody, lift: RigidLift, body: RigidBody, *,
                 name: str = ""):
        if not isinstance(reduced, ReducedFemBody):
            raise TypeError(f"LiftAttachment: expected a ReducedFemBody, got "
                            f"{type(reduced).__name__}")
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
        match = [k for k in range(U.shape[1] - 11)
                 if np.abs(U[:, k:k + 12] - L).max() <= 1e-12 * scale]
        if not match:
            raise InputError(f"{what}: the basis of {reduced.name!r} does not contain the "
                             "lift's 12 columns")
        self.first = match[0]
        rows = (3 * lift.dofs[:, None] + np.arange(3)).ravel()
        others = np.delete(U[rows], np.s_[self.first:self.first + 12], axis=1)
        if others.size and np.abs(others).max() > 1e-9 * max(1.0, float(np.abs(U).max())):
            raise InputError(f"{what}: basis columns other than the lift move the carried "
                             f"nodes (up to {np.abs(others).max():.3g}); they would not "
                             "follow the body")
        self.reduced, self.lift, self.body = reduced, lift, body
        self.columns = np.arange(self.first, self.first + 12)
        self._rest = reduced.full.V.tabulate_dof_coordinates()[lift.dofs]

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


class LoadElement:
    """What :class:`CoupledSystem` accepts as an explicit load: an object with

        master_loads(t) -> iterable of (body, array)

    per body of the scene: an FEM body (nodal forces in its blocked dof layout,
    the length of ``body.v.x.array``), a rigid body (the wrench [f; tau about the
    COM], world) or a reduced body (its generalized force, r). Loads enter the
    step explicitly (b += h f) and the static residual; e.g. a pressure on a skin
    mapped to its masters by G^T (virtual work).
    """

    @staticmethod
    def is_load(item) -> bool:
        return callable(getattr(item, "master_loads", None))


class FemPoint:
    """A point on a FEM body, x_a = sum_j w_j (X_j + u_j) (``FemPointWeights``: the shape
    functions of its element, or a support of k nodes: the paper's 4 versus 24).

    On a reduced body (weights on its full body's dofs) u = u_bar + U q, so
    x_a' = G q' with G = sum_j w_j U_j (3 x r), the paper's reduced point attachment.
    """

    def __init__(self, fem: FemBody | ReducedFemBody, weights: FemPointWeights, *,
                 name: str = ""):
        if not isinstance(fem, (FemBody, ReducedFemBody)):
            raise TypeError(f"FemPoint: expected a FemBody or ReducedFemBody, got "
                            f"{type(fem).__name__}")
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


class PointPath:
    """A spring or muscle (``AxialSpring``, ``ThelenMuscle``: ``evaluate(x, v, dt)``) through
    ``points``: :class:`FemPoint` objects, rigid-body or world ``Frame`` objects, or fixed
    world points (3 numbers). Add it to a :class:`CoupledSystem` (module docstring).

    ``excitation(t)``, if given, sets the muscle's excitation at the step's end time; the
    activation advances once per new time (as ``FramePath``).
    """

    def __init__(self, element, points, *, excitation=None, name: str = "path"):
        pts = []
        for p in points:
            if isinstance(p, (FemPoint, Frame)):
                pts.append(p)
            else:
                x = np.asarray(p, dtype=float)
                if x.shape != (3,) or not np.all(np.isfinite(x)):
                    raise InputError(f"PointPath {name!r}: a point is a FemPoint, a Frame or 3 "
                                     f"finite numbers (a fixed world point), got {p!r}")
                pts.append(Frame(None, x))
        if len(pts) < 2:
            raise InputError(f"PointPath {name!r}: a path needs at least two points, "
                             f"got {len(pts)}")
        self.element, self.points, self.name = element, pts, name
        self._timed = TimedPath(element, excitation, f"PointPath {name!r}")

    def __repr__(self) -> str:
        return f"PointPath({self.name!r}, {len(self.points)} points)"

    @property
    def conservative(self) -> bool:
        """True when the element has an energy (springs): statics may use it as a merit."""
        return hasattr(self.element, "energy")

    def positions(self) -> np.ndarray:
        return np.array([p.position() if isinstance(p, FemPoint) else p.world_position()
                         for p in self.points])

    def velocities(self) -> np.ndarray:
        return np.array([p.velocity() for p in self.points])

    def evaluate(self, t: float):
        """The element's PathForces at the current positions and velocities, time t."""
        return self._timed(t, self.positions(), self.velocities())

    def tension(self) -> float:
        return self._timed.tension()

    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.positions(), axis=0), axis=1).sum())

    def potential_energy(self) -> float:
        energy = getattr(self.element, "energy", None)
        return float(energy(self.positions())) if energy is not None else 0.0


@dataclass
class _Slaves:
    """The nodes of one NodeAttachment, as the scene indexes them."""

    attachment: NodeAttachment
    rows: np.ndarray            # all-space rows (3 per node, node-major)


class CoupledSystem:
    """FEM bodies, rigid bodies, attachments, joints and force elements (module docstring).

    Args:
        gravity: the gravitational acceleration (world), applied to every body:
            an FEM body's own ``gravity`` constant is set to it when added.
        stabilization: Baumgarte beta in [0, 1] of the joint rows (RigidSystem).
        geometric_stiffness: include K_geo in the step and the static tangent (default);
            False drops it, for comparisons.
    """

    def __init__(self, gravity=(0.0, 0.0, -9.81), *, stabilization: float = 1.0,
                 geometric_stiffness: bool = True):
        g = np.asarray(gravity, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise InputError(f"gravity must be 3 finite numbers, got {gravity!r}")
        if not 0.0 <= stabilization <= 1.0:
            raise InputError(f"stabilization must be in [0, 1], got {stabilization!r}")
        self._gravity = g
        self.stabilization = float(stabilization)
        self.geometric_stiffness = bool(geometric_stiffness)
        self.t = 0.0
        self.fem_bodies: list[FemBody] = []
        self.reduced_bodies: list[ReducedFemBody] = []
        self.rigid_bodies: list[RigidBody] = []
        self.node_attachments: list[NodeAttachment] = []
        self.rigid_attachments: list[RigidAttachment] = []
        self.embedded_attachments: list[EmbeddedFemAttachment] = []
        self.lift_attachments: list[LiftAttachment] = []
        self.frame_attachments: list[FrameAttachment] = []
        self.joints: list[Joint] = []
        self.forces: list[ForceElement] = []
        self.paths: list[PointPath] = []
        self.loads: list = []
        self._layout = None
        self._solver = _MumpsLU()
        self._impulses: dict = {}
        self._last_h = 1.0
        self._reactions = None          # the joints' last forces, all-space (for K_geo)
        self.last_solve: dict = {}

    @property
    def gravity(self) -> np.ndarray:
        """g (world); setting it sets every FEM body's gravity constant too."""
        return self._gravity

    @gravity.setter
    def gravity(self, value) -> None:
        g = np.asarray(value, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise InputError(f"gravity must be 3 finite numbers, got {value!r}")
        self._gravity = g.copy()
        for body in self._full_bodies():
            body.gravity.value[:] = g

    def _full_bodies(self) -> list[FemBody]:
        """The FEM bodies and the full bodies of the reduced ones (gravity, load factor)."""
        return self.fem_bodies + [b.full for b in self.reduced_bodies]

    # ---- building ------------------------------------------------------------------------

    def add(self, *items) -> None:
        """Add FEM bodies (full or reduced), rigid bodies, attachments, joints, force and
        load elements (any order).

        Cross-references (attachments and joints naming bodies of the scene, a
        node attached twice or also fixed, attachment cycles) are checked at
        the first step or static solve after a change (:meth:`check`).
        """
        for item in items:
            if isinstance(item, FemBody):
                if item.mesh.comm.size != 1:
                    raise NotImplementedError(f"FEM body {item.name!r}: coupled scenes run in "
                                              "serial only for now")
                if any(item is b for b in self.fem_bodies):
                    raise InputError(f"FEM body {item.name!r} is already in the scene")
                item.gravity.value[:] = self.gravity
                self.fem_bodies.append(item)
            elif isinstance(item, ReducedFemBody):
                if any(item is b for b in self.reduced_bodies):
                    raise InputError(f"reduced body {item.name!r} is already in the scene")
                item.full.gravity.value[:] = self.gravity
                self.reduced_bodies.append(item)
            elif isinstance(item, RigidBody):
                if any(item is b for b in self.rigid_bodies):
                    raise InputError(f"rigid body {item.name!r} is already in the scene")
                if item.motion == "prescribed":
                    item.follow_trajectory(self.t)
                self.rigid_bodies.append(item)
            elif isinstance(item, (NodeAttachment, RigidAttachment, EmbeddedFemAttachment,
                                   LiftAttachment, FrameAttachment, Joint, PointPath)):
                members = {NodeAttachment: self.node_attachments,
                           RigidAttachment: self.rigid_attachments,
                           EmbeddedFemAttachment: self.embedded_attachments,
                           LiftAttachment: self.lift_attachments,
                           FrameAttachment: self.frame_attachments,
                           Joint: self.joints, PointPath: self.paths}
                group = next(g for kind, g in members.items() if isinstance(item, kind))
                if any(item is other for other in group):
                    raise InputError(f"{type(item).__name__} {getattr(item, 'name', '')!r} is "
                                     f"already in the scene")
                group.append(item)
            elif isinstance(item, ForceElement):
                self.forces.append(item)
            elif LoadElement.is_load(item):
                if any(item is other for other in self.loads):
                    raise InputError(f"load element {item!r} is already in the scene")
                self.loads.append(item)
            else:
                raise TypeError(f"cannot add {type(item).__name__} to a CoupledSystem: expected "
                                "a FemBody, ReducedFemBody, RigidBody, an attachment, a Joint, "
                                "a force element with wrenches(t) or a load element with "
                                "master_loads(t)")
            self._layout = None

    def check(self) -> None:
        """Validate the scene and index its coordinates (done automatically when needed)."""
        self._layout = _Layout(self)

    def _ready(self) -> "_Layout":
        if self._layout is None:
            self._layout = _Layout(self)
        # Fixing nodes after adding is allowed: re-check when a body's fixed set changed.
        if any(not np.array_equal(b.fixed_dofs, f)
               for b, f in zip(self.fem_bodies, self._layout.fixed)):
            self._layout = _Layout(self)
        return self._layout

    # ---- observation ---------------------------------------------------------------------

    def _moving_bodies(self) -> list[RigidBody]:
        return [b for b in self.rigid_bodies if b.dynamic]

    def kinetic_energy(self) -> float:
        """1/2 v^T M v of the FEM bodies plus the rigid kinetic energy of the moving bodies."""
        return (sum(b.kinetic_energy() for b in self.fem_bodies + self.reduced_bodies)
                + sum(b.kinetic_energy() for b in self._moving_bodies()))

    def potential_energy(self) -> float:
        """FEM Pi(u) (strain minus the work of gravity and loads), -m g . p of the moving
        rigid bodies, and the force elements' potential_energy()."""
        return (sum(b.potential_energy() for b in self.fem_bodies + self.reduced_bodies)
                + sum(b.potential_energy(self.gravity) for b in self._moving_bodies())
                + sum(e.potential_energy() for e in self.forces
                      if hasattr(e, "potential_energy"))
                + sum(p.potential_energy() for p in self.paths))

    def energy(self) -> float:
        return self.kinetic_energy() + self.potential_energy()

    def momentum(self) -> np.ndarray:
        """Linear momentum: sum M v over the FEM nodes plus m v of the moving rigid bodies."""
        total = np.zeros(3)
        for body in self.fem_bodies:
            body.compile()
            Mv = body.v.x.petsc_vec.duplicate()
            body.mass_mult(body.v.x.petsc_vec, Mv)
            total += Mv.array.reshape(-1, 3).sum(axis=0)
            Mv.destroy()
        for body in self.reduced_bodies:    # 1_k^T M U q' = (U^T int rho e_k . phi dX) . q'
            total += body.G.T @ body.qdot
        return total + sum((b.mass * b.velocity for b in self._moving_bodies()), np.zeros(3))

    def attachment_errors(self) -> dict[str, float]:
        """max |x_i - (p + R r_i)| of each node and lift attachment, and the pose error
        (m and rad) of each frame attachment (round-off after a step)."""
        out = {a.name: float(np.abs(_dof_positions(a.fem)[a.dofs] - a.positions()).max())
               for a in self.node_attachments}
        out.update({a.name: float(np.abs(a.node_positions() - a.positions()).max())
                    for a in self.lift_attachments})
        for a in self.frame_attachments:
            out[a.name] = _pose_gap(a)
        return out

    def constraint_errors(self) -> dict[str, float]:
        """max |phi| of each joint's bilateral rows (m and rad)."""
        return {j.name: float(np.abs(j.constraint().phi).max()) for j in self.joints}

    def reaction(self, joint: Joint) -> tuple[np.ndarray, np.ndarray]:
        """The wrenches the joint applied to its bodies A and B over the last step
        (G_A^T lambda / h, G_B^T lambda / h, rows at the start of the step)."""
        if not any(joint is j for j in self.joints):
            raise UnknownNameError(f"joint {joint.name!r} is not in the scene")
        parts = self._impulses.get(joint, [])
        return (sum((rows.G_a.T @ lam for rows, lam in parts), np.zeros(6)) / self._last_h,
                sum((rows.G_b.T @ lam for rows, lam in parts), np.zeros(6)) / self._last_h)

    # ---- the step ------------------------------------------------------------------------

    def step(self, h: float) -> None:
        """Advance from t to t + h (module docstring)."""
        L, P, z_k, targets, A_m, b_m = self._step_system(h)
        bilateral, unilateral = L.joint_rows(P, z_k, h, self.stabilization)
        z_m, impulses = self._solve(A_m, b_m, bilateral, unilateral)
        z = P @ z_m + z_k
        L.advance(z, h, targets)
        self._impulses, self._last_h = impulses, h
        self._reactions = L.joint_forces((joint, rows, lam / h)
                                         for joint, parts in impulses.items()
                                         for rows, lam in parts)
        self.t += h

    def step_matrix(self, h: float) -> sparse.csr_matrix:
        """The masters' block P^T A_all P - h^2 K_geo of the next step's KKT matrix (for
        inspection; prescribed bodies take their twist at t + h, nothing else changes)."""
        return self._step_system(h)[4]

    def _step_system(self, h: float):
        """(layout, P, z_k, prescribed targets, A_m, b_m) of the step from t to t + h."""
        if not (np.isfinite(h) and h > 0):
            raise InputError(f"time step must be positive and finite, got {h!r}")
        L = self._ready()
        t1 = self.t + h
        targets = L.kinematic_targets(t1)               # prescribed poses and twists at t1
        for body, (_, _, twist) in targets.items():
            body.set_twist(twist)
        P = L.prolongation()
        z_k = L.known_velocities(h, targets)
        A, b, f_all = L.dynamics(h, t1)
        A_m = (P.T @ A @ P).tocsr()
        if self.geometric_stiffness:
            A_m = A_m - h * h * L.geometric_stiffness(self._with_reactions(f_all), P)
        b_m = P.T @ (b - A @ z_k)
        return L, P, z_k, targets, A_m, b_m

    def _solve(self, A_m, b_m, bilateral, unilateral):
        """z_m+ and the joint impulses from the KKT system, with an active set for the limits."""
        n = A_m.shape[0]
        if n == 0:                                  # everything fixed, prescribed or attached
            self.last_solve = {"masters": 0, "constraint_rows": 0, "factorizations": 0}
            return np.zeros(0), {}
        groups = bilateral + unilateral
        n_bi = sum(len(g[3]) for g in bilateral)
        G = sparse.vstack([g[2] for g in groups]).tocsr() if groups else \
            sparse.csr_matrix((0, n))
        c = np.concatenate([g[3] for g in groups]) if groups else np.zeros(0)
        active = np.zeros(len(c), dtype=bool)
        active[:n_bi] = True
        limits = np.arange(n_bi, len(c))
        tol = 1e-10 * max(1.0, np.abs(c).max()) if c.size else 0.0
        self.last_solve = {"masters": n, "constraint_rows": int(active.sum()), "factorizations": 0}
        for _ in range(2 * limits.size + 10):
            on = np.flatnonzero(active)
            K = sparse.bmat([[A_m, G[on].T], [G[on], None]], format="csr") if on.size else A_m
            rhs = np.concatenate([b_m, c[on]])
            x = self._solver.solve(K, rhs, f"t = {self.t:g}")
            self.last_solve["factorizations"] += 1
            z_m = x[:n]
            lam = np.zeros(len(c))
            lam[on] = -x[n:]
            if not limits.size:
                break
            slack = G[limits] @ z_m - c[limits]             # >= 0 wanted
            negative = active[limits] & (lam[limits] < -tol)
            violated = ~active[limits] & (slack < -tol)
            if negative.any():
                active[limits[np.argmin(np.where(negative, lam[limits], np.inf))]] = False
            elif violated.any():
                active[limits[np.argmin(np.where(violated, slack, np.inf))]] = True
            else:
                break
        else:
            raise CoupledStepFailed(f"t = {self.t:g}: the joint-limit active set did not settle")
        impulses: dict = {}
        start = 0
        for joint, rows, _, c_rows in groups:
            impulses.setdefault(joint, []).append((rows, lam[start:start + len(c_rows)]))
            start += len(c_rows)
        return z_m, impulses

    # ---- statics -------------------------------------------------------------------------

    def master_forces(self) -> np.ndarray:
        """F_m = P^T f_all: the static generalized forces on the masters (no inertia)."""
        L = self._ready()
        return L.prolongation().T @ L.static_forces(self.t, tangent=False)[0]

    def static_tangent(self) -> sparse.csr_matrix:
        """-dF_m/dq_m = P^T K_all P - K_geo at the current configuration (module docstring)."""
        L = self._ready()
        f_all, K_all = L.static_forces(self.t, tangent=True)
        P = L.prolongation()
        K = (P.T @ K_all @ P).tocsr()
        if not self.geometric_stiffness:
            return K
        return K - L.geometric_stiffness(self._with_reactions(f_all), P)

    def _with_reactions(self, f_all: np.ndarray) -> np.ndarray:
        """f_all plus the joints' last reaction forces: on a body that follows a frame or
        another body they load the attachment like any force (lagged by one step or one
        Newton iteration)."""
        r = self._reactions
        return f_all if r is None or r.shape != f_all.shape else f_all + r

    def displace_masters(self, dq) -> None:
        """Apply a master displacement: free FEM u += dq, dynamic roots p += dp and
        R = exp([dtheta]x) R; slaves follow their roots' poses exactly."""
        self._ready().displace(np.asarray(dq, dtype=float))

    def master_count(self) -> int:
        return self._ready().n_masters

    def solve_static(self, *, load_steps: int = 1, rtol: float = 1e-10, atol: float = 1e-12,
                     max_iterations: int = 30) -> list[int]:
        """Static equilibrium F_m = 0, phi = 0 by Newton (module docstring), the gravity and
        the FEM loads ramped over ``load_steps`` increments. Velocities are set to zero.
        Returns the Newton iterations per increment."""
        L = self._ready()
        for body in self.fem_bodies:
            body.v.x.array[:] = 0.0
        for body in self.reduced_bodies:
            body.qdot[:] = 0.0
        for body in self.rigid_bodies:
            if body.dynamic:
                body.set_twist(np.zeros(6))
        g = self.gravity.copy()
        self._reactions = None
        counts = []
        try:
            for k in range(1, load_steps + 1):
                self._set_load_factor(k / load_steps, g)
                counts.append(self._newton(L, rtol, atol, max_iterations, k / load_steps))
        finally:
            self._set_load_factor(1.0, g)
        return counts

    def _set_load_factor(self, factor: float, g: np.ndarray) -> None:
        """Ramp the loads: the rigid bodies' gravity, and the FEM load factor (which scales
        the FEM bodies' gravity, body forces and nodal loads)."""
        self._gravity = factor * g
        for body in self._full_bodies():
            body.load_factor.value = factor

    def _residual(self, L) -> tuple[np.ndarray, np.ndarray]:
        F = L.prolongation().T @ L.static_forces(self.t, tangent=False)[0]
        phi = np.concatenate([j.constraint().phi for j in self.joints]) if self.joints \
            else np.zeros(0)
        return F, phi

    def _merit(self, L, F: np.ndarray, phi: np.ndarray) -> float:
        """|[F_m - G_m^T mu; phi]| with mu the least-squares joint reactions at the current
        configuration: the forces the joints cannot balance, and the joints' error."""
        if self.joints:
            G = L.joint_matrix(L.prolongation()).toarray()
            F = F - G.T @ np.linalg.lstsq(G.T, F, rcond=None)[0]
        return float(np.linalg.norm(np.concatenate([F, phi])))

    def _newton(self, L, rtol, atol, max_iterations, factor) -> int:
        F, phi = self._residual(L)
        norm = self._merit(L, F, phi)
        scale = max(norm, atol)
        for it in range(1, max_iterations + 1):
            if norm <= max(rtol * scale, atol):
                return it - 1
            K = self.static_tangent()
            P = L.prolongation()
            G = L.joint_matrix(P) if self.joints else sparse.csr_matrix((0, K.shape[0]))
            KKT = sparse.bmat([[K, G.T], [G, None]], format="csr") if G.shape[0] else K
            x = self._solver.solve(KKT, np.concatenate([F, -phi]), "static solve")
            dq, mu = x[:K.shape[0]], x[K.shape[0]:]
            if self.joints:             # K dq = F - G^T mu: the joints apply -G^T mu
                groups = L.joint_rows(P, np.zeros(L.n_all), 1.0, 0.0)[0]
                cuts = np.cumsum([len(g[1]) for g in groups])[:-1]
                self._reactions = L.joint_forces((g[0], g[1], m) for g, m in
                                                 zip(groups, np.split(-mu, cuts)))
            saved = L.save()
            # The energy is a merit when it is the whole potential; with joints, the exact
            # penalty E + rho |phi|_1, rho > max |mu|, whose slope along the step is
            # -F . dq - rho |phi|_1 = -dq^T K dq + mu . phi - rho |phi|_1 < 0.
            use_energy = all(hasattr(e, "potential_energy") for e in self.forces) \
                and all(p.conservative for p in self.paths)
            rho = 2.0 * float(np.abs(mu).max()) if mu.size else 0.0
            energy0 = self.potential_energy() + rho * float(np.abs(phi).sum()) \
                if use_energy else 0.0
            slope = -float(F @ dq) - rho * float(np.abs(phi).sum())
            step = 1.0
            while step >= 1e-4:
                L.displace(step * dq)
                if not L.inverted():
                    # Energy (Armijo) first: a rotation of a root moves its slaves on arcs
                    # while the free nodes beside them move on straight lines, so a large
                    # rotation raises the force residual sharply (stiff elements by the
                    # attachment), not the energy (integrators._backtrack, same rule).
                    F_new, phi_new = self._residual(L)
                    energy = self.potential_energy() + rho * float(np.abs(phi_new).sum()) \
                        if use_energy else np.inf
                    trial = self._merit(L, F_new, phi_new)
                    if np.isfinite(trial) and (
                            energy <= energy0 + 1e-4 * step * slope
                            or trial <= (1.0 - 1e-4 * step) * norm):
                        break
                L.restore(saved)
                step *= 0.5
            else:
                raise CoupledStepFailed(f"static solve: line search failed at load factor "
                                        f"{factor:g}, Newton iteration {it}")
            F, phi, norm = F_new, phi_new, trial
            if step == 1.0 and np.abs(dq).max() <= 1e-14 * max(L.master_scale(), 1e-300):
                return it
        if norm <= max(rtol * scale, atol):
            return max_iterations
        raise CoupledStepFailed(f"static solve: Newton did not converge in {max_iterations} "
                                f"iterations at load factor {factor:g} (|r| = {norm:.3e})")


class _Layout:
    """The scene's coordinates: all-space offsets, masters, slaves, roots (module docstring)."""

    def __init__(self, scene: CoupledSystem):
        self.scene = scene
        fem_bodies, rigid = scene.fem_bodies, scene.rigid_bodies
        self.fixed = [b.fixed_dofs.copy() for b in fem_bodies]
        offset = 0
        self.fem_offset: dict[int, int] = {}
        self.fem_size: dict[int, int] = {}
        for body in fem_bodies:
            n = body.V.dofmap.index_map.size_local + body.V.dofmap.index_map.num_ghosts
            self.fem_offset[id(body)], self.fem_size[id(body)] = offset, 3 * n
            offset += 3 * n
        self.reduced_offset: dict[int, int] = {}
        for body in scene.reduced_bodies:
            self.reduced_offset[id(body)] = offset
            offset += body.r
        self.rigid_offset: dict[int, int] = {}
        for body in rigid:
            self.rigid_offset[id(body)] = offset
            offset += 6
        self.n_all = offset
        self._check_references()

        # Roots of the rigid attachment chains, in dependency order (masters first).
        chains = {id(b): _chain(b, scene.rigid_attachments, "attachment cycle")
                  for b in rigid}
        self.root: dict[int, RigidBody] = {key: c[-1] for key, c in chains.items()}
        self.rigid_attachments = sorted(scene.rigid_attachments,
                                        key=lambda a: len(chains[id(a.slave)]))
        # Embedded bodies, slaves before their masters (deepest first).
        self.embedded = sorted(scene.embedded_attachments, key=lambda a: -len(_chain(
            a.slave, scene.embedded_attachments, "embedded attachment cycle")))

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
            is_slave_row[o:o + self.fem_size[id(att.slave)]] = True
        for att in scene.lift_attachments:
            is_slave_row[self.reduced_offset[id(att.reduced)] + att.columns] = True
        framed = {id(att.slave) for att in scene.frame_attachments}
        master_rows = []
        for body, fixed in zip(fem_bodies, self.fixed):
            o = self.fem_offset[id(body)]
            known = np.zeros(self.fem_size[id(body)], dtype=bool)
            known[(3 * fixed[:, None] + np.arange(3)).ravel()] = True
            rows = o + np.flatnonzero(~known)
            master_rows.append(rows[~is_slave_row[rows]])
        for body in scene.reduced_bodies:
            rows = self.reduced_offset[id(body)] + np.arange(body.r)
            master_rows.append(rows[~is_slave_row[rows]])
        self.roots = [b for b in rigid if b.dynamic and self.root[id(b)] is b
                      and id(b) not in framed]
        for body in self.roots:
            master_rows.append(self.rigid_offset[id(body)] + np.arange(6))
        self.master_rows = np.concatenate(master_rows) if master_rows else np.zeros(0, int)
        self.n_masters = self.master_rows.size
        self.master_col = {id(b): int(np.searchsorted(self.master_rows,
                                                      self.rigid_offset[id(b)]))
                           for b in self.roots}
        # (rows sorted: FEM, reduced, then rigid bodies in order, so searchsorted finds them)
        assert np.all(np.diff(self.master_rows) > 0)
        self.free_fem = [(body, rows - self.fem_offset[id(body)])
                         for body, rows in zip(fem_bodies, master_rows)]
        self.free_reduced = [(body, rows - self.reduced_offset[id(body)]) for body, rows in
                             zip(scene.reduced_bodies, master_rows[len(fem_bodies):])]
        self._embedding_map = self._embedding_matrix()
        self._place_lifts()             # lift coordinates from the bodies' poses

    def _embedding_matrix(self) -> sparse.csr_matrix:
        """Z_e (n_all x n_all): z_slave = W z_master of every embedded body (constant)."""
        blocks = []
        for att in self.embedded:
            o_s, o_m = self.fem_offset[id(att.slave)], self.fem_offset[id(att.master)]
            W = att.W.tocoo()
            blocks.append((W.data, o_s + W.row, o_m + W.col))
        if not blocks:
            return sparse.csr_matrix((self.n_all, self.n_all))
        vals, rows, cols = (np.concatenate(x) for x in zip(*blocks))
        return sparse.csr_matrix((vals, (rows, cols)), shape=(self.n_all, self.n_all))

    def _lift_matrix(self) -> sparse.csr_matrix:
        """Z_l (n_all x n_all): g' = G_g(R) u of every lift, at the bodies' current poses."""
        rows, cols, vals = [], [], []
        for att in self.scene.lift_attachments:
            r = self.reduced_offset[id(att.reduced)] + att.columns
            c = self.rigid_offset[id(att.body)] + np.arange(6)
            rr, cc = np.meshgrid(r, c, indexing="ij")
            rows.append(rr.ravel()), cols.append(cc.ravel())
            vals.append(RigidLift.jacobian(att.body.rotation).ravel())
        if not rows:
            return sparse.csr_matrix((self.n_all, self.n_all))
        return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                         np.concatenate(cols))),
                                 shape=(self.n_all, self.n_all))

    def _frame_matrix(self) -> sparse.csr_matrix:
        """Z_f (n_all x n_all): u_b = J z_nodes of every frame-attached body, at the current
        configuration (FrameAttachment)."""
        rows, cols, vals = [], [], []
        for att in self.scene.frame_attachments:
            r0 = self.rigid_offset[id(att.slave)] + np.arange(6)
            o = self._body_offset(att.frame.body)
            for c, J in att.jacobian():
                rr, cc = np.meshgrid(r0, o + c, indexing="ij")
                rows.append(rr.ravel()), cols.append(cc.ravel()), vals.append(J.ravel())
        if not rows:
            return sparse.csr_matrix((self.n_all, self.n_all))
        return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                         np.concatenate(cols))),
                                 shape=(self.n_all, self.n_all))

    def _body_offset(self, body) -> int:
        """The all-space offset of an FEM (blocked dofs) or reduced body (q)."""
        return self.fem_offset[id(body)] if isinstance(body, FemBody) else \
            self.reduced_offset[id(body)]

    @staticmethod
    def _chain(Z: sparse.csr_matrix, X):
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
            fixed = np.intersect1d(att.dofs, att.fem.fixed_dofs)
            if fixed.size:
                inverse = {d: n for n, d in att.fem._node_to_dof.items()}
                raise InputError(f"{what}: nodes {[inverse[int(d)] for d in fixed[:10]]} of "
                                 f"{att.fem.name!r} are fixed; a node is either fixed or "
                                 "attached")
            for node in att.nodes.tolist():
                key = (id(att.fem), node)
                if key in attached:
                    raise InputError(f"node {node} of FEM body {att.fem.name!r} is attached "
                                     f"twice: by {attached[key]!r} and by {att.name!r}")
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
                raise InputError(f"rigid body {att.slave.name!r} is attached twice: by "
                                 f"{slaves[id(att.slave)]!r} and by {att.name!r}")
            slaves[id(att.slave)] = att.name
        # The offsets were taken when the attachment was made: if a body moved since (a
        # prescribed body is placed on its trajectory only when it is added to the scene),
        # the slaves are no longer where the attachment puts them.
        for att in scene.node_attachments:
            x = _dof_positions(att.fem)[att.dofs]
            gap = float(np.abs(x - att.positions()).max())
            if gap > 1e-9 * (1.0 + float(np.abs(att.offsets).max())):
                raise InputError(
                    f"node attachment {att.name!r}: the nodes are up to {gap:.3g} from where the "
                    f"attachment puts them; {att.body.name!r} or {att.fem.name!r} moved after the "
                    "attachment was made (a prescribed body takes its trajectory's pose when "
                    "added to the scene: add it before making the attachment)")
        for att in scene.rigid_attachments:
            gap = _pose_gap(att)
            if gap > 1e-9 * (1.0 + float(np.abs(att.offset).max())):
                raise InputError(
                    f"rigid attachment {att.name!r}: {att.slave.name!r} is {gap:.3g} off the pose "
                    f"the attachment gives it; a body moved after the attachment was made")
        embedded: dict[int, str] = {}
        for att in scene.embedded_attachments:
            what = f"embedded attachment {att.name!r}"
            for b in (att.slave, att.master):
                if id(b) not in fem_ids:
                    raise InputError(f"{what}: FEM body {b.name!r} is not in the scene")
            if att.slave.fixed_dofs.size:
                raise InputError(f"{what}: the embedded body {att.slave.name!r} has fixed nodes; "
                                 "its nodes are either fixed or embedded")
            if any(a.fem is att.slave for a in scene.node_attachments):
                raise InputError(f"{what}: nodes of {att.slave.name!r} are also attached to a "
                                 "rigid body")
            if id(att.slave) in embedded:
                raise InputError(f"FEM body {att.slave.name!r} is embedded twice: by "
                                 f"{embedded[id(att.slave)]!r} and by {att.name!r}")
            embedded[id(att.slave)] = att.name
        reduced_ids = {id(b) for b in scene.reduced_bodies}
        lifted: dict[int, list] = {}
        for att in scene.lift_attachments:
            what = f"lift attachment {att.name!r}"
            if id(att.reduced) not in reduced_ids:
                raise InputError(f"{what}: reduced body {att.reduced.name!r} is not in the scene")
            if id(att.body) not in rigid_ids:
                raise InputError(f"{what}: rigid body {att.body.name!r} is not in the scene")
            for other in lifted.get(id(att.reduced), []):
                if np.intersect1d(other.columns, att.columns).size:
                    raise InputError(f"{what}: the coordinates of {att.reduced.name!r} it drives "
                                     f"are already driven by {other.name!r}")
            lifted.setdefault(id(att.reduced), []).append(att)
        framed: dict[int, str] = {}
        for att in scene.frame_attachments:
            what = f"frame attachment {att.name!r}"
            if id(att.slave) not in rigid_ids:
                raise InputError(f"{what}: rigid body {att.slave.name!r} is not in the scene")
            if id(att.frame.body) not in fem_ids | reduced_ids:
                raise InputError(f"{what}: FEM body {att.frame.body.name!r} is not in the scene")
            if id(att.slave) in framed or id(att.slave) in slaves:
                raise InputError(f"rigid body {att.slave.name!r} is attached twice: by "
                                 f"{framed.get(id(att.slave), slaves.get(id(att.slave)))!r} "
                                 f"and by {att.name!r}")
            framed[id(att.slave)] = att.name
            gap = _pose_gap(att)
            if gap > 1e-9 * (1.0 + float(np.abs(att.offset).max())):
                raise InputError(f"{what}: {att.slave.name!r} is {gap:.3g} off the pose the "
                                 "frame gives it; a body moved after the attachment was made")
        carried = [(a.name, a.body) for a in scene.node_attachments + scene.lift_attachments] \
            + [(a.name, a.master) for a in scene.rigid_attachments]
        for name, body in carried:
            if id(body) in framed:
                raise InputError(f"attachment {name!r}: {body.name!r} follows a frame on an FEM "
                                 f"body ({framed[id(body)]!r}); attach to that FEM body instead")
        for body in scene.rigid_bodies:
            if body.massless and body.dynamic and id(body) not in framed.keys() | slaves.keys():
                raise InputError(f"rigid body {body.name!r} is massless (a marker) but attached "
                                 "to nothing: its step would be singular")
        for path in scene.paths:
            for pt in path.points:
                if isinstance(pt, FemPoint) and id(pt.fem) not in fem_ids | reduced_ids:
                    raise InputError(f"path {path.name!r}: FEM body {pt.fem.name!r} is not in "
                                     "the scene")
                if isinstance(pt, Frame) and pt.body is not None and id(pt.body) not in rigid_ids:
                    raise InputError(f"path {path.name!r}: rigid body {pt.body.name!r} is not in "
                                     "the scene")
        for joint in scene.joints:
            for body in joint.bodies:
                if body is not None and id(body) not in rigid_ids:
                    raise InputError(f"joint {joint.name!r} connects rigid body {body.name!r}, "
                                     "which is not in the scene")

    # ---- per-step pieces ---------------------------------------------------------------

    def kinematic_targets(self, t1: float) -> dict:
        """Prescribed roots: (p, R, twist) at t1."""
        out = {}
        for body in self.scene.rigid_bodies:
            if body.motion == "prescribed":
                s = body.prescribed_state(t1)
                out[body] = (s.position, s.rotation, np.concatenate([s.velocity,
                                                                      s.angular_velocity]))
        return out

    def prolongation(self) -> sparse.csr_matrix:
        """P (n_all x n_masters) at the current poses (module docstring)."""
        rows = [self.master_rows]
        cols = [np.arange(self.n_masters)]
        vals = [np.ones(self.n_masters)]

        def carried(all_rows: np.ndarray, d: np.ndarray, root: RigidBody) -> None:
            """3 rows per point d (n, 3) relative to the root: [1, -[d]x] on its 6 columns."""
            c0 = self.master_col[id(root)]
            n = len(d)
            G = np.zeros((n, 3, 6))
            G[:, :, :3] = np.eye(3)
            G[:, :, 3:] = -_skews(d)
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
        P0 = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                       np.concatenate(cols))),
                               shape=(self.n_all, self.n_masters))
        # rows derived from others: embedded FEM bodies (W), lift coordinates (G_g) and
        # frame-attached bodies (J)
        if self.embedded or self.scene.lift_attachments or self.scene.frame_attachments:
            Z = self._embedding_map + self._lift_matrix() + self._frame_matrix()
            return self._chain(Z.tocsr(), P0).tocsr()
        return P0

    def known_velocities(self, h: float, targets: dict) -> np.ndarray:
        """z_k: prescribed twists at t1, secant velocities of slave nodes of prescribed roots."""
        z = np.zeros(self.n_all)
        for body, (_, _, twist) in targets.items():
            o = self.rigid_offset[id(body)]
            z[o:o + 6] = twist
        for att in self.rigid_attachments:
            root = self.root[id(att.slave)]
            if root in targets:
                p1, R1, twist = targets[root]
                d1 = R1 @ root.rotation.T @ (att.slave.position - root.position)
                o = self.rigid_offset[id(att.slave)]
                z[o:o + 3] = twist[:3] + np.cross(twist[3:], d1)
                z[o + 3:o + 6] = twist[3:]
        for s in self.slaves:
            root = self.root[id(s.attachment.body)]
            if root in targets:
                p1, R1, _ = targets[root]
                x0 = s.attachment.positions()
                x1 = p1 + (x0 - root.position) @ (R1 @ root.rotation.T).T
                z[s.rows] = ((x1 - x0) / h).ravel()
        for att in self.scene.lift_attachments:        # g is linear in (p, R): the secant
            root = self.root[id(att.body)]
            if root in targets:
                p1, R1, _ = targets[root]
                turn = R1 @ root.rotation.T
                g1 = att.lift.coordinates(p1 + turn @ (att.body.position - root.position),
                                          turn @ att.body.rotation)
                z[self.reduced_offset[id(att.reduced)] + att.columns] = \
                    (g1 - att.coordinates()) / h
        if self.embedded or self.scene.frame_attachments:
            z = self._chain((self._embedding_map + self._frame_matrix()).tocsr(), z)
        return z

    def _rigid_wrenches(self, t1: float, h: float | None, A, b):
        """Force elements: wrenches into b (times h, or 1 for statics), Jacobian blocks into
        A (-h D - h^2 K, or -K for statics); returns the wrench per body id."""
        scene = self.scene
        forces = {}
        known = {id(x) for x in scene.rigid_bodies}
        scale = 1.0 if h is None else h
        for element in scene.forces:
            for body, wrench in element.wrenches(t1):
                wrench = _checked(element, known, body, wrench, (6,))
                o = self.rigid_offset[id(body)]
                b[o:o + 6] += scale * wrench
                forces[id(body)] = forces.get(id(body), np.zeros(6)) + wrench
            for bi, bj, K, D in getattr(element, "jacobians", lambda t: ())(t1):
                K, D = (_checked(element, known, bi, np.zeros((6, 6)) if X is None else X,
                                 (6, 6), bj) for X in (K, D))
                i, j = self.rigid_offset[id(bi)], self.rigid_offset[id(bj)]
                if h is None:
                    A.append((i, j, -K))
                else:
                    A.append((i, j, -h * D - h * h * K))
                    b[i:i + 6] -= h * D @ bj.twist
        return forces

    def dynamics(self, h: float, t1: float):
        """A_all, b_all (module docstring) and the applied forces f_all (for K_geo)."""
        scene = self.scene
        blocks, b, f_all = [], np.zeros(self.n_all), np.zeros(self.n_all)
        for body in scene.fem_bodies:
            o, n = self.fem_offset[id(body)], self.fem_size[id(body)]
            body.assemble(tangent=True)
            K = _csr(body.K)
            M = _mass(body)
            v = body.v.x.array[:n]
            Mv = M @ v
            f = -body.R.array[:n]
            b[o:o + n] = Mv + h * f
            f_all[o:o + n] = f - body.alpha * Mv - body.beta * (K @ v)
            blocks.append(((1.0 + h * body.alpha) * M + (h * body.beta + h * h) * K).tocsr())
        for body in scene.reduced_bodies:       # the same, dense r x r (advance_reduced)
            o, r = self.reduced_offset[id(body)], body.r
            K, f, M, v = body.tangent(), body.force(), body.M, body.qdot
            b[o:o + r] = M @ v + h * f
            f_all[o:o + r] = f - body.alpha * (M @ v) - body.beta * (K @ v)
            blocks.append(sparse.csr_matrix((1.0 + h * body.alpha) * M
                                            + (h * body.beta + h * h) * K))
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
            b[o:o + 6] += M @ u + h * (f - D @ u)
            f_all[o:o + 6] += f
        extra: list = []
        element_wrenches = self._rigid_wrenches(t1, h, extra, b)
        for key, wrench in element_wrenches.items():
            o = self.rigid_offset[key]
            f_all[o:o + 6] += wrench
        A = self._stack(blocks, rigid_blocks, extra)
        if scene.paths:
            F, K, D = self.path_terms(t1, h)
            z = self.current_velocities()
            b += h * F - h * (D @ z)
            A = (A - h * D - h * h * K).tocsr()
            f_all += F
        if scene.loads:
            F = self.load_vector(t1)
            b += h * F
            f_all += F
        return A, b, f_all

    def load_vector(self, t: float) -> np.ndarray:
        """The load elements' forces at time t, all-space (LoadElement)."""
        F = np.zeros(self.n_all)
        for element in self.scene.loads:
            for body, f in element.master_loads(t):
                what = f"load element {type(element).__name__}"
                if isinstance(body, FemBody) and id(body) in self.fem_offset:
                    o, n = self.fem_offset[id(body)], self.fem_size[id(body)]
                elif isinstance(body, ReducedFemBody) and id(body) in self.reduced_offset:
                    o, n = self.reduced_offset[id(body)], body.r
                elif isinstance(body, RigidBody) and id(body) in self.rigid_offset:
                    o, n = self.rigid_offset[id(body)], 6
                else:
                    raise InputError(f"{what} loads {getattr(body, 'name', body)!r}, which is "
                                     "not a body of this scene")
                f = np.asarray(f, dtype=float).ravel()
                if f.shape != (n,) or not np.all(np.isfinite(f)):
                    raise InputError(f"{what}: expected {n} finite values for "
                                     f"{body.name!r}, got shape {f.shape}")
                F[o:o + n] += f
        return F

    def current_velocities(self) -> np.ndarray:
        """z: the FEM nodal velocities and the rigid twists (all-space)."""
        z = np.zeros(self.n_all)
        for body in self.scene.fem_bodies:
            o, n = self.fem_offset[id(body)], self.fem_size[id(body)]
            z[o:o + n] = body.v.x.array[:n]
        for body in self.scene.reduced_bodies:
            o = self.reduced_offset[id(body)]
            z[o:o + body.r] = body.qdot
        for body in self.scene.rigid_bodies:
            o = self.rigid_offset[id(body)]
            z[o:o + 6] = body.twist
        return z

    def path_map(self, path: "PointPath") -> sparse.csr_matrix:
        """G (3n x n_all): x_a' = G z for the path's points (module docstring)."""
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
        n = 3 * len(path.points)
        if not rows:
            return sparse.csr_matrix((n, self.n_all))
        return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                         np.concatenate(cols))),
                                 shape=(n, self.n_all))

    def path_terms(self, t: float, h: float | None):
        """All paths at time t: F = G^T f (all-space), K = G^T K_p G + K_r and D = G^T D_p G
        (n_all x n_all, the derivatives of F by the positions and the velocities)."""
        scene = self.scene
        F = np.zeros(self.n_all)
        K = sparse.csr_matrix((self.n_all, self.n_all))
        D = sparse.csr_matrix((self.n_all, self.n_all))
        for path in scene.paths:
            result = path.evaluate(t)
            G = self.path_map(path)
            F += G.T @ result.forces.ravel()
            K = K + G.T @ sparse.csr_matrix(result.stiffness) @ G
            D = D + G.T @ sparse.csr_matrix(result.damping) @ G
            # rigid frames: the levers turn with the body (point_force_wrenches' extra terms)
            rigid = [(i, pt) for i, pt in enumerate(path.points)
                     if isinstance(pt, Frame) and pt.body is not None]
            if rigid:
                rr, cc, vv = [], [], []
                for i, pt in rigid:
                    o = self.rigid_offset[id(pt.body)]
                    Ki = np.zeros((self.n_all, 6))
                    Ki[o:o + 6] += pt.wrench_stiffness(result.forces[i])
                    # K_bc[:, 3:] -= sum_{a on b} G_a^T D_a,i [w]x [r]x for column body c = i's
                    Dcol = (G.T @ sparse.csr_matrix(result.damping[:, 3 * i:3 * i + 3])).toarray()
                    Ki[:, 3:] -= Dcol @ skew(pt.body.angular_velocity) @ skew(pt.lever())
                    nz = np.nonzero(Ki)
                    rr.append(nz[0]), cc.append(o + nz[1]), vv.append(Ki[nz])
                K = K + sparse.csr_matrix((np.concatenate(vv), (np.concatenate(rr),
                                                                np.concatenate(cc))),
                                          shape=(self.n_all, self.n_all))
        return F, K.tocsr(), D.tocsr()

    def static_forces(self, t: float, tangent: bool):
        """f_all (FEM -dPi/du; rigid m g plus force elements) and, if asked, K_all = -df/dq."""
        scene = self.scene
        blocks, f_all = [], np.zeros(self.n_all)
        for body in scene.fem_bodies:
            o, n = self.fem_offset[id(body)], self.fem_size[id(body)]
            body.assemble(tangent=tangent)
            f_all[o:o + n] = -body.R.array[:n]
            if tangent:
                blocks.append(_csr(body.K))
        for body in scene.reduced_bodies:
            o = self.reduced_offset[id(body)]
            f_all[o:o + body.r] = body.force()
            if tangent:
                blocks.append(sparse.csr_matrix(body.tangent()))
        for body in scene.rigid_bodies:
            if body.dynamic:
                o = self.rigid_offset[id(body)]
                f_all[o:o + 3] += body.mass * scene.gravity
        extra: list = []
        self._rigid_wrenches(t, None, extra, f_all)
        K_path = None
        if scene.paths:
            F, K_path, _ = self.path_terms(t, None)
            f_all += F                           # statics: whole wrenches on rigid rows
        if scene.loads:
            f_all += self.load_vector(t)
        if not tangent:
            return f_all, None
        zeros = [np.zeros((6, 6)) for _ in scene.rigid_bodies]
        K_all = self._stack(blocks, zeros, extra)
        if K_path is not None:
            K_all = (K_all - K_path).tocsr()
        return f_all, K_all

    def _stack(self, fem_blocks, rigid_blocks, extra) -> sparse.csr_matrix:
        parts = list(fem_blocks)
        if rigid_blocks:
            parts.append(sparse.block_diag([sparse.csr_matrix(b) for b in rigid_blocks],
                                           format="csr"))
        A = sparse.block_diag(parts, format="csr") if parts else \
            sparse.csr_matrix((self.n_all, self.n_all))
        if extra:
            rows, cols, vals = [], [], []
            for i, j, X in extra:
                r, c = np.meshgrid(i + np.arange(6), j + np.arange(6), indexing="ij")
                rows.append(r.ravel()), cols.append(c.ravel()), vals.append(X.ravel())
            A = A + sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                              np.concatenate(cols))),
                                      shape=A.shape)
        return A.tocsr()

    def geometric_stiffness(self, f_all: np.ndarray, P: sparse.csr_matrix) -> sparse.csr_matrix:
        """K_geo on the masters (module docstring): sum_s [f_s]x [d_s]x on each dynamic root's
        rotation block, for the applied forces f_all on the slaves (an embedded body's
        forces first moved to its master's nodes, W^T f_s; a lift as levers R_k)."""
        K_frames = None
        if self.scene.frame_attachments:
            f_all = f_all.copy()
            rows, cols, vals = [], [], []
            for att in self.scene.frame_attachments:    # leaves: before the embedded bodies
                wrench = f_all[self.rigid_offset[id(att.slave)] + np.arange(6)]
                o = self._body_offset(att.frame.body)
                for c, J in att.jacobian():
                    f_all[o + c] += J.T @ wrench
                c, Kf = att.stiffness(wrench)
                rr, cc = np.meshgrid(o + c, o + c, indexing="ij")
                rows.append(rr.ravel()), cols.append(cc.ravel()), vals.append(Kf.ravel())
            K_frames = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                                 np.concatenate(cols))),
                                         shape=(self.n_all, self.n_all))
            K_frames = (P.T @ K_frames @ P).tocsr()
        if self.embedded:
            f_all = f_all.copy()
            for att in self.embedded:                   # slaves before their masters
                o_s, o_m = self.fem_offset[id(att.slave)], self.fem_offset[id(att.master)]
                f_all[o_m:o_m + att.W.shape[1]] += att.W.T @ f_all[o_s:o_s + att.W.shape[0]]
        K = {}
        for att in self.scene.lift_attachments:
            root = self.root[id(att.body)]
            if root.dynamic:
                f = f_all[self.reduced_offset[id(att.reduced)] + att.columns].reshape(4, 3)
                levers = np.vstack([att.body.position - root.position, att.body.rotation.T])
                K[id(root)] = K.get(id(root), 0.0) + np.einsum("nij,njk->ik", _skews(f),
                                                               _skews(levers))
        for s in self.slaves:
            root = self.root[id(s.attachment.body)]
            if root.dynamic:
                f = f_all[s.rows].reshape(-1, 3)
                d = s.attachment.positions() - root.position
                K[id(root)] = K.get(id(root), 0.0) + np.einsum("nij,njk->ik", _skews(f),
                                                               _skews(d))
        for att in self.rigid_attachments:
            root = self.root[id(att.slave)]
            if root.dynamic:
                o = self.rigid_offset[id(att.slave)]
                K[id(root)] = K.get(id(root), 0.0) + skew(f_all[o:o + 3]) @ skew(
                    att.slave.position - root.position)
        rows, cols, vals = [], [], []
        for key, block in K.items():
            c0 = self.master_col[key] + 3
            r, c = np.meshgrid(c0 + np.arange(3), c0 + np.arange(3), indexing="ij")
            rows.append(r.ravel()), cols.append(c.ravel()), vals.append(block.ravel())
        K_roots = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                            np.concatenate(cols))),
                                    shape=(self.n_masters, self.n_masters)) if rows else \
            sparse.csr_matrix((self.n_masters, self.n_masters))
        return K_roots if K_frames is None else (K_roots + K_frames).tocsr()

    def joint_forces(self, parts) -> np.ndarray:
        """sum G^T lambda over (joint, ConstraintRows, lambda), on the all-space rigid rows."""
        out = np.zeros(self.n_all)
        for joint, rows, lam in parts:
            for body, G in zip(joint.bodies, (rows.G_a, rows.G_b)):
                if body is not None:
                    o = self.rigid_offset[id(body)]
                    out[o:o + 6] += G.T @ lam
        return out

    def joint_matrix(self, P) -> sparse.csr_matrix:
        """The bilateral joint rows on the masters, G P (static solve)."""
        blocks = self.joint_rows(P, np.zeros(self.n_all), 1.0, 0.0)[0]
        return sparse.vstack([g[2] for g in blocks]).tocsr()

    def joint_rows(self, P, z_k, h, beta):
        """(joint, rows, G P, c) of the bilateral and of the unilateral rows (module docstring)."""
        out = {"bilateral": [], "unilateral": []}
        for joint in self.scene.joints:
            for kind, rows in (("bilateral", joint.constraint()), ("unilateral",
                                                                    joint.unilateral())):
                if not len(rows):
                    continue
                G = np.zeros((len(rows), self.n_all))
                for body, G_body in zip(joint.bodies, (rows.G_a, rows.G_b)):
                    if body is not None:
                        o = self.rigid_offset[id(body)]
                        G[:, o:o + 6] += G_body
                if kind == "bilateral":
                    c = -beta * rows.phi / h
                else:                               # reach the limit, never cross it
                    c = np.where(rows.phi > 0, -rows.phi / h, -beta * rows.phi / h)
                G = sparse.csr_matrix(G)
                out[kind].append((joint, rows, (G @ P).tocsr(), c - G @ z_k))
        return out["bilateral"], out["unilateral"]

    # ---- updates -----------------------------------------------------------------------

    def advance(self, z: np.ndarray, h: float, targets: dict) -> None:
        """Velocities from z; free FEM dofs, free reduced coordinates and dynamic roots move
        by h z; prescribed bodies go to their targets; slaves are set from their masters."""
        for body, free in self.free_fem:
            o, n = self.fem_offset[id(body)], self.fem_size[id(body)]
            body.v.x.array[:n] = z[o:o + n]
            body.u.x.array[free] += h * z[o + free]
        for att in self.embedded:
            o, n = self.fem_offset[id(att.slave)], self.fem_size[id(att.slave)]
            att.slave.v.x.array[:n] = z[o:o + n]
        for body, free in self.free_reduced:
            o = self.reduced_offset[id(body)]
            body.qdot = z[o:o + body.r].copy()
            body.q[free] += h * z[o + free]
        for body in self.scene.rigid_bodies:
            o = self.rigid_offset[id(body)]
            if body.motion == "prescribed":
                p1, R1, twist = targets[body]
                body.position, body.rotation = p1, R1
                body.set_twist(twist)
            elif body.dynamic:
                body.set_twist(z[o:o + 6])
                if any(body is r for r in self.roots):
                    body.advance_pose(h)
        self.place_slaves()

    def place_slaves(self) -> None:
        for att in self.rigid_attachments:              # dependency order
            att.slave.position, att.slave.rotation = att.pose()
        for s in self.slaves:
            att = s.attachment
            u = att.fem.u.x.array.reshape(-1, 3)
            u[att.dofs] = att.positions() - att.fem.V.tabulate_dof_coordinates()[att.dofs]
        for att in reversed(self.embedded):             # masters before their slaves
            att.slave.u.x.array[:att.W.shape[0]] = att.displacement()
        self._place_lifts()
        for att in self.scene.frame_attachments:        # leaves: after every FEM body
            att.slave.position, att.slave.rotation = att.pose()
        for body in self.scene.fem_bodies:
            body.u.x.scatter_forward()
            body.v.x.scatter_forward()

    def _place_lifts(self) -> None:
        for att in self.scene.lift_attachments:
            att.reduced.q[att.columns] = att.coordinates()
        for body in self.scene.reduced_bodies:
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
            body.position = body.position + dq[c:c + 3]
            body.rotation = orthonormalize(exp_so3(dq[c + 3:c + 6]) @ body.rotation)
        self.place_slaves()

    def save(self):
        return ([b.u.x.array.copy() for b in self.scene.fem_bodies],
                [(b.position.copy(), b.rotation.copy()) for b in self.scene.rigid_bodies],
                [b.q.copy() for b in self.scene.reduced_bodies])

    def restore(self, saved) -> None:
        for body, u in zip(self.scene.fem_bodies, saved[0]):
            body.u.x.array[:] = u
        for body, (p, R) in zip(self.scene.rigid_bodies, saved[1]):
            body.position, body.rotation = p, R
        for body, q in zip(self.scene.reduced_bodies, saved[2]):
            body.set_q(q)

    def master_scale(self) -> float:
        vals = [np.abs(b.u.x.array).max() for b in self.scene.fem_bodies if b.u.x.array.size]
        vals += [np.abs(b.q).max() for b in self.scene.reduced_bodies if b.r]
        vals += [np.abs(b.position).max() for b in self.roots]
        return max(vals, default=1.0)

    def inverted(self) -> bool:
        for body in self.scene.reduced_bodies:
            detF = body.det_F()
            if detF.size and not np.nanmin(detF) > 0:
                return True
        for body in self.scene.fem_bodies:
            detF = body.det_F()
            if detF.size and not np.nanmin(detF) > 0:
                return True
        return False


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


def _pose_gap(att) -> float:
    """max |p - p_s|, |R - R_s| between the pose an attachment gives its slave body and the
    body's own pose (m and rad-like; round-off when in place)."""
    p, R = att.pose()
    return max(float(np.abs(p - att.slave.position).max()),
               float(np.abs(R - att.slave.rotation).max()))


def _checked(element, known, body, array, shape, other=None) -> np.ndarray:
    """``array`` as a finite float array of ``shape``, on bodies of the scene."""
    what = f"force element {type(element).__name__}"
    for b in (body, other or body):
        if not isinstance(b, RigidBody) or id(b) not in known:
            raise InputError(f"{what} acts on {b!r}, which is not a rigid body of this scene")
    array = np.asarray(array, dtype=float)
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise InputError(f"{what}: expected a finite array of shape {shape} for body "
                         f"{body.name!r}, got shape {array.shape}")
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


class _MumpsLU:
    """x = K^-1 b by a MUMPS LU factorization (petsc4py, one process); systems of at most
    ``DENSE_MAX`` unknowns (reduced and rigid bodies only) by dense LAPACK LU instead, which
    costs microseconds where building the PETSc matrix alone costs a millisecond."""

    DENSE_MAX = 400

    def __init__(self):
        self.ksp = PETSc.KSP().create(PETSc.COMM_SELF)
        self.ksp.setType("preonly")
        pc = self.ksp.getPC()
        pc.setType("lu")
        pc.setFactorSolverType("mumps")
        self._mat = None
        self._pattern = None

    def solve(self, K: sparse.csr_matrix, b: np.ndarray, what: str) -> np.ndarray:
        if K.shape[0] <= self.DENSE_MAX:
            try:
                out = np.linalg.solve(K.toarray(), b)
            except np.linalg.LinAlgError as exc:
                raise CoupledStepFailed(f"{what}: the dense LU failed ({exc}); a singular "
                                        "system: redundant joints, or a free body with no "
                                        "mass?") from exc
            if not np.all(np.isfinite(out)):
                raise CoupledStepFailed(f"{what}: the dense solve gave non-finite values; a "
                                        "singular system: redundant joints, or a free body "
                                        "with no mass?")
            return out
        K = K.tocsr()
        K.sort_indices()
        n = K.shape[0]
        indptr = K.indptr.astype(PETSc.IntType)
        indices = K.indices.astype(PETSc.IntType)
        pattern = (n, indptr.tobytes(), indices.tobytes())
        if self._mat is not None and pattern == self._pattern:
            self._mat.setValuesCSR(indptr, indices, K.data)    # same pattern: keep the analysis
            self._mat.assemble()
        else:
            if self._mat is not None:
                self.ksp.reset()                # a new pattern (or size): a new analysis
                self._mat.destroy()
            self._mat = PETSc.Mat().createAIJ(size=(n, n), csr=(indptr, indices, K.data),
                                              comm=PETSc.COMM_SELF)
            self._mat.assemble()
            self._pattern = pattern
        self.ksp.setOperators(self._mat)
        rhs = self._mat.createVecLeft()
        x = self._mat.createVecRight()
        rhs.array[:] = b
        try:
            self.ksp.solve(rhs, x)
        except PETSc.Error as exc:
            raise CoupledStepFailed(f"{what}: the LU factorization failed ({exc}); a singular "
                                    "system: redundant joints, or a free body with no mass?") \
                from exc
        reason = self.ksp.getConvergedReason()
        out = x.array.copy()
        rhs.destroy()
        x.destroy()
        if reason < 0 or not np.all(np.isfinite(out)):
            raise CoupledStepFailed(f"{what}: the direct solve failed (KSP reason {reason}, "
                                    "finite: " f"{bool(np.all(np.isfinite(out)))}); a singular "
                                    "system: redundant joints, or a free body with no mass?")
        return out
