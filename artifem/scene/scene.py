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

    FEM:    A = M + h D + h^2 K,                        b = M v + h f,     f = -dPi/du,
            (D = alpha M + beta K_0, K_0 the stiffness at rest: FemBody.rest_stiffness)
            (``integrators.step_system``, which SemiImplicitEuler solves for dv = v+ - v)
    rigid:  A = M - h D - h^2 K_e,                      b = M u + h (f - D u),
            (gravity m g, the gyroscopic wrench, force elements; D and K_e the
            velocity and pose Jacobians of the wrenches, the gyroscopic one in D;
            M at the start of the step)

stacked into A_all, b_all (force elements add their off-diagonal blocks) and
reduced by P, with the constraint rows as Lagrange multipliers:

    [ P^T A_all P - h^2 K_geo    -G_m^T ] [ z_m+   ]   [ P^T (b_all - A_all z_k) ]
    [ G_m                         0     ] [ lambda ] = [ -beta phi / h - G z_k   ],

G the rows of every constraint (``Scene.constraints``: the joints and their limits,
the contacts (:mod:`artifem.multibody.contact`),
each a list of :class:`~artifem.multibody.constraint_rows.RowBlock` with bounds on
lambda) on the all-space coordinates (:mod:`artifem.scene.constraint_map`), G_m = G P
and lambda the impulses (force times h), solved through the Schur complement of the
rows (:mod:`artifem.scene.constraints`: minimum-norm impulses for redundant rows,
an active set for the bounded rows, one factorization of the master block).

Rigid bodies alone: with forces that have no Jacobians (gravity) the step is
symplectic Euler (velocities from forces at q, positions from u+), so the energy
error of an undamped system oscillates with an O(h) amplitude and does not drift
(a double pendulum: 2.9e-3 m g L at h = 1 ms over 10 s). Stiffness and damping
Jacobians, and the gyroscopic one, make it (linearized) backward Euler, which
dissipates at O(h) and is stable for stiff elements.

Drift: Baumgarte-style velocity stabilization. Since phi(q+) = phi(q) + h G u+
+ O(h^2), the row G u+ = -beta phi / h leaves phi(q+) = (1 - beta) phi(q) +
O(h^2): with ``stabilization`` beta = 1 (the default) the error is removed in one
step and stays O(h^2 |u|^2 / length) instead of growing. It costs no second
solve; the price is that the joint reaction does the work -lambda . beta phi / h,
which vanishes with phi. Limits are rows G_l u+ >= -phi_l / h (reach the limit,
never cross it; -beta phi_l / h once crossed) with lambda_l >= 0.

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

Statics (:meth:`Scene.solve_static`): Newton on the master forces
F_m + G_m^T lambda = 0 with phi = 0 on the free rows and phi >= 0, lambda >= 0 on the
bounded ones (joint limits), with the same tangent without the inertia,

    [ P^T K_all P - K_geo   G_a^T ] [ dq ]   [ F_m  ]
    [ G_a                   0     ] [ mu ] = [ -phi ],      lambda = -mu,

