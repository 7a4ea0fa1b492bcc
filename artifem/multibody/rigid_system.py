"""A rigid multibody scene and its constrained semi-implicit Euler step.

The dofs are the velocities u = [v; w] of the dynamic bodies (6 each); fixed
and prescribed bodies are not dofs (a prescribed body follows its trajectory,
its velocity enters the constraints as a known term). Forces are wrenches
f = [force; torque about the COM] in world coordinates: gravity [m g; 0], the
gyroscopic wrench of each body and those of the force elements.

The step (ArtiSynth's ConstrainedBackwardEuler): backward Euler
M (u+ - u) = h f(q+, u+) + G^T lambda with q+ - q = h u+, the force linearized
at the start of the step, f(q+, u+) ~ f + K (h u+) + D (u+ - u) with
K = df/dq and D = df/du (dq = [dp; dtheta], see rigid_body), gives one linear
KKT system per step,

    [ A   -G^T ] [ u+     ]   [ b ]      A = M - h D - h^2 K,
    [ G    0   ] [ lambda ] = [ c ],     b = M u + h (f - D u),
                                         c = -beta phi(q) / h - G_k u_k (k known),

where G stacks the joint rows (G u = phi', joints), lambda are the
constraint impulses (force times h) and the last term of c carries the
velocities of prescribed bodies at the end of the step. Poses then advance
with u+ (p+ = p + h v+, R+ = exp(h [w+]x) R). D includes the gyroscopic
Jacobian; M is taken at the start of the step.

Energy: with forces that have no Jacobians (gravity) the step is symplectic
Euler (velocities from forces at q, positions from u+), so the energy error of
an undamped system oscillates with an O(h) amplitude and does not drift
(tests: a double pendulum, 2.9e-3 m g L at h = 1 ms over 10 s). Stiffness and
damping Jacobians, and the gyroscopic one, make it (linearized) backward
Euler, which dissipates at O(h) and is stable for stiff elements.

Drift: Baumgarte-style velocity stabilization. Since phi(q+) = phi(q) + h G u+
+ O(h^2), the row G u+ = -beta phi / h leaves phi(q+) = (1 - beta) phi(q) +
O(h^2): with ``stabilization`` beta = 1 (the default) the error is removed in
one step and stays O(h^2 |u|^2 / length) instead of growing. It costs no
second solve; the price is that the joint reaction does the work
-lambda . beta phi / h, which vanishes with phi.

The KKT system is solved through its Schur complement,
S lambda = c - G A^-1 b, S = G A^-1 G^T, by least squares (SVD), so redundant
joint rows (closed loops) get the minimum-norm multipliers instead of a
singular matrix; u+ = A^-1 (b + G^T lambda).

Joint limits are unilateral rows phi_lim >= 0 (joints): the end-of-step row
G u+ >= c_lim = -phi_lim / h (reach the limit, not cross it; -beta phi_lim / h
once crossed) with lambda >= 0 and complementarity, solved by a primal-dual
active set on the same Schur complement (add the most violated row, drop the
most negative multiplier, repeat).

Force elements (springs, muscles, external loads) implement
:class:`ForceElement`.
"""

from __future__ import annotations

from typing import Iterable, Protocol, Sequence, runtime_checkable

import numpy as np

from artifem.errors import InputError, RigidStepFailed, UnknownNameError
from artifem.multibody.joints import ConstraintRows, Joint
from artifem.multibody.rigid_body import Frame, RigidBody, skew

__all__ = ["ForceElement", "JacobianBlock", "RigidStepFailed", "RigidSystem",
           "point_force_wrenches"]

#: (body_i, body_j, K_ij, D_ij): the 6 x 6 derivatives of the wrench on body i with
#: respect to body j's pose (K = df_i/dq_j) and velocity (D = df_i/du_j); either may be None.
JacobianBlock = tuple[RigidBody, RigidBody, "np.ndarray | None", "np.ndarray | None"]


@runtime_checkable
class ForceElement(Protocol):
    """What a force effector (spring, muscle, load) gives the rigid step.

    ``wrenches(t)`` returns (body, wrench) pairs: the world wrench
    [force; torque about the body's COM] on each body it acts on, at the
    current poses and velocities and at time t (the end of the step, when
    backward Euler evaluates the forces: excitations are read at t). A point
    force f at a frame's origin is ``frame.wrench(f)``.

    Optional methods, used when present:

    - ``jacobians(t) -> Iterable[JacobianBlock]``: K_ij = df_i/dq_j and
      D_ij = df_i/du_j (stiffness and damping; the step uses -h D - h^2 K).
      Without it the element is explicit in the step. For a point force f(x)
      on points carried by frames, :func:`point_force_wrenches` builds both
      the wrenches and these blocks from the point forces and their Jacobians.
    - ``potential_energy() -> float``: its stored energy, for energy checks.
    """

    def wrenches(self, t: float) -> Iterable[tuple[RigidBody, np.ndarray]]: ...


