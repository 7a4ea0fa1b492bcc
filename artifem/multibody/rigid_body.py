"""Rigid bodies and the frames attached to them (ArtiSynth's RigidBody, Frame).

Pose: the world position p of the centre of mass (COM) and the rotation R
(body to world, kept orthonormal). Velocity: 6 dofs u = [v; w], the COM
velocity v and the angular velocity w, both in world coordinates. The body
frame has its origin at the COM; the inertia I_b (3 x 3, about the COM) is
given in body axes, in world axes it is I_w = R I_b R^T.

Newton-Euler equations about the COM, in world coordinates:

    M u' = f_ext + f_gyro,    M = diag(m 1, I_w),    f_gyro = [0; -w x (I_w w)],

with the wrench f = [force; torque about the COM]. Poses advance by

    p+ = p + h v+,    R+ = exp(h [w+]x) R    (Rodrigues),

so a pose variation is dq = [dp; dtheta] with R -> exp([dtheta]x) R, the dual of
the wrench. R is re-orthonormalized (polar factor) when round-off makes
|R^T R - 1| exceed 1e-12.

A point r_b (body coordinates, relative to the COM) sits at x = p + R r_b and
moves with x' = v + w x r = G_b u, G_b = [1, -[r]x], r = R r_b; a force f at x
is the wrench G_b^T f = [f; r x f] on the body (virtual work).

Mass properties from a closed triangulated surface use the divergence theorem
over the signed tetrahedra (c0, a, b, c) that each triangle forms with a
reference point c0 (Mirtich 1996; Blow & Binstock 2004). With a, b, c relative
to c0, d = a . (b x c) and s = a + b + c:

    V = sum d / 6,    S1 = sum d s / 24,
    C = int x x^T dV = sum d (a a^T + b b^T + c c^T + s s^T) / 120,

so m = rho V, COM = c0 + S1 / V, C_com = C - V e e^T (e = S1 / V) and
I = rho (tr(C_com) 1 - C_com). Triangles must be outward-oriented and the
surface closed; cavities are inner components oriented inward.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np
from scipy import sparse

from artifem.contact_points import facing_areas
from artifem.errors import InputError

__all__ = [
    "BodyPoints",
    "BodyState",
    "Frame",
    "MassProperties",
    "RigidBody",
    "cross",
    "exp_so3",
    "orthonormalize",
    "skew",
]

MOTIONS = ("dynamic", "fixed", "prescribed")
ORTHONORMAL_TOL = 1e-12


def skew(a) -> np.ndarray:
    """[a]x, the matrix with [a]x b = a x b."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def skews(d: np.ndarray) -> np.ndarray:
    """[d_i]x for each row of d (n, 3) -> (n, 3, 3)."""
    S = np.zeros((len(d), 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -d[:, 2], d[:, 1]
    S[:, 1, 0], S[:, 1, 2] = d[:, 2], -d[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -d[:, 1], d[:, 0]
    return S


def cross(a, b) -> np.ndarray:
    """a x b over the last axis (broadcasting); np.cross without its per-call overhead."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.ndim == b.ndim == 1:
        return np.array(
            [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
        )
    return np.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )


def exp_so3(phi) -> np.ndarray:
    """Rodrigues: exp([phi]x) = 1 + sin t [k]x + (1 - cos t) [k]x^2, t = |phi|, k = phi / t."""
    phi = np.asarray(phi, dtype=float)
    t = float(np.linalg.norm(phi))
    K = skew(phi)
    if t < 1e-8:  # series to second order; error O(t^3) < round-off
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + (np.sin(t) / t) * K + ((1.0 - np.cos(t)) / (t * t)) * K @ K


def dexp_so3(phi) -> np.ndarray:
    """The left Jacobian of exp: exp([phi + dphi]x) = exp([J dphi]x) exp([phi]x) + O(dphi^2),
    J = 1 + (1 - cos t) / t^2 [phi]x + (t - sin t) / t^3 [phi]x^2, t = |phi|."""
    phi = np.asarray(phi, dtype=float)
    t = float(np.linalg.norm(phi))
    K = skew(phi)
    if t < 1e-6:  # series: error O(t^3)
        return np.eye(3) + 0.5 * K + K @ K / 6.0
    return np.eye(3) + ((1.0 - np.cos(t)) / (t * t)) * K + ((t - np.sin(t)) / t**3) * K @ K


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """The rotation nearest to R (polar factor U V^T of R = U S V^T)."""
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def _vector(value, what: str) -> np.ndarray:
    vec = np.asarray(value, dtype=float)
    if vec.shape != (3,) or not np.all(np.isfinite(vec)):
        raise InputError(f"{what}: expected 3 finite numbers, got {value!r}")
    return vec.copy()


def _rotation(value, what: str) -> np.ndarray:
    if value is None:
        return np.eye(3)
    R = np.asarray(value, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise InputError(f"{what}: expected a finite 3 x 3 rotation matrix, got shape {R.shape}")
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-8 or np.linalg.det(R) <= 0:
        raise InputError(f"{what}: not a rotation (R^T R != 1 or det R <= 0)")
    return orthonormalize(R)


def _check_surface(vertices: np.ndarray, triangles: np.ndarray, what: str) -> None:
    """A closed, consistently oriented triangle surface, or a ValueError saying what is wrong."""
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.all(np.isfinite(vertices)):
        raise InputError(f"{what}: vertices must be a finite (n, 3) array, got {vertices.shape}")
    if triangles.ndim != 2 or triangles.shape[1] != 3 or triangles.shape[0] < 4:
        raise InputError(
            f"{what}: triangles must be an (m >= 4, 3) integer array, got {triangles.shape}"
        )
    if triangles.min() < 0 or triangles.max() >= len(vertices):
        raise InputError(f"{what}: triangle indices must be in [0, {len(vertices)})")
    repeated = np.flatnonzero(
        (triangles[:, 0] == triangles[:, 1])
        | (triangles[:, 1] == triangles[:, 2])
        | (triangles[:, 2] == triangles[:, 0])
    )
    if repeated.size:
        raise InputError(f"{what}: triangles {repeated[:5].tolist()} repeat a vertex")
    n = len(vertices)
    i = triangles.ravel()
    j = np.roll(triangles, -1, axis=1).ravel()
    codes, counts = np.unique(i * n + j, return_counts=True)
    if np.any(counts > 1):
        e = codes[counts > 1][0]
        raise InputError(
            f"{what}: edge ({e // n}, {e % n}) is used twice in the same direction: "
            "the triangles are inconsistently oriented or the surface is "
            "non-manifold"
        )
    boundary = codes[~np.isin((codes % n) * n + codes // n, codes)]
    if boundary.size:
        e = boundary[0]
        raise InputError(
            f"{what}: the surface is not closed: {boundary.size} boundary edges, "
            f"e.g. ({e // n}, {e % n})"
        )


@dataclass(frozen=True)
class MassProperties:
    """Mass, centre of mass (world/mesh coordinates) and inertia about the COM (mesh axes)."""

    mass: float
    center: np.ndarray
    inertia: np.ndarray

    def __post_init__(self):
        if not (np.isfinite(self.mass) and self.mass > 0):
            raise InputError(f"mass must be positive and finite, got {self.mass!r}")
        object.__setattr__(self, "center", _vector(self.center, "centre of mass"))
        inertia = np.asarray(self.inertia, dtype=float)
        if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
            raise InputError(f"inertia must be a finite 3 x 3 matrix, got shape {inertia.shape}")
        if np.abs(inertia - inertia.T).max() > 1e-9 * np.abs(inertia).max():
            raise InputError("inertia must be symmetric")
        inertia = 0.5 * (inertia + inertia.T)
        principal = np.linalg.eigvalsh(inertia)
        tol = 1e-9 * principal[-1]
        if principal[0] <= 0 or principal[0] + principal[1] < principal[2] - tol:
            raise InputError(
                f"inertia has principal moments {principal.tolist()}: they must be "
                "positive and satisfy the triangle inequality I1 + I2 >= I3"
            )
        object.__setattr__(self, "inertia", inertia)

    @classmethod
    def from_surface(
        cls, vertices, triangles, density: float, what: str = "surface"
    ) -> MassProperties:
        """Mass properties of the solid bounded by a closed outward triangle surface.

        See the module docstring for the equations. ``what`` names the surface
        in errors. An open, inconsistently oriented or inverted (inward)
        surface is a ValueError.
        """
        if not (np.isfinite(density) and density > 0):
            raise InputError(f"{what}: density must be positive and finite, got {density!r}")
        vertices = np.asarray(vertices, dtype=float)
        triangles = np.asarray(triangles)
        if not np.issubdtype(triangles.dtype, np.integer):
            raise InputError(f"{what}: triangles must be integer vertex indices")
        _check_surface(vertices, triangles, what)
        c0 = vertices.mean(axis=0)  # conditioning: translated meshes stay exact
        a, b, c = (vertices[triangles[:, k]] - c0 for k in range(3))
        d = np.einsum("ij,ij->i", a, cross(b, c))
        s = a + b + c
        volume = d.sum() / 6.0
        if not volume > 0:
            raise InputError(
                f"{what}: enclosed volume {volume:.3g} <= 0: the triangles are "
                "oriented inward (inverted surface)"
            )
        e = (d @ s) / 24.0 / volume
        C = (
            np.einsum("i,ij,ik->jk", d, a, a)
            + np.einsum("i,ij,ik->jk", d, b, b)
            + np.einsum("i,ij,ik->jk", d, c, c)
            + np.einsum("i,ij,ik->jk", d, s, s)
        )
        C = C / 120.0 - volume * np.outer(e, e)
        return cls(density * volume, c0 + e, density * (np.trace(C) * np.eye(3) - C))


class BodyState(NamedTuple):
    """A pose and velocity in world coordinates: what a prescribed trajectory returns."""

    position: np.ndarray
    rotation: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray


#: t -> BodyState (p, R, v, w) of a prescribed (kinematic) body.
Trajectory = Callable[[float], BodyState]


class RigidBody:
    """A rigid body (see the module docstring for the state and equations).

    Args:
        name: used in errors and output.
        mass, inertia: the mass and the 3 x 3 inertia about the COM in body axes.
        position, rotation: the COM position and rotation matrix (world).
        velocity, angular_velocity: v and w (world).
        motion: ``"dynamic"`` (6 dofs), ``"fixed"`` (never moves) or
            ``"prescribed"`` (kinematic: pose and velocity from ``trajectory``).
        trajectory: t -> BodyState, required for (and only for) prescribed bodies.
        surface: optional (vertices in body coordinates, triangles) for output.
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "rigid_bodies"

    def __init__(
        self,
        name: str,
        mass: float,
        inertia,
        *,
        position=(0.0, 0.0, 0.0),
        rotation=None,
        velocity=(0.0, 0.0, 0.0),
        angular_velocity=(0.0, 0.0, 0.0),
        motion: str = "dynamic",
        trajectory: Trajectory | None = None,
        surface: tuple[np.ndarray, np.ndarray] | None = None,
    ):
        self.name = str(name)
        what = f"rigid body {self.name!r}"
        try:
            props = MassProperties(mass, np.zeros(3), inertia)
        except ValueError as exc:
            raise InputError(f"{what}: {exc}") from None
        if motion not in MOTIONS:
            raise InputError(f"{what}: motion must be one of {MOTIONS}, got {motion!r}")
        if (motion == "prescribed") != (trajectory is not None):
            raise InputError(
                f"{what}: a trajectory is required for, and only for, "
                f"motion='prescribed' (motion={motion!r})"
            )
        self.mass = props.mass
        self.inertia = props.inertia
        self.motion = motion
        self.trajectory = trajectory
        self.surface = surface
        self.position = _vector(position, f"{what}: position")
        self.rotation = _rotation(rotation, f"{what}: rotation")
        self.velocity = _vector(velocity, f"{what}: velocity")
        self.angular_velocity = _vector(angular_velocity, f"{what}: angular velocity")
        if motion == "fixed" and (self.velocity.any() or self.angular_velocity.any()):
            raise InputError(f"{what}: a fixed body cannot have a velocity")

    @classmethod
    def from_surface(cls, name: str, vertices, triangles, density: float, **kwargs) -> RigidBody:
        """A body of uniform ``density`` bounded by a closed outward triangle surface.

        The body frame is the mesh frame translated to the COM: p = COM, R = 1,
        and ``surface`` holds the vertices relative to the COM.
        """
        props = MassProperties.from_surface(
            vertices, triangles, density, what=f"rigid body {name!r}: surface"
        )
        if "position" in kwargs or "rotation" in kwargs:
            raise InputError(
                f"rigid body {name!r}: the pose of a body built from a surface is "
                "the surface's (COM, identity rotation); move the surface instead"
            )
        surface = (np.asarray(vertices, dtype=float) - props.center, np.asarray(triangles))
        return cls(
            name, props.mass, props.inertia, position=props.center, surface=surface, **kwargs
        )

    @classmethod
    def marker(cls, name: str, *, position=(0.0, 0.0, 0.0), rotation=None) -> RigidBody:
        """A massless dynamic body: a coordinate frame that follows an attachment (e.g. a
        frame on an FEM body, for joints and paths). It has no inertia of its own, so it
        can only be a slave (Scene checks); free, its step would be singular."""
        body = cls(name, 1.0, np.eye(3), position=position, rotation=rotation)
        body.mass, body.inertia = 0.0, np.zeros((3, 3))
        return body

    @property
    def massless(self) -> bool:
        return self.mass == 0.0

    def __repr__(self) -> str:
        return f"RigidBody({self.name!r}, mass={self.mass:.6g}, motion={self.motion!r})"

    # ---- state ---------------------------------------------------------------------------

    @property
    def dynamic(self) -> bool:
        return self.motion == "dynamic"

    @property
    def twist(self) -> np.ndarray:
        """u = [v; w] (world)."""
        return np.concatenate([self.velocity, self.angular_velocity])

    def set_twist(self, u: np.ndarray) -> None:
        self.velocity = np.array(u[:3], dtype=float)
        self.angular_velocity = np.array(u[3:], dtype=float)

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A copy of (p, R, u): the pose and the twist (the body interface of a scene)."""
        return self.position.copy(), self.rotation.copy(), self.twist

    def set_state(self, state) -> None:
        p, R, u = state
        self.position, self.rotation = np.array(p, dtype=float), np.array(R, dtype=float)
        self.set_twist(u)

    def constraint_failure(self) -> None:
        """A rigid body has no constraints of its own (the body interface)."""
        return None

    def inverted_elements(self) -> tuple[np.ndarray, float]:
        """A rigid body has no elements to invert: (none, inf) (the body interface)."""
        return np.zeros(0, dtype=np.int64), np.inf

    def inertia_world(self) -> np.ndarray:
        """I_w = R I_b R^T."""
        return self.rotation @ self.inertia @ self.rotation.T

    def mass_matrix(self) -> np.ndarray:
        """M = diag(m 1, I_w), 6 x 6."""
        M = np.zeros((6, 6))
        M[:3, :3] = self.mass * np.eye(3)
        M[3:, 3:] = self.inertia_world()
        return M

    def gyroscopic_wrench(self) -> np.ndarray:
        """f_gyro = [0; -w x (I_w w)]."""
        w = self.angular_velocity
        return np.concatenate([np.zeros(3), -cross(w, self.inertia_world() @ w)])

    def gyroscopic_damping(self) -> np.ndarray:
        """D_gyro = d f_gyro / du = [[0, 0], [0, [I_w w]x - [w]x I_w]]."""
        w = self.angular_velocity
        Iw = self.inertia_world()
        D = np.zeros((6, 6))
        D[3:, 3:] = skew(Iw @ w) - skew(w) @ Iw
        return D

    def kinetic_energy(self) -> float:
        """T = m |v|^2 / 2 + w . I_w w / 2."""
        w = self.angular_velocity
        return 0.5 * self.mass * self.velocity @ self.velocity + 0.5 * w @ self.inertia_world() @ w

    def potential_energy(self, gravity) -> float:
        """V = -m g . p (zero at the world origin)."""
        return -self.mass * float(np.dot(gravity, self.position))

    def angular_momentum(self, about=(0.0, 0.0, 0.0)) -> np.ndarray:
        """L = (p - about) x m v + I_w w."""
        return (
            cross(self.position - np.asarray(about, dtype=float), self.mass * self.velocity)
            + self.inertia_world() @ self.angular_velocity
        )

    def advance_pose(self, h: float) -> None:
        """p += h v, R = exp(h [w]x) R, re-orthonormalized when round-off demands it."""
        self.position = self.position + h * self.velocity
        R = exp_so3(h * self.angular_velocity) @ self.rotation
        if np.abs(R.T @ R - np.eye(3)).max() > ORTHONORMAL_TOL:
            R = orthonormalize(R)
        self.rotation = R

    def prescribed_state(self, t: float) -> BodyState:
        """A prescribed body's trajectory at time t, validated."""
        what = f"rigid body {self.name!r}: trajectory({t:g})"
        state = BodyState(*self.trajectory(t))
        return BodyState(
            _vector(state.position, f"{what} position"),
            _rotation(state.rotation, f"{what} rotation"),
            _vector(state.velocity, f"{what} velocity"),
            _vector(state.angular_velocity, f"{what} angular velocity"),
        )

    def follow_trajectory(self, t: float) -> None:
        """Put a prescribed body at its trajectory's pose and twist at time t."""
        state = self.prescribed_state(t)
        self.position, self.rotation = state.position, state.rotation
        self.set_twist(np.concatenate([state.velocity, state.angular_velocity]))

    def contact_points(self, points=None) -> BodyPoints:
        """The points contact may push (:mod:`artifem.contact_points`): ``points`` (n, 3) in
        the body frame about the COM, or the surface's vertices."""
        if points is None:
            if self.surface is None:
                raise InputError(
                    f"rigid body {self.name!r} has no surface: give the contact "
                    "points (body frame, about the COM)"
                )
            points = self.surface[0]
        return BodyPoints(self, points)

    def contact_surface(self) -> tuple[BodyPoints, np.ndarray]:
        """(the surface's vertices, its triangles); an InputError without a surface."""
        if self.surface is None:
            raise InputError(
                f"rigid body {self.name!r} has no surface for contact: give "
                "surface=(vertices, triangles) or use RigidBody.from_surface"
            )
        return BodyPoints(self, self.surface[0]), np.asarray(self.surface[1])

    def to_world(self, points) -> np.ndarray:
        """World positions of body-coordinate points (n, 3): p + R r_b."""
        return self.position + np.asarray(points, dtype=float) @ self.rotation.T


@dataclass(eq=False)
class Frame:
    """A coordinate frame fixed to a body (or to the world when ``body`` is None).

    ``position`` and ``rotation`` are the frame's offset in body coordinates
    (relative to the COM, body axes); for a world frame they are its world pose.
    The frame's origin moves with x' = G_b u (module docstring).
    """

    body: RigidBody | None
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        owner = "world" if self.body is None else repr(self.body.name)
        self.position = _vector(self.position, f"frame on {owner}: position")
        self.rotation = _rotation(self.rotation, f"frame on {owner}: rotation")

    @classmethod
    def at_world(cls, body: RigidBody | None, position, rotation=None) -> Frame:
        """The frame on ``body`` whose *current* world pose is (position, rotation)."""
        position = _vector(position, "frame: world position")
        rotation = _rotation(rotation, "frame: world rotation")
        if body is None:
            return cls(None, position, rotation)
        return cls(body, body.rotation.T @ (position - body.position), body.rotation.T @ rotation)

    def world_position(self) -> np.ndarray:
        """x = p + R r_b."""
        if self.body is None:
            return self.position
        return self.body.position + self.body.rotation @ self.position

    def world_rotation(self) -> np.ndarray:
        """R R_b: the frame's axes (columns) in world coordinates."""
        if self.body is None:
            return self.rotation
        return self.body.rotation @ self.rotation

    def lever(self) -> np.ndarray:
        """r = R r_b, the origin relative to the body's COM (world); zero for a world frame."""
        return np.zeros(3) if self.body is None else self.body.rotation @ self.position

    def velocity(self) -> np.ndarray:
        """x' = v + w x r."""
        if self.body is None:
            return np.zeros(3)
        return self.body.velocity + cross(self.body.angular_velocity, self.lever())

    def jacobian(self) -> np.ndarray:
        """G_b = [1, -[r]x] (3 x 6): x' = G_b u of the owning body."""
        return np.hstack([np.eye(3), -skew(self.lever())])

    def wrench(self, force) -> np.ndarray:
        """G_b^T f = [f; r x f]: the wrench on the body of a world force f at the origin."""
        force = np.asarray(force, dtype=float)
        return np.concatenate([force, cross(self.lever(), force)])

    def wrench_stiffness(self, force) -> np.ndarray:
        """d(G_b^T f)/dq at constant f (6 x 6): only the torque varies, d(r x f)/dtheta = [f]x [r]x.

        A force that depends on positions adds G_b^T (df/dx) G_b (``point_force_wrenches``).
        """
        K = np.zeros((6, 6))
        K[3:, 3:] = skew(np.asarray(force, dtype=float)) @ skew(self.lever())
        return K


class BodyPoints:
    """Points r_j fixed in a rigid body's frame (about the COM), x_j = p + R r_j: a point
    set of :mod:`artifem.contact_points`, rows on the twist [v; w]."""

    def __init__(self, body: RigidBody, points):
        self.body = body
        self.local = np.asarray(points, dtype=float)
        if (
            self.local.ndim != 2
            or self.local.shape[1] != 3
            or not len(self.local)
            or not np.all(np.isfinite(self.local))
        ):
            raise InputError(
                f"rigid body {body.name!r}: contact points must be a finite "
                f"(n >= 1, 3) array, got shape {self.local.shape}"
            )
        self.labels = np.arange(len(self.local))
        self.mesh_body = None  # no FEM mesh: no contact pressure
        self._areas = None  # facing_areas's, in the body frame

    def __len__(self) -> int:
        return len(self.local)

    def positions(self) -> np.ndarray:
        return self.body.to_world(self.local)

    def rigid_frame(self) -> tuple:
        """(r_j, R, p): the points in the body frame, and the pose, x_j = p + R r_j."""
        return self.local, self.body.rotation, self.body.position

    def describe(self, i: int) -> str:
        return f"point {i} (body frame {self.local[i].tolist()})"

    def _levers(self, W) -> tuple[np.ndarray, np.ndarray]:
        """(w_k = sum_j W_kj, r_k = sum_j W_kj R r_j) of the combined points."""
        W = sparse.csr_matrix(W)
        return np.asarray(W.sum(axis=1)).ravel(), W @ (self.local @ self.body.rotation.T)

    def rows(self, W, directions: np.ndarray) -> np.ndarray:
        """G_k = [w_k e_k^T, (r_k x e_k)^T]."""
        w, r = self._levers(W)
        return np.hstack([w[:, None] * directions, cross(r, directions)])

    def stiffness(self, W, forces: np.ndarray) -> np.ndarray:
        """sum_k [f_k]x [r_k]x on the rotation (the levers turn with the body)."""
        K = np.zeros((6, 6))
        K[3:, 3:] = np.einsum("jab,jbc->ac", skews(forces), skews(self._levers(W)[1]))
        return K

    def facing_areas(self, indices: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(k,) the surface area point ``indices[k]`` stands for against ``directions[k]``
        (:func:`~artifem.contact_points.facing_areas`): a third of each adjacent
        surface triangle facing it, projected on it, at the current pose. The points must
        be the surface's vertices (the default contact points)."""
        if self._areas is None:  # the triangles' vector areas in the body frame
            surface = self.body.surface
            if (
                surface is None
                or np.shape(surface[0]) != self.local.shape
                or not np.allclose(surface[0], self.local)
            ):
                raise InputError(
                    f"rigid body {self.body.name!r}: an elastic foundation "
                    "needs the contact points to be the body's surface "
                    "vertices (the default), to know the area each stands for"
                )
            x, tris = self.local, np.asarray(surface[1])
            self._areas = (
                0.5 * np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]]),
                tris,
            )
        area, tris = self._areas  # a_world . e = a_body . R^T e
        return facing_areas(
            area, tris, indices, np.asarray(directions) @ self.body.rotation, len(self.local)
        )