G_a the free rows and the bounded rows an active set holds as equalities (the others
at lambda = 0 while phi + G dq >= 0; :func:`~artifem.scene.constraints.solve_saddle`,
one KKT factorization per trial, the trials starting from the active set of the Schur
complement of the tangent when it factors alone), K_all = d^2 Pi/du^2 on the FEM dofs and -K_e
on the rigid ones, master displacements dq = free FEM du and [dp; dtheta] of each dynamic root
(p += dp, R = exp([dtheta]x) R), slaves set from the poses; a backtracking
line search on |[F_m; phi]| refuses inverted elements. Inside Newton's region (the
last step was full and lowered the merit) the tangent also takes the rows' own turning,
K - P^T d(G^T lambda)/dq P at the last solve's forces (by row keys; each block's
``stiffness(lambda)``: a joint's levers, a mesh contact's levers, normals and sliding
closest points, :mod:`~artifem.multibody.distance_hessian`), which Newton needs for more
than a linear rate where loaded joints and contacts turn (the loaded foot: 0.5 per
iteration without it); where that saddle does not solve, the plain tangent is taken.
Outside, a scene whose only stiffness in a joint's free direction would come from it (a
rigid pendulum under gravity alone) has a singular tangent there.

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
same backward-Euler block, dense r x r: A = M~ + h D~ + h^2 K~ (D~ = U^T D U),
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
rows Z, lifts included); its forces reach K_geo as W^T f_s. On a reduced master
the same rows are the dense G = W U on its q (z_s = W U q'), the slave placed at
x_s = W (X_m + u_bar + U q) + c (``EmbeddedFemAttachment.jacobian``, ``positions``).

Load elements (:class:`LoadElement`, ``master_loads(t)``): explicit forces on
FEM nodes, reduced coordinates and rigid bodies (a skin pressure through G^T),
b += h F, and in the static residual, ramped by the load factor with the other
loads. Their Jacobians dF/dx (``master_load_jacobians(t)``, e.g. a follower
pressure's G^T (df/dx) G) enter the static tangent, so Newton sees them. A load
with a potential (``potential_energy(t)``: a constant force) enters the scene's
energy; one without (a follower pressure) leaves statics the force residual as
its merit.

Rigid bodies on frames of FEM bodies (:class:`FrameAttachment`, the paper's
section 3.2 and Fig. 11): a body follows a frame (origin and polar or Procrustes
rotation, :mod:`~artifem.multibody.frame_attachments`) on a full or reduced body,
u = J v_nodes; its rows of P are J times the nodes' (derived rows, like the
embedded ones), and K_geo adds d(J^T [f; tau])/dx. A massless body
(``RigidBody.marker``) on a frame carries joints: joints between frames on
deformable bodies. The joints' reactions load such attachments like any force;
they enter K_geo lagged by one step (or one Newton iteration).

Statics with constraints use the exact-penalty merit E + E_c + rho |gap|_1 (E_c the
compliant rows' springs, sum max(-phi, 0)^2 / 2C; rho = 2 max |lambda|; gap = phi on
free rows, min(phi, 0) on bounded ones) when every force and load has an energy, and
otherwise the force residual left after the compliant rows' forces, the sliding
friction rows' forces of the last solve and the least-squares reactions of the rows
it held active (carried by row keys to a configuration where rows came or went).
Each Newton solve starts its active set from the last one's
(:class:`~artifem.scene.constraints.ActiveSetMemory`, by row keys, across the load
increments too, and back to the last converged one when an increment fails): started
from the rows' own bounds, the friction passes of a foot's hundreds of contact rows
circled and the solve stopped ("did not settle"). Friction sticks to where the load
increment found each point (:mod:`~artifem.scene.increment_slip`: a row's slip s
since then is its phi, and it is in the merit's gap while it sticks; sliding rows'
forces do work -lambda_h . G dq in the energy merit). Once two of a solve's steps
raised the merit or lowered it by less than a tenth, its contacts hold their pairs
(``hold_pairs``) for the rest of it: a vertex pressed near the edge between two
triangles went from one to the other and back in each iteration, and on the level-1
foot the merit stalled near 0.33 (``HOLD_AFTER_RISES``).

Scenes of at most ``DENSE_MAX`` (direct_solver) coordinates (reduced and rigid bodies)
are solved by a dense LU instead of MUMPS.

Islands
-------
Bodies interact within a step only through attachments, paths, loads, joints and
contacts (``Scene.constraints``). A deformable body that none of them names
(``item.bodies``) is an island of its own and is advanced by the scene's integrator
with its own solver: a full FEM body by ``integrator.advance(body, h, solver)`` with a PETSc
:class:`~artifem.linear_solver.LinearSolver` (CG with algebraic multigrid by
default; distributed under ``mpiexec``), a reduced body by
``integrator.advance_reduced(body, h)``; semi-implicit (the equations above,
the same step) or implicit (Newton with a line search, ``ImplicitEuler``).
Everything else (rigid bodies and the deformable bodies coupled to anything)
forms the coupled island of the layout above, semi-implicit as above, or
implicit (:mod:`artifem.scene.implicit_step`: the same equations solved by
Newton, joints and limits included). Its linear system is solved directly (one
LU of the KKT matrix, serial) or, for FEM bodies carried by rigid bodies, with
the FEM blocks distributed and the rigid coordinates eliminated by a Schur
complement (:mod:`artifem.scene.schur_island`, ``island_solver="schur"``, the
default under ``mpiexec``). Statics
likewise: ``integrators.solve_static`` per body on its own, the Newton above for
the coupled island. Controllers, the health check, halving and
``save_state``/``restore_state`` cover every island at once.
"""

from __future__ import annotations

import time

from dataclasses import dataclass
from typing import Callable

import numpy as np
from mpi4py import MPI
from scipy import sparse

from artifem.errors import (
    ElementInversionError,
    InputError,
    LinearSolveError,
    SingularSystem,
    StepFailed,
    UnknownNameError,
)
from artifem.fem_body import FemBody
from artifem.integrators import (
    ImplicitEuler,
    SemiImplicitEuler,
    StaticCounts,
    ramp_load,
    solve_static,
    solve_static_reduced,
)
from artifem.linear_solver import DEFAULT_METHOD, METHODS, LinearSolver
from artifem.multibody.attachments import (
    EmbeddedFemAttachment,
    FrameAttachment,
    LiftAttachment,
    NodeAttachment,
    RigidAttachment,
    dof_positions,
    pose_gap,
)
from artifem.multibody.contact import ContactForces, PlaneContact
from artifem.multibody.contact_pressure import boundary_areas, contact_pressure
from artifem.multibody.joints import Joint
from artifem.multibody.loads import LoadElement
from artifem.multibody.point_paths import PointPath
from artifem.multibody.rigid_body import RigidBody
from artifem.multibody.force_elements import ForceElement
from artifem.reduction.reduced_body import ReducedFemBody
from artifem.scene.constraints import (
    ActiveSetMemory,
    impulses_by_constraint,
    solve_constrained,
    solve_saddle,
)
from artifem.scene.direct_solver import DirectSolver
from artifem.scene.implicit_step import implicit_step
from artifem.scene.increment_slip import IncrementSlip
from artifem.scene.schur_island import SchurIsland
from artifem.scene.layout import STATICS_ADVICE, STEP_ADVICE, Layout

__all__ = ["Scene", "SceneState"]

#: A controller sets inputs (excitations, loads) for the step from t0 to t1.
Controller = Callable[["Scene", float, float], None]

INTEGRATORS = {"semi-implicit": SemiImplicitEuler, "implicit": ImplicitEuler}
#: Statics holds the contacts' pairs (``hold_pairs``) for the rest of a Newton solve once
#: this many of its steps raised the merit or lowered it by less than a tenth: its
#: iterations circle between the features a contact point is paired with, or stall at
#: them (Scene._newton_iterations).
HOLD_AFTER_RISES = 2
#: The scene's lists of bodies, and of every component (``scene_group`` of each class).
BODY_GROUPS = ("fem_bodies", "reduced_bodies", "rigid_bodies")
COMPONENT_GROUPS = BODY_GROUPS + (
    "node_attachments",
    "rigid_attachments",
    "embedded_attachments",
    "lift_attachments",
    "frame_attachments",
    "joints",
    "contacts",
    "paths",
    "forces",
    "loads",
)


def _merge_counts(a: list, b: list) -> StaticCounts:
    """The larger Newton iteration count of each increment over two islands (their
    adaptive schedules may differ in length: the shorter is padded with zeros), and the
    iterations both spent on failed increments; their residuals, one island's increments
    after the other's."""
    n = max(len(a), len(b))
    return StaticCounts(
        [max(a[k] if k < len(a) else 0, b[k] if k < len(b) else 0) for k in range(n)],
        failed=getattr(a, "failed", 0) + getattr(b, "failed", 0),
        residuals=getattr(a, "residuals", []) + getattr(b, "residuals", []),
    )


@dataclass(frozen=True)
class SceneState:
    """A scene's complete state (:meth:`Scene.save_state`): restore it to go back."""

    t: float
    bodies: list  # body.state() of every body, in Scene.bodies order
    elements: list  # save_state() of the force and path elements that have one
    joints: tuple  # the joints' last impulses, step and reactions


@dataclass(frozen=True)
class _Failure:
    message: str
    inverted: list  # (body name, input element indices, min det F)


class Scene:
    """FEM bodies, rigid bodies, attachments, joints and force elements (module docstring).

    Args:
        gravity: the gravitational acceleration (world), applied to every body:
            an FEM body's own ``gravity`` constant is set to it when added.
        stabilization: Baumgarte beta in [0, 1], the fraction of the joint position error
            removed per step (module docstring: drift).
        geometric_stiffness: include K_geo in the step and the static tangent (default);
            False drops it, for comparisons.
        max_halvings: how many times a failing step may be halved (:meth:`step`).
        integrator: how the bodies that nothing couples are stepped (islands, module
            docstring): ``"semi-implicit"`` (ArtiSynth's default, the same equations as
            the coupled step), ``"implicit"`` (Newton with a line search), or an object
            with ``advance(body, h, solver)`` and ``advance_reduced(body, h)``.
        linear_solver: the :class:`~artifem.linear_solver.LinearSolver` method of those
            FEM bodies (PETSc: CG with algebraic multigrid by default, or ``"mumps"``).
        fallback: the integrator that retries a step the semi-implicit one fails (an
            inverted element, volumes not held, a failed solve) before the step is
            halved: ``"implicit"`` (the default: Newton on the same backward Euler
            equations, :meth:`step`) or None (halve at once). Used only when
            ``integrator`` is the semi-implicit one and the island is not the
            distributed Schur island.
        island_solver: how the coupled island's linear system is solved: ``"direct"``
            (one sparse or dense LU of the whole KKT system, serial) or ``"schur"`` (FEM
            blocks distributed, solved by ``linear_solver``, the rigid coordinates by a
            Schur complement: :mod:`artifem.scene.schur_island`); default: ``"schur"``
            when the FEM bodies run on several MPI ranks, else ``"direct"``.
    """

    def __init__(
        self,
        gravity=(0.0, 0.0, -9.81),
        *,
        stabilization: float = 1.0,
        geometric_stiffness: bool = True,
        max_halvings: int = 4,
        integrator="semi-implicit",
        linear_solver: str = DEFAULT_METHOD,
        island_solver: str | None = None,
        fallback: str | None = "implicit",
    ):
        g = np.asarray(gravity, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise InputError(f"gravity must be 3 finite numbers, got {gravity!r}")
        if not 0.0 <= stabilization <= 1.0:
            raise InputError(f"stabilization must be in [0, 1], got {stabilization!r}")
        if int(max_halvings) != max_halvings or max_halvings < 0:
            raise InputError(f"max_halvings must be an integer >= 0, got {max_halvings!r}")
        if isinstance(integrator, str):
            if integrator not in INTEGRATORS:
                raise InputError(
                    f"unknown integrator {integrator!r}; choose one of {sorted(INTEGRATORS)}"
                )
            integrator = INTEGRATORS[integrator]()
        for method in ("advance", "advance_reduced"):
            if not callable(getattr(integrator, method, None)):
                raise InputError(f"integrator {integrator!r} has no {method}() method")
        if fallback not in (None, "implicit"):
            raise InputError(f"fallback must be 'implicit' or None, got {fallback!r}")
        if linear_solver not in METHODS:
            raise InputError(f"unknown linear solver {linear_solver!r}; choose one of {METHODS}")
        if island_solver not in (None, "direct", "schur"):
            raise InputError(f"island_solver must be 'direct' or 'schur', got {island_solver!r}")
        self.integrator = integrator
        #: the integrator that retries a failed semi-implicit step before it is halved
        self.fallback = (
            ImplicitEuler()
            if fallback is not None and getattr(integrator, "name", None) == "semi-implicit"
            else None
        )
        self.fallbacks = 0  # steps completed by the fallback integrator
        self.linear_solver = linear_solver
        self.island_solver = island_solver
        self._schur = None  # the SchurIsland stepping the coupled island, if any
        self._linear_solvers: dict[tuple, LinearSolver] = {}
        self._comm = MPI.COMM_SELF  # the FEM bodies' communicator (one for the scene)
        self._islands = None  # (free FEM, free reduced, coupled FEM, coupled reduced)
        self._gravity = g
        self.max_halvings = int(max_halvings)
        self.controllers: list[Controller] = []
        self.halvings = 0  # step halvings so far
        self.min_det_F = np.inf  # smallest det F after any accepted step
        self.stabilization = float(stabilization)
        self.load_factor = 1.0  # scales the load elements (ramped by solve_static)
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
        self.contacts: list[PlaneContact] = []
        self.forces: list[ForceElement] = []
        self.paths: list[PointPath] = []
        self.loads: list = []
        self._layout = None
        self._solver = DirectSolver()
        self._active_sets = ActiveSetMemory()  # the last solve's active rows (warm start)
        self._impulses: dict = {}
        self._reference_areas: dict = {}  # (FEM body, degree) -> its boundary areas
        self._last_h = 1.0
        self._reactions = None  # the joints' last forces, all-space (for K_geo)
        self.last_solve: dict = {}

    @property
    def comm(self) -> MPI.Comm:
        """The MPI communicator of the scene's FEM bodies (COMM_SELF without any)."""
        return self._comm

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
            # Each component declares its list (scene_group); force and load elements are
            # recognized by their protocols (wrenches(t), master_loads(t)).
            group = getattr(item, "scene_group", None)
            if group is None and isinstance(item, ForceElement):
                group = "forces"
            elif group is None and LoadElement.is_load(item):
                group = "loads"
            if group not in COMPONENT_GROUPS:
                raise TypeError(
                    f"cannot add {type(item).__name__} to a Scene: expected "
                    "a FemBody, ReducedFemBody, RigidBody, an attachment, a Joint, "
                    "a PlaneContact, a path, a force element with wrenches(t) or a "
                    "load element with master_loads(t)"
                )
            members = getattr(self, group)
            name = getattr(item, "name", "")
            if group in BODY_GROUPS and any(name == b.name for b in self.bodies):
                raise InputError(
                    f"a body named {name!r} is already in the scene (bodies "
                    "are named in errors, records and output files: give each "
                    "its own name)"
                )
            if any(item is other for other in members):
                raise InputError(f"{type(item).__name__} {name!r} is already in the scene")
            if group == "fem_bodies":
                comm = item.mesh.comm
                if self.fem_bodies and comm.size != self._comm.size:
                    raise InputError(
                        f"FEM body {name!r} runs on {comm.size} MPI ranks, "
                        f"the scene's other FEM bodies on {self._comm.size}"
                    )
                self._comm = comm
            if group in ("fem_bodies", "reduced_bodies"):
                item.gravity.value[:] = self.gravity
            if group == "rigid_bodies" and item.motion == "prescribed":
                item.follow_trajectory(self.t)
            if group == "loads" and not isinstance(getattr(item, "bodies", None), (tuple, list)):
                raise InputError(
                    f"load element {item!r} has no ``bodies`` (the tuple of "
                    "bodies it loads; LoadElement)"
                )
            members.append(item)
            self._layout = None

    def couplings_of(self, body) -> list:
        """The components other than bodies (attachments, joints, paths, force and load
        elements) whose ``bodies`` include ``body``."""
        return [
            item
            for group in COMPONENT_GROUPS
            if group not in BODY_GROUPS
            for item in getattr(self, group)
            if any(b is body for b in getattr(item, "bodies", ()))
        ]

    def remove(self, *items) -> None:
        """Take components out of the scene (the inverse of :meth:`add`): e.g. a full body
        and its couplings, for the reduced body that replaces them. Whatever stays must
        not name a removed body (checked at the next step or static solve)."""
        for item in items:
            group = next(
                (g for g in COMPONENT_GROUPS if any(item is other for other in getattr(self, g))),
                None,
            )
            if group is None:
                raise InputError(
                    f"{type(item).__name__} {getattr(item, 'name', '')!r} is not in the scene"
                )
            members = getattr(self, group)
            members.pop(next(k for k, other in enumerate(members) if other is item))
            self._layout = None
        self._comm = self.fem_bodies[0].mesh.comm if self.fem_bodies else MPI.COMM_SELF
        for solver in self._linear_solvers.values():  # their PETSc objects, freed now
            solver.destroy()
        self._linear_solvers.clear()
        self._schur = None

    def check(self) -> None:
        """Validate the scene and index its coordinates (done automatically when needed)."""
        self._layout = None
        self._ready()

    def islands(self) -> tuple[list, list]:
        """(bodies stepped on their own, bodies of the coupled island): a deformable body
        that no attachment, path, load or constraint names is its own island (module
        docstring)."""
        self._ready()
        free_fem, free_reduced, fem, reduced = self._islands
        return [*free_fem, *free_reduced], [*fem, *reduced, *self.rigid_bodies]

    def _ready(self) -> "Layout":
        if self._layout is None:
            coupled = {
                id(b)
                for item in [
                    *self.node_attachments,
                    *self.rigid_attachments,
                    *self.embedded_attachments,
                    *self.lift_attachments,
                    *self.frame_attachments,
                    *self.paths,
                    *self.loads,
                    *self.constraints,
                ]
                for b in item.bodies
            }
            known = {id(b) for b in self.bodies}
            for item in [*self.paths, *self.loads]:
                for body in item.bodies:
                    if id(body) not in known:
                        raise InputError(
                            f"{item!r} acts on {getattr(body, 'name', body)!r}, "
                            "which is not a body of this scene"
                        )
            self._islands = (
                [b for b in self.fem_bodies if id(b) not in coupled],
                [b for b in self.reduced_bodies if id(b) not in coupled],
                [b for b in self.fem_bodies if id(b) in coupled],
                [b for b in self.reduced_bodies if id(b) in coupled],
            )
            schur = self.island_solver == "schur" or (
                self.island_solver is None and self._comm.size > 1
            )
            if schur and self._islands[2]:
                self._schur = SchurIsland(self, self._islands[2])
                self._layout = self._schur.rigid
                if self.integrator.name != "semi-implicit":
                    raise InputError(
                        "the distributed (Schur) island steps semi-implicitly "
                        "only for now: Scene(integrator='semi-implicit'), or the "
                        "implicit integrator in serial with island_solver='direct'"
                    )
            else:
                self._schur = None
                self._layout = Layout(self, self._islands[2], self._islands[3])
            for constraint in self.constraints:  # the joints' bodies: checked by Layout
                for body in constraint.bodies:
                    if body is not None and id(body) not in known:
                        raise InputError(
                            f"constraint {constraint.name!r} acts on "
                            f"{getattr(body, 'name', body)!r}, which is not a "
                            "body of this scene"
                        )
                failure = constraint.constraint_failure()
                if failure is not None:
                    raise InputError(f"at the start (t = {self.t:g}): {failure}")
            if self._layout.n_all and getattr(self.integrator, "name", None) not in INTEGRATORS:
                raise InputError(
                    f"integrator {type(self.integrator).__name__}: the coupled island "
                    f"(attachments, paths, loads, joints, rigid bodies) is stepped by one of "
                    f"{sorted(INTEGRATORS)}; a custom integrator steps bodies on their own only"
                )
        # Fixing nodes after adding is allowed: re-check when a body's fixed set changed.
        elif any(
            not np.array_equal(b.fixed_components, f)
            for b, f in zip(self._layout.fem_bodies, self._layout.fixed)
        ):
            self._layout = None
            return self._ready()
        return self._layout

    def _direct_layout(self, what: str) -> "Layout":
        """The coupled island's layout for an operation of the direct island solver."""
        L = self._ready()
        if self._schur is not None:
            raise InputError(
                f"{what}: not available with the distributed (Schur) island yet "
                "(island_solver='direct', serial)"
            )
        return L

    def linear_solver_for(self, body: FemBody) -> LinearSolver:
        """The PETSc solver of an FEM body stepped on its own (one per body, reused)."""
        # A follower pressure on faces with a free border makes the tangent unsymmetric.
        key = (id(body), body.conservative)
        if key not in self._linear_solvers:
            self._linear_solvers[key] = LinearSolver(
                body.mesh.comm, self.linear_solver, V=body.V, symmetric=body.conservative
            )
        return self._linear_solvers[key]

    # ---- observation ---------------------------------------------------------------------

    def _moving_bodies(self) -> list[RigidBody]:
        return [b for b in self.rigid_bodies if b.dynamic]

    def kinetic_energy(self) -> float:
        """1/2 v^T M v of the FEM bodies plus the rigid kinetic energy of the moving bodies."""
        return sum(b.kinetic_energy() for b in self.fem_bodies + self.reduced_bodies) + sum(
            b.kinetic_energy() for b in self._moving_bodies()
        )

    def potential_energy(self) -> float:
        """FEM Pi(u) (strain minus the work of gravity and loads), -m g . p of the moving
        rigid bodies, the force elements' and paths' potential_energy(), and the load
        elements' potential_energy(t) (times the load factor) where they have one."""
        return (
            sum(b.potential_energy() for b in self.fem_bodies + self.reduced_bodies)
            + sum(b.potential_energy(self.gravity) for b in self._moving_bodies())
            + sum(e.potential_energy() for e in self.forces if hasattr(e, "potential_energy"))
            + sum(p.potential_energy() for p in self.paths)
            + self.load_factor
            * sum(e.potential_energy(self.t) for e in self.loads if hasattr(e, "potential_energy"))
        )

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
        for body in self.reduced_bodies:  # 1_k^T M U q' = (U^T int rho e_k . phi dX) . q'
            total += body.G.T @ body.qdot
        return total + sum((b.mass * b.velocity for b in self._moving_bodies()), np.zeros(3))

    def angular_momentum(self, about=(0.0, 0.0, 0.0)) -> np.ndarray:
        """Angular momentum about ``about``: sum (x_i - about) x (M v)_i over the FEM nodes
        (a reduced body's through its full body's nodes, O(n r)) plus (p - about) x m v
        + I_w w of the moving rigid bodies."""
        about = np.asarray(about, dtype=float)
        total = sum((b.angular_momentum(about) for b in self._moving_bodies()), np.zeros(3))
        for full, u, v in [(b, b.u.x.array, b.v.x.array) for b in self.fem_bodies] + [
            (b.full, b.nodal_displacement(), b.nodal_velocity()) for b in self.reduced_bodies
        ]:
            full.compile()
            x = full.V.tabulate_dof_coordinates() + u.reshape(-1, 3)
            V, Mv = full.v.x.petsc_vec.duplicate(), full.v.x.petsc_vec.duplicate()
            V.array[:] = v[: V.array.size]
            full.mass_mult(V, Mv)
            n = Mv.array.size // 3
            total += np.cross(x[:n] - about, Mv.array.reshape(-1, 3)).sum(axis=0)
            V.destroy()
            Mv.destroy()
        return total

    def attachment_errors(self) -> dict[str, float]:
        """max |x_i - (p + R r_i)| of each node and lift attachment, max |x_s - (W x_m + c)|
        of each embedded attachment, and the pose error (m and rad) of each frame
        attachment (round-off after a step)."""
        out = {
            a.name: float(np.abs(dof_positions(a.fem)[a.dofs] - a.positions()).max())
            for a in self.node_attachments
        }
        out.update(
            {
                a.name: float(np.abs(dof_positions(a.slave) - a.positions()).max())
                for a in self.embedded_attachments
            }
        )
        out.update(
            {
                a.name: float(np.abs(a.node_positions() - a.positions()).max())
                for a in self.lift_attachments
            }
        )
        for a in self.frame_attachments:
            out[a.name] = pose_gap(a)
        return out

    def constraint_errors(self) -> dict[str, float]:
        """max |phi| of each joint's bilateral rows (m and rad)."""
        return {j.name: float(np.abs(j.constraint().phi).max()) for j in self.joints}

    @property
    def constraints(self) -> list:
        """The components that give constraint rows (:mod:`~artifem.multibody.
        constraint_rows`): the joints, their limits included, and the contacts."""
        return [*self.joints, *self.contacts]

    def contact_forces(self, contact: PlaneContact) -> ContactForces:
        """The forces the contact applied at its points over the last step (impulses / h,
        rows at the start of the step), or in the last static solve's last Newton
        iteration (:meth:`PlaneContact.forces`)."""
        if not any(contact is c for c in self.contacts):
            raise UnknownNameError(f"contact {contact.name!r} is not in the scene")
        return contact.forces(self._impulses.get(contact, []), self._last_h)

    def contact_pressure(self, contact, **options) -> dict:
        """{FEM body name: :class:`~artifem.multibody.contact_pressure.ContactPressure`}:
        the pressure p_j = f_n,j / A_j of the contact's nodes on each FEM body it touches
        (a reduced body's on its full body's mesh; rigid bodies have none), from the forces
        of :meth:`contact_forces` (``options``: ``quadrature_degree``, ``configuration`` of
        :func:`~artifem.multibody.contact_pressure.contact_pressure`)."""
        if not any(contact is c for c in self.contacts):
            raise UnknownNameError(f"contact {contact.name!r} is not in the scene")
        out = {}
        for points, f in contact.normal_forces(self._impulses.get(contact, []), self._last_h):
            body = points.mesh_body
            if body is None:
                continue
            areas = None
            if options.get("configuration", "reference") == "reference":
                # the reference areas do not change: assembled once per body and degree
                key = (body, options.get("quadrature_degree", 2))
                if key not in self._reference_areas:
                    self._reference_areas[key] = boundary_areas(body, quadrature_degree=key[1])
                areas = self._reference_areas[key]
            out[body.name] = contact_pressure(points, f, areas=areas, **options)
        return out

    def reaction(self, joint: Joint) -> tuple[np.ndarray, ...]:
        """The wrenches the joint applied to each of its ``bodies`` over the last step
        (G_k^T lambda / h, rows at the start of the step; a joint's frame on the world gets
        the world's share), or in the last static solve. A contact's forces:
        :meth:`contact_forces`."""
        if not any(joint is c for c in self.joints):
            raise UnknownNameError(f"joint {joint.name!r} is not in the scene")
        parts = self._impulses.get(joint, [])
        return tuple(
            sum((block.jacobians[k][1].T @ lam for block, lam in parts), np.zeros(6)) / self._last_h
            for k in range(len(joint.bodies))
        )

    # ---- the step ------------------------------------------------------------------------

    def add_controller(self, controller: Controller) -> None:
        """``controller(scene, t0, t1)`` sets inputs (excitations, loads) before every step
        from t0 to t1, halved steps included (ArtiSynth's Controller.apply)."""
        if not callable(controller):
            raise InputError(f"a controller is a callable (scene, t0, t1), got {controller!r}")
        self.controllers.append(controller)

    @property
    def bodies(self) -> list:
        """Every body of the scene: FEM, reduced and rigid (the body interface: state(),
        set_state(), inverted_elements(), kinetic_energy())."""
        return [*self.fem_bodies, *self.reduced_bodies, *self.rigid_bodies]

    def _stateful(self) -> list:
        """Force and path elements with a time-dependent state (muscle activation, tendon)."""
        return [e for e in [*self.forces, *self.paths] if hasattr(e, "save_state")]

    def save_state(self) -> SceneState:
        """The complete state: time, every body's coordinates and velocities, the muscles'
        activation and tendon state, and the joints' last impulses."""
        return SceneState(
            self.t,
            [b.state() for b in self.bodies],
            [e.save_state() for e in self._stateful()],
            (self._impulses, self._last_h, self._reactions),
        )

    def restore_state(self, state: SceneState) -> None:
        """Back to a state saved from this scene (the same components)."""
        bodies, stateful = self.bodies, self._stateful()
        if len(state.bodies) != len(bodies) or len(state.elements) != len(stateful):
            raise InputError(
                "restore_state: the state was saved from a scene with other "
                f"components ({len(state.bodies)} bodies, {len(state.elements)} "
                f"stateful elements; this scene has {len(bodies)} and "
                f"{len(stateful)})"
            )
        self.t = state.t
        for body, saved in zip(bodies, state.bodies):
            body.set_state(saved)
        for element, saved in zip(stateful, state.elements):
            element.restore_state(saved)
        self._impulses, self._last_h, self._reactions = state.joints

    def step(self, h: float) -> None:
        """Advance from t to t + h: the controllers, one linearized step (module docstring),
        then the health of every body (finite coordinates, det F > 0 at every quadrature
        point, a reduced body's at its integration points; hard-incompressible volumes
        within ``step_tol``, projected back by the step where they are not). A failed step
        (unhealthy, or a singular or failed solve) is undone (:meth:`restore_state`) and
        retried by the ``fallback`` integrator (Newton on the same backward Euler
        equations: it holds where the linearization at the start of the step does not,
        e.g. a full excitation switched on at once; ``fallbacks`` counts the steps it
        completed), so the cost is the semi-implicit step's wherever that succeeds. A step that
        fails both ways is retried as two steps of half the size, recursively up to
        ``max_halvings`` times; beyond that it raises
        :class:`~artifem.errors.ElementInversionError` (body, time, elements, smallest det F)
        or :class:`~artifem.errors.StepFailed`, the scene left at the start of the failed
        step."""
        if not (np.isfinite(h) and h > 0):
            raise InputError(f"time step must be positive and finite, got {h!r}")
        self._advance(h, depth=0)

    def _advance(self, h: float, depth: int) -> None:
        for controller in self.controllers:
            controller(self, self.t, self.t + h)
        saved = self.save_state()
        failure = self._attempt(h, self.integrator)
        if failure is not None and self._retries_with_fallback():
            self.restore_state(saved)
            retried = self._attempt(h, self.fallback)
            if retried is None:
                self.fallbacks += 1
                return
            failure = _Failure(
                f"{failure.message}; the {self.fallback.name} retry: {retried.message}",
                retried.inverted or failure.inverted,
            )
        if failure is None:
            return
        self.restore_state(saved)
        if depth >= self.max_halvings:
            self._raise(failure, h)
        self.halvings += 1
        self._advance(h / 2, depth + 1)
        self._advance(h / 2, depth + 1)

    def _retries_with_fallback(self) -> bool:
        """A failed step is retried by the fallback: the scene has one, steps semi-
        implicitly, and its coupled island is not the distributed Schur island."""
        return (
            self.fallback is not None
            and self._schur is None
            and getattr(self.integrator, "name", None) == "semi-implicit"
        )

    def _attempt(self, h: float, integrator) -> _Failure | None:
        """One step by ``integrator`` and the health check: None, or what went wrong."""
        try:
            self._step_once(h, integrator)
            return self._health()
        except (StepFailed, LinearSolveError) as exc:
            return _Failure(str(exc), self._inverted())

    def _inverted(self) -> list:
        """(body name, inverted elements, min det F) of every body with det F <= 0 now."""
        out = []
        for body in self.bodies:
            bad, min_det = body.inverted_elements()
            if bad.size or not min_det > 0:
                out.append((body.name, bad, min_det))
        return out

    def _health(self) -> _Failure | None:
        """None after a sound step; otherwise what went wrong, body by body."""
        inverted, step_min = [], np.inf
        for body in self.bodies:  # the same order on every rank (collective)
            finite = all(bool(np.all(np.isfinite(a))) for a in body.state())
            if not self._comm.allreduce(finite, op=MPI.LAND):
                return _Failure(f"non-finite coordinates or velocities in {body.name!r}", [])
            bad, min_det = body.inverted_elements()
            if bad.size or not min_det > 0:
                inverted.append((body.name, bad, min_det))
            step_min = min(step_min, min_det)
        if inverted:
            return _Failure(
                "inverted elements in " + ", ".join(repr(n) for n, *_ in inverted), inverted
            )
        collapsed = [att.name for att in self.frame_attachments if att.frame.collapsed()]
        if collapsed:
            return _Failure(
                "the support of frame attachment(s) "
                + ", ".join(map(repr, collapsed))
                + " collapsed or inverted (no rotation)",
                [],
            )
        for item in [*self.bodies, *self.constraints]:
            off = item.constraint_failure()
            if off is not None:
                return _Failure(off, [])
        self.min_det_F = min(self.min_det_F, step_min)
        return None

    def _raise(self, failure: _Failure, h: float) -> None:
        retried = (
            "semi-implicit, then implicit"
            if self._retries_with_fallback()
            else getattr(self.integrator, "name", "the integrator")
        )
        detail = (
            f"{failure.message}; step {h:.3g} s after {self.max_halvings} halvings "
            f"({retried} at each size); what to try: a smaller dt, more max_halvings, "
            "or the excitation or load ramped over a few steps"
        )
        if failure.inverted:
            name, bad, min_det = min(failure.inverted, key=lambda x: x[2])
            raise ElementInversionError(self.t + h, bad, min_det, detail, body=name)
        raise StepFailed(f"step failed at t = {self.t:.6g} s: {detail}")

    def _step_once(self, h: float, integrator) -> None:
        """One step from t to t + h (module docstring), no checks: the bodies on their own
        by ``integrator``, the coupled island by one linearized solve or, with the
        implicit integrator, by Newton (:func:`~artifem.scene.implicit_step.implicit_step`)."""
        L = self._ready()
        free_fem, free_reduced = self._islands[:2]
        for body in free_fem:
            integrator.advance(body, h, self.linear_solver_for(body))
        for body in free_reduced:
            integrator.advance_reduced(body, h)
        if self._schur is not None:
            self._record_impulses(L, self._schur.step(h), h)
        elif L.n_all and integrator.name == "implicit":
            impulses, merits = implicit_step(
                self, L, h, integrator.rtol, integrator.atol, integrator.max_iterations
            )
            self._record_impulses(L, impulses, h)
            self.last_solve = {
                "masters": L.n_masters,
                "newton_iterations": len(merits) - 1,
                "merits": merits,
            }
        elif L.n_all:
            self._step_island(h)
        self.t += h

    def _step_island(self, h: float) -> None:
        """The coupled island's linearized step (module docstring)."""
        L, P, z_k, targets, A_m, b_m = self._step_system(h)
        rows = L.constraint_map.rows(P, z_k, h, self.stabilization)
        z_m, lam, resolve = self._solve(A_m, b_m, rows)
        z = P @ z_m + z_k
        if not L.volume_constraints:
            L.advance(z, h, targets)
        else:
            L.hold_volumes(z, lam, P, resolve, h)
            start = L.save()  # the projection redoes the step from here
            L.advance(z, h, targets)
            L.project_volumes(z, lam, P, resolve, h, targets, start)
        self._record_impulses(L, impulses_by_constraint(rows, lam), h)

    def _record_impulses(self, L, impulses: dict, h: float) -> None:
        """Keep the constraints' impulses of the step (reactions, and K_geo's lagged
        loads); statics keeps its forces as the impulses of a step h = 1."""
        self._impulses, self._last_h = impulses, h
        self._reactions = L.constraint_map.forces(
            (block, lam / h) for parts in impulses.values() for block, lam in parts
        )

    def step_matrix(self, h: float) -> sparse.csr_matrix:
        """The masters' block P^T A_all P - h^2 K_geo of the coupled island's next KKT
        matrix (for inspection; prescribed bodies take their twist at t + h, nothing else
        changes)."""
        return sparse.csr_matrix(self._step_system(h)[4])

    def _step_system(self, h: float):
        """(layout, P, z_k, prescribed targets, A_m, b_m) of the step from t to t + h."""
        if not (np.isfinite(h) and h > 0):
            raise InputError(f"time step must be positive and finite, got {h!r}")
        L = self._direct_layout("step_matrix")
        t1 = self.t + h
        targets = L.kinematic_targets(t1)  # prescribed poses and twists at t1
        for body, (_, _, twist) in targets.items():
            body.set_twist(twist)
        P = L.prolongation()
        z_k = L.known_velocities(h, targets)
        A, b, f_all = L.dynamics(h, t1)
        A_m = L.fmt(P.T @ A @ P)
        if self.geometric_stiffness:
            A_m = A_m - h * h * L.geometric_stiffness(self._with_reactions(f_all), P)
        b_m = P.T @ (b - A @ z_k)
        return L, P, z_k, targets, A_m, b_m

    def _solve(self, A_m, b_m, rows):
        """z_m+, the constraint impulses lambda and the solve for another right-hand side
        (:func:`~artifem.scene.constraints.solve_constrained`: the Schur complement of the
        constraint rows, minimum-norm for redundant rows, or the sparse KKT for many rows
        on a large FEM island; an active set for the bounded ones, warm-started from the
        last solve's). ``last_solve`` gives the path, the trials of the active set, the
        factorizations and the seconds of detection, mapping and solve."""
        n = A_m.shape[0]
        if n == 0:  # everything fixed, prescribed or attached
            self.last_solve = {"masters": 0, "constraint_rows": 0, "factorizations": 0}
            return np.zeros(0), np.zeros(0), lambda rhs: (np.zeros(0), np.zeros(0))
        info: dict = {}
        tic = time.perf_counter()
        try:
            z_m, lam, active, resolve = solve_constrained(
                self._solver,
                A_m,
                b_m,
                rows,
                f"t = {self.t:g}",
                resolver=True,
                memory=self._active_sets,
                info=info,
            )
        except SingularSystem as error:
            if self._layout is None:
                raise
            raise self._layout.unresisted(error, A_m, STEP_ADVICE) from error
        seconds = dict(self._layout.constraint_map.seconds) if self._layout is not None else {}
        seconds["solve"] = time.perf_counter() - tic
        self.last_solve = {
            "masters": n,
            "constraint_rows": active,
            "factorizations": info["factorizations"],
            "path": info["path"],
            "updates": info.get("updates", 0),
            "trials": info["trials"],
            "seconds": seconds,
        }
        return z_m, lam, resolve

    # ---- statics -------------------------------------------------------------------------

    def master_forces(self) -> np.ndarray:
        """F_m = P^T f_all: the static generalized forces on the coupled island's masters
        (no inertia)."""
        L = self._direct_layout("master_forces")
        return L.prolongation().T @ L.static_forces(self.t, tangent=False)[0]

    def static_tangent(self) -> sparse.csr_matrix:
        """-dF_m/dq_m = P^T K_all P - K_geo at the current configuration (module docstring)."""
        L = self._direct_layout("static_tangent")
        f_all, K_all = L.static_forces(self.t, tangent=True)
        P = L.prolongation()
        K = L.fmt(P.T @ K_all @ P)
        if self.geometric_stiffness:
            K = K - L.geometric_stiffness(self._with_reactions(f_all), P)
        return sparse.csr_matrix(K)

    def _with_reactions(self, f_all: np.ndarray) -> np.ndarray:
        """f_all plus the joints' last reaction forces: on a body that follows a frame or
        another body they load the attachment like any force (lagged by one step or one
        Newton iteration)."""
        r = self._reactions
        return f_all if r is None or r.shape != f_all.shape else f_all + r

    def displace_masters(self, dq) -> None:
        """Apply a master displacement: free FEM u += dq, dynamic roots p += dp and
        R = exp([dtheta]x) R; slaves follow their roots' poses exactly."""
        self._direct_layout("displace_masters").displace(np.asarray(dq, dtype=float))

    def master_count(self) -> int:
        return self._direct_layout("master_count").n_masters

    def solve_static(
        self,
        *,
        load_steps: int | str = 1,
        rtol: float = 1e-10,
        atol: float = 1e-12,
        max_iterations: int = 30,
        progress=None,
    ) -> list[int]:
        """Static equilibrium by Newton, the gravity and the loads ramped over ``load_steps``
        increments: each body on its own (``integrators.solve_static``, its PETSc solver;
        ``solve_static_reduced``), then the coupled island, F_m + G^T lambda = 0 with
        phi = 0 on the joints and phi >= 0, lambda >= 0 on their limits (module
        docstring). Velocities are set to zero. Returns the largest Newton iteration count
        of each increment over the islands (a :class:`~artifem.integrators.StaticCounts`,
        whose ``failed`` adds the iterations of the increments that failed and were cut).
        ``load_steps="auto"`` (or a count whose increments are cut when they fail):
        :func:`~artifem.integrators.ramp_load`.
        ``progress`` (e.g. tqdm) is updated once per increment of each island."""
        L = self._ready()
        free_fem, free_reduced = self._islands[:2]
        counts = []
        options = dict(
            load_steps=load_steps,
            rtol=rtol,
            atol=atol,
            max_iterations=max_iterations,
            progress=progress,
        )
        for body in free_fem:
            body.v.x.array[:] = 0.0
            counts = _merge_counts(
                counts, solve_static(body, self.linear_solver_for(body), **options)
            )
        for body in free_reduced:
            body.qdot[:] = 0.0
            counts = _merge_counts(counts, solve_static_reduced(body, **options))
        if L.n_all:
            L = self._direct_layout("solve_static")
            counts = _merge_counts(
                counts,
                self._solve_island_static(L, load_steps, rtol, atol, max_iterations, progress),
            )
        if not counts and not isinstance(load_steps, str):
            counts = StaticCounts([0] * int(load_steps))
        return counts

    def _solve_island_static(self, L, load_steps, rtol, atol, max_iterations, progress):
        """The coupled island's static Newton (module docstring: statics)."""
        for body in L.fem_bodies:
            body.v.x.array[:] = 0.0
        for body in L.reduced_bodies:
            body.qdot[:] = 0.0
        for body in self.rigid_bodies:
            if body.dynamic:
                body.set_twist(np.zeros(6))
        g = self.gravity.copy()
        self._reactions = None
        memory = ActiveSetMemory()  # the statics' own: forces, not impulses
        residuals = []  # the merit at each iterate of each increment
        # prescribed displacements written since the bodies last moved: ramped with the load
        ramps = [r for r in (body.take_prescribed_ramp() for body in L.fem_bodies) if r is not None]
        for ramp in ramps:
            ramp.apply(0.0)

        def solve_increment(factor: float, limit: int) -> int:
            self._set_load_factor(factor, g)
            for ramp in ramps:
                ramp.apply(factor)
            residuals.append([])
            kept = memory.save()
            contacts = (memory, IncrementSlip())  # friction sticks to the increment's start
            try:
                return self._newton(
                    L, rtol, atol, limit, factor, contacts, residuals[-1]
                ) + self._hold_volumes_static(L, rtol, atol, limit, factor, contacts, residuals[-1])
            except StepFailed:
                residuals.pop()
                memory.restore(kept)  # the next try starts from the last solution
                raise

        try:
            counts = ramp_load(
                solve_increment,
                self.save_state,
                self.restore_state,
                load_steps,
                max_iterations,
                "static solve (coupled island)",
                progress,
            )
        except StepFailed:
            for ramp in ramps:
                ramp.give_back()
            raise
        finally:
            self._set_load_factor(1.0, g)
        counts.residuals = residuals
        return counts

    def _hold_volumes_static(
        self, L, rtol, atol, max_iterations, factor, contacts, residuals
    ) -> int:
        """Uzawa around the island's static Newton for hard-incompressible bodies: while
        some element volume is off by more than its tolerance, p <- pi and Newton again
        (the last residual assembled g at the solution). The Newton iterations it took."""
        constrained = [vc for _, vc in L.volume_constraints]
        iterations = 0
        limit = min((vc.spec.max_updates for vc in constrained), default=0) + 1
        for updates in range(1, limit + 1):  # noqa: B007 (the count is read after the loop)
            violations = [vc.update() for vc in constrained]
            if all(v <= vc.spec.tol for v, vc in zip(violations, constrained)):
                return iterations
            iterations += self._newton(L, rtol, atol, max_iterations, factor, contacts, residuals)
        off = "; ".join(vc.describe() for v, vc in zip(violations, constrained) if v > vc.spec.tol)
        raise StepFailed(
            f"static solve: {off} after {updates - 1} pressure updates at load factor {factor:g}"
        )

    def _set_load_factor(self, factor: float, g: np.ndarray) -> None:
        """Ramp the loads: the rigid bodies' gravity, the load elements, and the FEM load
        factor (which scales the FEM bodies' gravity, body forces and nodal loads)."""
        self._gravity = factor * g
        self.load_factor = factor
        for body in self._full_bodies():
            body.set_load_factor(factor)

    def _residual(self, L) -> tuple[np.ndarray, list]:
        """(F_m, the constraints' rows on the masters): statics asks phi + G dq = 0 on the
        free rows and >= 0 on the bounded ones, c = -phi (their right-hand side at
        h = beta = 1)."""
        P = L.prolongation()
        F = P.T @ L.static_forces(self.t, tangent=False)[0]
        return F, L.constraint_map.rows(P, np.zeros(L.n_all), 1.0, 1.0)

    @staticmethod
    def _merit(F: np.ndarray, rows: list, active: np.ndarray, held=None) -> float:
        """|[F_m + G_c^T f_c + G_h^T lambda_h - G_a^T mu; gap]| at the current
        configuration: the forces the constraints cannot balance, and their error (phi on
        free rows, the crossed part min(phi, 0) of bounded ones). Compliant rows push by
        their law, f_c = max(-phi, 0) / C (statics: h = 1); ``held`` (the last solve's
        forces on the rows it held at a bound: sliding friction) acts as it was; mu are
        the least-squares reactions of the other ``active`` rows (every free row and the
        limits the last solve pressed on); the sticking friction rows' slip counts in the
        gap."""
        gap = _gap(rows, active)
        hard = active.copy()
        offset = 0
        for g in rows:
            m = len(g.c)
            part = None if held is None else held[offset : offset + m]
            if g.compliance is not None:
                on = g.block.compliant
                law = np.where(on, np.maximum(-g.block.phi, 0.0), 0.0) / np.where(
                    on, g.compliance, 1.0
                )
                part = law if part is None else part + law
                hard[offset : offset + m] &= ~on
            if part is not None and np.any(part):
                F = F + np.asarray(g.G.T @ part).ravel()
            offset += m
        if hard.any():
            G = np.vstack([g.G.toarray() if sparse.issparse(g.G) else g.G for g in rows])
            G = G[hard]
            F = F - G.T @ np.linalg.lstsq(G.T, F, rcond=None)[0]
        return float(np.linalg.norm(np.concatenate([F, gap])))

    def _newton(self, L, rtol, atol, max_iterations, factor, contacts, residuals) -> int:
        """Newton on the island's statics at load factor ``factor`` (module docstring:
        statics); ``contacts`` = (memory, slip): each active set started from the last
        one's (:class:`ActiveSetMemory`), the friction rows anchored where the increment
        began (:class:`IncrementSlip`). The merit of each iterate is appended to
        ``residuals``. The contacts' pairs, held once :data:`HOLD_AFTER_RISES` steps
        raised the merit, are released at the end."""
        try:
            return self._newton_iterations(
                L, rtol, atol, max_iterations, factor, contacts, residuals
            )
        finally:
            for constraint in self.constraints:
                constraint.hold_pairs(False)

    @staticmethod
    def _balanced_tangent(L, K, F, rows, memory):
        """K - P^T d(G^T lambda)/dq P with the reactions that balance F best
        (:func:`_balancing_reactions` over the rows active now); None when they vanish."""
        balancing = _balancing_reactions(F, rows, _carried(rows, memory)[0])
        if not np.any(balancing):
            return None
        P = L.prolongation()
        return L.fmt(K - P.T @ L.constraint_map.stiffness(rows, balancing) @ P)

    def _newton_iterations(self, L, rtol, atol, max_iterations, factor, contacts, residuals) -> int:
        """:meth:`_newton`'s iterations."""
        memory, slip = contacts
        F, rows = self._residual(L)
        rows = slip.anchored(rows)
        # the last solve's active set and sliding forces (by row keys), and the free rows
        # and the crossed bounded ones
        active, held = _carried(rows, memory)
        norm = self._merit(F, rows, active, held)
        # the size of the loads: the forces the constraints carry at the start (the merit
        # of a converged state under a small increment is no measure of them)
        scale = max(norm, float(np.linalg.norm(F)), atol)
        near = False  # Newton's region: the last step was full and lowered the merit
        rises = 0  # steps that raised the merit or hardly lowered it
        for it in range(1, max_iterations + 1):
            residuals.append(norm)
            if norm <= max(rtol * scale, atol):
                return it - 1
            K = self.static_tangent()
            tangents = [L.fmt(K)]
            last = memory.start(rows) if rows else None
            turning = near and last is not None and np.any(last[3])
            if turning:  # rows turn under their forces
                P = L.prolongation()
                tangents.insert(0, L.fmt(K - P.T @ L.constraint_map.stiffness(rows, last[3]) @ P))
            elif rows and L.dense:
                # A small island's rows turn under the reactions that balance F best,
                # -G_a^T lambda = F in least squares, where no solve has given their
                # forces yet (joints: their reactions carry a loaded pendulum's stiffness,
                # and Newton converged linearly without it, at 0.4 per iteration).
                turned = self._balanced_tangent(L, K, F, rows, memory)
                if turned is not None:
                    tangents.insert(0, turned)
                turning = True
            # K dq - G^T lambda = F, free rows G dq = -phi, bounded ones by an active set.
            # Where each tangent is singular (a small, dense system): the rows' turning
            # with the balancing reactions, if not taken yet; then, along the motions the
            # first (most complete) tangent leaves free, if no force works on them, a small
            # stiffness (neutral: every position along them is an equilibrium, and the
            # step keeps the one it has: a ball-jointed rod's spin about its own axis).
            first, neutral = None, False  # first: (the first singular tangent, its error)
            for K in tangents:
                try:
                    dq, lam, active = solve_saddle(
                        self._solver, L.kkt, K, F, rows, "static solve", memory
                    )
                    break
                except StepFailed as error:
                    singular = isinstance(error, SingularSystem) and error.matrix is not None
                    if singular and first is None:
                        first = (K, error)
                    if K is not tangents[-1]:
                        continue
                    error.iterations = it
                    if first is None:
                        raise
                    if rows and not turning:
                        turning = True
                        turned = self._balanced_tangent(L, K, F, rows, memory)
                        if turned is not None:
                            tangents.append(turned)
                            first = None  # the turned tangent is the most complete
                            continue
                    best, failure = first
                    held = None if neutral else L.neutral_stiffness(failure, best, F)
                    if held is None:
                        raise L.unresisted(failure, best, STATICS_ADVICE) from error
                    neutral = True
                    tangents.append(best + held)
            # the rows held at a bound (sliding friction) push with their last forces
            held = np.where(active, 0.0, lam) if rows else None
            if rows:  # the constraints apply G^T lambda (forces: h = 1)
                self._record_impulses(L, impulses_by_constraint(rows, lam), 1.0)
            gap = _gap(rows, active)
            # the rows' motion along the step, G dq, and the held forces' work along it
            # (they are constant within it)
            motion = (
                np.concatenate([np.asarray(g.G @ dq).ravel() for g in rows])
                if rows
                else np.zeros(0)
            )
            pushed = float(held @ motion) if rows else 0.0
            saved = L.save()
            # The energy is a merit when it is the whole potential; with constraints, the
            # exact penalty E - lambda_h s_h + rho |gap|_1, rho > max |lambda| (the held
            # rows' forces constant), whose slope along the step is
            # -(F + G_h^T lambda_h) . dq - rho |gap|_1 = -dq^T K dq - lambda . phi - ... < 0.
            use_energy = (
                all(hasattr(e, "potential_energy") for e in self.forces)
                and all(hasattr(e, "potential_energy") for e in self.loads)
                and all(p.conservative for p in self.paths)
                and all(b.conservative for b in L.fem_bodies)
            )
            rho = 2.0 * float(np.abs(lam).max()) if lam.size else 0.0
            energy0 = (
                self.potential_energy() + _compliant_energy(rows) + rho * float(np.abs(gap).sum())
                if use_energy
                else 0.0
            )
            slope = -float(F @ dq) - pushed - rho * float(np.abs(gap).sum())
            step = 1.0
            while step >= 1e-4:
                L.displace(step * dq)
                if not L.inverted():
                    # Energy (Armijo) first: a rotation of a root moves its slaves on arcs
                    # while the free nodes beside them move on straight lines, so a large
                    # rotation raises the force residual sharply (stiff elements by the
                    # attachment), not the energy (integrators._backtrack, same rule).
                    moved = slip.advanced(rows, step * motion)
                    F_new, rows_new = self._residual(L)
                    rows_new = moved.anchored(rows_new)
                    # a contact point that entered or left its margin changes the rows:
                    # the solve's set carried over by row keys
                    same = [len(g.c) for g in rows_new] == [len(g.c) for g in rows]
                    on, pushing = (active, held) if same else _carried(rows_new, memory)
                    gap_new = _gap(rows_new, on)
                    energy = (
                        self.potential_energy()
                        + _compliant_energy(rows_new)
                        - step * pushed
                        + rho * float(np.abs(gap_new).sum())
                        if use_energy
                        else np.inf
                    )
                    trial = self._merit(F_new, rows_new, on, pushing)
                    if np.isfinite(trial) and (
                        energy <= energy0 + 1e-4 * step * slope
                        or trial <= (1.0 - 1e-4 * step) * norm
                    ):
                        break
                L.restore(saved)
                step *= 0.5
            else:
                raise StepFailed(
                    f"static solve: line search failed at load factor "
                    f"{factor:g}, Newton iteration {it}",
                    iterations=it,
                )
            near = step == 1.0 and trial < norm
            rises += trial > 0.9 * norm  # raised, or hardly lowered
            slip.take(moved)
            F, rows, norm = F_new, rows_new, trial
            if rises == HOLD_AFTER_RISES:  # Newton circles between contact features
                for constraint in self.constraints:
                    constraint.hold_pairs(True)
            if step == 1.0 and np.abs(dq).max() <= 1e-14 * max(L.master_scale(), 1e-300):
                residuals.append(norm)
                return it
        residuals.append(norm)
        if norm <= max(rtol * scale, atol):
            return max_iterations
        raise StepFailed(
            f"static solve: Newton did not converge in {max_iterations} "
            f"iterations at load factor {factor:g} (|r| = {norm:.3e})",
            iterations=max_iterations,
        )


def _balancing_reactions(F: np.ndarray, rows: list, active: np.ndarray) -> np.ndarray:
    """The row forces lambda (all rows; 0 off ``active``) that balance the master forces
    best: -G_a^T lambda_a = F in least squares (statics' sign: F + G^T lambda = 0)."""
    lam = np.zeros(active.size)
    if active.any():
        G = np.vstack([g.G.toarray() if sparse.issparse(g.G) else g.G for g in rows])[active]
        lam[active] = -np.linalg.lstsq(G.T, F, rcond=None)[0]
    return lam


def _carried(rows: list, memory: ActiveSetMemory) -> tuple:
    """(active, held) for the merit at a configuration the last solve did not see: the
    free rows, the crossed bounded ones and the rows that solve held active, by row keys;
    held, the forces it left on the others (sliding friction; 0 where it let go)."""
    active = _crossed(rows)
    last = memory.start(rows) if rows else None
    if last is None:
        return active, None
    active = active | last[0]
    return active, np.where(active, 0.0, last[3])


def _crossed(rows: list) -> np.ndarray:
    """The rows a merit holds before a solve: the free rows and the crossed bounded ones
    (not compliant ones: their crossing is the law's)."""
    return (
        np.concatenate([~g.block.bounded | ((g.block.phi < 0) & ~g.block.compliant) for g in rows])
        if rows
        else np.zeros(0, dtype=bool)
    )


def _compliant_energy(rows: list) -> float:
    """The compliant rows' springs, sum max(-phi, 0)^2 / (2 C) (statics: h = 1)."""
    return sum(
        float(
            np.sum(
                np.where(g.block.compliant, np.minimum(g.block.phi, 0.0) ** 2, 0.0)
                / (2.0 * np.where(g.block.compliant, g.compliance, 1.0))
            )
        )
        for g in rows
        if g.compliance is not None
    )


def _gap(rows: list, active: np.ndarray) -> np.ndarray:
    """The constraint error of statics: phi on free rows, min(phi, 0) on bounded ones,
    and on the sticking (``active``) friction rows their slip since the increment began,
    -c (:class:`IncrementSlip`)."""
    if not rows:
        return np.zeros(0)
    gap = np.concatenate([g.block.gap() for g in rows])
    sticking = active & np.concatenate(
        [
            g.block.friction.rows if g.block.friction is not None else np.zeros(len(g.c), bool)
            for g in rows
        ]
    )
    return np.where(sticking, -np.concatenate([g.c for g in rows]), gap)