def point_force_wrenches(frames: Sequence[Frame], forces, stiffness=None, damping=None
                         ) -> tuple[list[tuple[RigidBody, np.ndarray]], list[JacobianBlock]]:
    """Map forces on points carried by frames to body wrenches and ForceElement Jacobians.

    Point i is the origin x_i of ``frames[i]`` (on body b_i; world frames carry
    nothing), with x_i' = G_i u_i, G_i = [1, -[r_i]x]. For forces f_i (n x 3) with
    K = df/dx and D = df/dv (3n x 3n, optional), virtual work gives

        wrench_b = sum_{i on b} G_i^T f_i,
        K_bc = sum_{i on b, j on c} G_i^T (K_ij G_j + D_ij [0, -[w_j]x [r_j]x])
               + delta_bc sum_{i on b} [0, 0; 0, [f_i]x [r_i]x],
        D_bc = sum_{i on b, j on c} G_i^T D_ij G_j,

    the second K term because v_j = v + w x r_j turns with the body, the third
    because the lever r_i does (``Frame.wrench_stiffness``).
    """
    n = len(frames)
    forces = np.asarray(forces, dtype=float).reshape(n, 3)
    wrenches: dict[int, list] = {}
    for frame, f in zip(frames, forces):
        if frame.body is not None:
            wrenches.setdefault(id(frame.body), [frame.body, np.zeros(6)])[1] += frame.wrench(f)
    blocks: dict[tuple[int, int], list] = {}

    def block(bi, bj):
        return blocks.setdefault((id(bi), id(bj)), [bi, bj, np.zeros((6, 6)), np.zeros((6, 6))])
    for frame, f in zip(frames, forces):
        if frame.body is not None:
            block(frame.body, frame.body)[2] += frame.wrench_stiffness(f)
    K = None if stiffness is None else np.asarray(stiffness, dtype=float).reshape(3 * n, 3 * n)
    D = None if damping is None else np.asarray(damping, dtype=float).reshape(3 * n, 3 * n)
    for i, fi in enumerate(frames):
        for j, fj in enumerate(frames):
            if fi.body is None or fj.body is None:
                continue
            entry = block(fi.body, fj.body)
            Gi, Gj = fi.jacobian(), fj.jacobian()
            if K is not None:
                entry[2] += Gi.T @ K[3 * i:3 * i + 3, 3 * j:3 * j + 3] @ Gj
            if D is not None:
                Dij = D[3 * i:3 * i + 3, 3 * j:3 * j + 3]
                entry[3] += Gi.T @ Dij @ Gj
                entry[2][:, 3:] -= Gi.T @ Dij @ skew(fj.body.angular_velocity) @ skew(fj.lever())
    return ([tuple(w) for w in wrenches.values()], [tuple(b) for b in blocks.values()])


class RigidSystem:
    """Rigid bodies, joints and force elements advanced by the step of the module docstring.

    Args:
        gravity: the gravitational acceleration g (world).
        stabilization: beta in [0, 1], the fraction of the joint position error
            removed per step (0: none).
    """

    def __init__(self, gravity=(0.0, 0.0, -9.81), *, stabilization: float = 1.0):
        g = np.asarray(gravity, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise InputError(f"gravity must be 3 finite numbers, got {gravity!r}")
        if not 0.0 <= stabilization <= 1.0:
            raise InputError(f"stabilization must be in [0, 1], got {stabilization!r}")
        self.gravity = g
        self.stabilization = float(stabilization)
        self.t = 0.0
        self.bodies: list[RigidBody] = []
        self.joints: list[Joint] = []
        self.forces: list[ForceElement] = []
        self._impulses: dict[Joint, list[tuple[ConstraintRows, np.ndarray]]] = {}
        self._last_h = 1.0

    # ---- building ------------------------------------------------------------------------

    def add(self, *items) -> None:
        """Add rigid bodies, joints and force elements (any order)."""
        for item in items:
            if isinstance(item, RigidBody):
                if item.name in {b.name for b in self.bodies}:
                    raise InputError(f"a body named {item.name!r} is already in the system")
                if item.massless:
                    raise InputError(f"rigid body {item.name!r} is massless (a marker): it can "
                                     "only follow an attachment in a Scene")
                if item.motion == "prescribed":
                    item.follow_trajectory(self.t)
                self.bodies.append(item)
            elif isinstance(item, Joint):
                if any(item is j for j in self.joints):
                    raise InputError(f"joint {item.name!r} is already in the system")
                self.joints.append(item)
            elif isinstance(item, ForceElement):
                self.forces.append(item)
            else:
                raise TypeError(f"cannot add {type(item).__name__} to a RigidSystem: expected a "
                                "RigidBody, a Joint or a force element with wrenches(t)")

    # ---- observation ---------------------------------------------------------------------

    def kinetic_energy(self) -> float:
        return sum(b.kinetic_energy() for b in self.bodies if b.dynamic)

    def potential_energy(self) -> float:
        """Gravity (-m g . p) of the dynamic bodies plus the force elements' potential_energy()."""
        gravity = sum(b.potential_energy(self.gravity) for b in self.bodies if b.dynamic)
        return gravity + sum(e.potential_energy() for e in self.forces
                             if hasattr(e, "potential_energy"))

    def energy(self) -> float:
        return self.kinetic_energy() + self.potential_energy()

    def momentum(self, about=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """Linear momentum and angular momentum about ``about`` of the dynamic bodies."""
        dyn = [b for b in self.bodies if b.dynamic]
        return (sum((b.mass * b.velocity for b in dyn), np.zeros(3)),
                sum((b.angular_momentum(about) for b in dyn), np.zeros(3)))

    def constraint_errors(self) -> dict[str, float]:
        """max |phi| of each joint's bilateral rows (m and rad) at the current poses."""
        return {j.name: float(np.abs(j.constraint().phi).max()) for j in self.joints}

    def reaction(self, joint: Joint) -> tuple[np.ndarray, np.ndarray]:
        """The wrenches (world, about each COM) the joint applied to bodies A and B last step.

        G_A^T lambda / h and G_B^T lambda / h with the rows at the start of the step
        (bilateral and limit rows); zeros before the first step.
        """
        if not any(joint is j for j in self.joints):
            raise UnknownNameError(f"joint {joint.name!r} is not in the system")
        parts = self._impulses.get(joint, [])
        return (sum((rows.G_a.T @ lam for rows, lam in parts), np.zeros(6)) / self._last_h,
                sum((rows.G_b.T @ lam for rows, lam in parts), np.zeros(6)) / self._last_h)

    # ---- the step ------------------------------------------------------------------------

    def step(self, h: float) -> None:
        """Advance from t to t + h (module docstring)."""
        if not (np.isfinite(h) and h > 0):
            raise InputError(f"time step must be positive and finite, got {h!r}")
        t1 = self.t + h
        prescribed = {b: b.prescribed_state(t1) for b in self.bodies if b.motion == "prescribed"}
        for body, state in prescribed.items():      # known velocities over the step
            body.set_twist(np.concatenate([state.velocity, state.angular_velocity]))
        dyn = [b for b in self.bodies if b.dynamic]
        index = {id(b): 6 * k for k, b in enumerate(dyn)}
        known = {id(b) for b in self.bodies}
        A, b = self._dynamics(dyn, index, known, h, t1)
        bilateral, unilateral = self._constraints(index, known, h)
        u = self._solve(A, b, bilateral, unilateral)
        for body in dyn:
            k = index[id(body)]
            body.set_twist(u[k:k + 6])
            body.advance_pose(h)
        for body, state in prescribed.items():
            body.position, body.rotation = state.position, state.rotation
        self.t = t1
        self._last_h = h

    def _dynamics(self, dyn, index, known, h, t1):
        """A = M - h D - h^2 K and b = M u + h (f - D u) (module docstring)."""
        n = 6 * len(dyn)
        A = np.zeros((n, n))
        b = np.zeros(n)
        for body in dyn:
            k = slice(index[id(body)], index[id(body)] + 6)
            M, D, u = body.mass_matrix(), body.gyroscopic_damping(), body.twist
            f = body.gyroscopic_wrench()
            f[:3] += body.mass * self.gravity
            A[k, k] += M - h * D
            b[k] += M @ u + h * (f - D @ u)
        for element in self.forces:
            for body, wrench in element.wrenches(t1):
                wrench = self._checked(element, known, body, wrench, (6,))
                if body.dynamic:
                    b[index[id(body)]:index[id(body)] + 6] += h * wrench
            for bi, bj, K, D in getattr(element, "jacobians", lambda t: ())(t1):
                K, D = (self._checked(element, known, bi, np.zeros((6, 6)) if X is None else X,
                                      (6, 6), bj) for X in (K, D))
                if not bi.dynamic:
                    continue
                i = slice(index[id(bi)], index[id(bi)] + 6)
                if bj.dynamic:
                    j = slice(index[id(bj)], index[id(bj)] + 6)
                    A[i, j] -= h * D + h * h * K
                    b[i] -= h * D @ bj.twist
                elif bj.motion == "prescribed":     # f(q+) ~ f + K h u_j(t1); D u_j is in f
                    b[i] += h * h * K @ bj.twist
        return A, b

    @staticmethod
    def _checked(element, known, body, array, shape, other=None) -> np.ndarray:
        """``array`` as a finite float array of ``shape``, the bodies it concerns in the system."""
        what = f"force element {type(element).__name__}"
        for b in (body, other or body):
            if not isinstance(b, RigidBody) or id(b) not in known:
                raise InputError(f"{what} acts on {b!r}, which is not a body of this system")
        array = np.asarray(array, dtype=float)
        if array.shape != shape or not np.all(np.isfinite(array)):
            raise InputError(f"{what}: expected a finite array of shape {shape} for body "
                             f"{body.name!r}, got shape {array.shape}")
        return array

    def _constraints(self, index, known, h):
        """(joint, rows, G, c) of the bilateral and of the unilateral rows, G over the dofs."""
        n = 6 * len(index)
        beta = self.stabilization
        blocks = {"bilateral": [], "unilateral": []}
        for joint in self.joints:
            for body in joint.bodies:
                if body is not None and id(body) not in known:
                    raise InputError(f"joint {joint.name!r} connects body {body.name!r}, "
                                     "which is not in the system")
            for kind, rows in (("bilateral", joint.constraint()),
                               ("unilateral", joint.unilateral())):
                if not len(rows):
                    continue
                G = np.zeros((len(rows), n))
                if kind == "bilateral":
                    c = -beta * rows.phi / h
                else:                               # reach the limit, never cross it
                    c = np.where(rows.phi > 0, -rows.phi / h, -beta * rows.phi / h)
                for body, G_body in zip(joint.bodies, (rows.G_a, rows.G_b)):
                    if body is None:
                        continue
                    if body.dynamic:
                        G[:, index[id(body)]:index[id(body)] + 6] += G_body
                    else:                           # known velocity: zero when fixed
                        c = c - G_body @ body.twist
                blocks[kind].append((joint, rows, G, c))
        return blocks["bilateral"], blocks["unilateral"]

    def _solve(self, A, b, bilateral, unilateral) -> np.ndarray:
        """u+ from the KKT system by its Schur complement, with an active set for the limits."""
        if not A.size:
            self._impulses = {}
            return np.zeros(0)
        groups = bilateral + unilateral
        G = np.vstack([g[2] for g in groups]) if groups else np.zeros((0, len(b)))
        try:
            X = np.linalg.solve(A, np.column_stack([b, G.T]))
        except np.linalg.LinAlgError as exc:
            raise RigidStepFailed(f"t = {self.t:g}: the step matrix M - h D - h^2 K is singular "
                                  f"({exc})") from exc
        a, W = X[:, 0], X[:, 1:]                    # A^-1 b, A^-1 G^T
        if not groups:
            self._impulses = {}
            return self._finite(a)
        c = np.concatenate([g[3] for g in groups])
        S = G @ W
        r = c - G @ a
        n_bi = sum(len(g[3]) for g in bilateral)
        limit = np.arange(n_bi, len(c))
        active = np.zeros(len(c), dtype=bool)
        active[:n_bi] = True
        lam = np.zeros(len(c))
        tol = 1e-10 * max(1.0, np.abs(c).max())
        for _ in range(2 * limit.size + 10):
            on = np.flatnonzero(active)
            lam[:] = 0.0
            if on.size:
                lam[on] = np.linalg.lstsq(S[np.ix_(on, on)], r[on], rcond=1e-12)[0]
            if not limit.size:
                break
            slack = S[limit] @ lam - r[limit]       # G_lim u+ - c_lim >= 0 wanted
            negative = active[limit] & (lam[limit] < -tol)
            violated = ~active[limit] & (slack < -tol)
            if negative.any():
                active[limit[np.argmin(np.where(negative, lam[limit], np.inf))]] = False
            elif violated.any():
                active[limit[np.argmin(np.where(violated, slack, np.inf))]] = True
            else:
                break
        else:
            raise RigidStepFailed(f"t = {self.t:g}: the joint-limit active set did not settle")
        self._impulses = {}
        start = 0
        for joint, rows, _, c_rows in groups:
            self._impulses.setdefault(joint, []).append((rows, lam[start:start + len(c_rows)]))
            start += len(c_rows)
        return self._finite(a + W @ lam)

    def _finite(self, u: np.ndarray) -> np.ndarray:
        if not np.all(np.isfinite(u)):
            raise RigidStepFailed(f"t = {self.t:g}: non-finite velocities")
        return u
