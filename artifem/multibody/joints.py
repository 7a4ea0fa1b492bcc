"""Bilateral joints between two frames, and the coordinate limits of hinges and sliders.

A joint connects frame A (on body A) to frame B (on body B, or on the world),
ArtiSynth's frames C and D. With a_i, b_i the axes (columns) of the two frames
in world coordinates, x_A, x_B their origins, p_A, p_B the COMs and
d = x_A - x_B, each joint is a set of position constraints phi(q) = 0 of two
kinds, both with an exact velocity Jacobian (phi' = G_A u_A + G_B u_B):

- translation along b_k:   phi = b_k . d,
      G_A = [b_k, (x_A - p_A) x b_k],   G_B = -[b_k, (x_A - p_B) x b_k]
  (the reaction is a force along b_k at x_A, equal and opposite on A and B);
- rotation, a combination of axis products with coefficients C_ij:
      phi = sum_ij C_ij a_i . b_j,   G_A = [0, sum_ij C_ij a_i x b_j],   G_B = -G_A
  (d(a . b)/dt = (a x b) . (w_A - w_B)).

The rows per joint (translation axes of B; rotation rows):

| joint      | translation     | rotation                                      | rows |
|------------|-----------------|-----------------------------------------------|------|
| fixed      | x, y, z         | vee(skew(B^T A)): 1/2 (a_j . b_i - a_i . b_j)  | 6    |
| spherical  | x, y, z         | -                                             | 3    |
| revolute   | x, y, z         | z_A . y_B = 0, z_A . x_B = 0 (hinge about z)  | 5    |
| slider     | x, y            | vee(skew(B^T A)) (slides along z)             | 5    |
| planar     | z               | z_A . y_B = 0, z_A . x_B = 0 (xy plane, turns about z) | 3 |

Near phi = 0 each rotation row is the small rotation angle about one axis of B
(the vee rows are sin(angle) times the rotation axis), so phi is a position
error in metres and radians for drift stabilization.

Limits (unilateral, phi_lim >= 0): the revolute angle
theta = atan2(a_x . b_y, a_x . b_x) in [lower, upper] within [-pi, pi] with
theta' = (c (a_x x b_y) - s (a_x x b_x)) / (c^2 + s^2) . (w_A - w_B), s, c the
two products; the slider distance s = b_z . d in [lower, upper] (a translation row).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from artifem.errors import InputError
from artifem.multibody.constraint_rows import RowBlock
from artifem.multibody.rigid_body import Frame, RigidBody, cross, skew, skews

__all__ = [
    "ConstraintRows",
    "FixedJoint",
    "Joint",
    "PlanarJoint",
    "RevoluteJoint",
    "SliderJoint",
    "SphericalJoint",
    "axis_rotation",
]


def _levi_civita() -> np.ndarray:
    eps = np.zeros((3, 3, 3))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        eps[i, j, k], eps[i, k, j] = 1.0, -1.0
    return eps


#: Rotation rows phi_k = 1/2 eps_kij a_i . b_j = vee(skew(B^T A))_k: all three rotations locked.
LOCK_ROTATION = 0.5 * _levi_civita()
#: Rotation rows -z_A . y_B and z_A . x_B: z axes aligned, free to turn about z.
ALIGN_Z = np.zeros((2, 3, 3))
ALIGN_Z[0, 2, 1], ALIGN_Z[1, 2, 0] = -1.0, 1.0


def axis_rotation(axis) -> np.ndarray:
    """A rotation whose z column is the unit vector along ``axis`` (x and y chosen stably)."""
    z = np.asarray(axis, dtype=float)
    norm = np.linalg.norm(z) if z.shape == (3,) else 0.0
    if not (np.isfinite(norm) and norm > 0):
        raise InputError(f"axis must be a non-zero 3-vector, got {axis!r}")
    z = z / norm
    helper = np.eye(3)[np.argmin(np.abs(z))]
    x = cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, cross(z, x), z])


@dataclass(frozen=True)
class ConstraintRows:
    """phi (m,) and its Jacobians G_A, G_B (m x 6 on each body's [v; w])."""

    phi: np.ndarray
    G_a: np.ndarray
    G_b: np.ndarray

    def __len__(self) -> int:
        return self.phi.size


def _translation_rows(fa: Frame, fb: Frame, axes: np.ndarray) -> ConstraintRows:
    """phi = b_k . (x_A - x_B) for the world directions b_k (rows of ``axes``); module docstring."""
    xa = fa.world_position()
    phi = axes @ (xa - fb.world_position())
    G_a = np.zeros((len(axes), 6))
    G_b = np.zeros((len(axes), 6))
    if fa.body is not None:
        G_a[:, :3] = axes
        G_a[:, 3:] = cross(xa - fa.body.position, axes)
    if fb.body is not None:
        G_b[:, :3] = -axes
        G_b[:, 3:] = -cross(xa - fb.body.position, axes)
    return ConstraintRows(phi, G_a, G_b)


def _rotation_rows(fa: Frame, fb: Frame, coefficients: np.ndarray) -> ConstraintRows:
    """phi_r = sum_ij C_rij a_i . b_j, angular rows +-sum_ij C_rij a_i x b_j (module docstring)."""
    A, B = fa.world_rotation(), fb.world_rotation()
    crosses = cross(A.T[:, None, :], B.T[None, :, :])  # [i, j] = a_i x b_j
    phi = np.einsum("rij,ij->r", coefficients, A.T @ B)
    rows = np.einsum("rij,ijk->rk", coefficients, crosses)
    zeros = np.zeros_like(rows)
    return ConstraintRows(phi, np.hstack([zeros, rows]), np.hstack([zeros, -rows]))


def _stack(*blocks: ConstraintRows) -> ConstraintRows:
    return ConstraintRows(
        np.concatenate([b.phi for b in blocks]),
        np.vstack([b.G_a for b in blocks]),
        np.vstack([b.G_b for b in blocks]),
    )


def _check_limits(limits, bounds: tuple[float, float], what: str):
    if limits is None:
        return None
    try:
        lower, upper = (float(v) for v in limits)
    except (TypeError, ValueError):
        raise InputError(f"{what}: limits must be (lower, upper), got {limits!r}") from None
    if not (np.isfinite(lower) and np.isfinite(upper) and bounds[0] <= lower < upper <= bounds[1]):
        raise InputError(
            f"{what}: limits need finite {bounds[0]:g} <= lower < upper <= "
            f"{bounds[1]:g}, got ({lower:g}, {upper:g})"
        )
    return lower, upper


@dataclass(frozen=True, eq=False)
class Joint:
    """A bilateral constraint between ``frame_a`` and ``frame_b`` (see the module docstring).

    Subclasses set TRANSLATION (the constrained axes of frame B) and ROTATION
    (coefficient rows C_r). ``limits`` (lower, upper), where a subclass allows
    them, adds unilateral rows on its coordinate.
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "joints"

    frame_a: Frame
    frame_b: Frame
    name: str = ""
    limits: tuple[float, float] | None = None

    TRANSLATION: ClassVar[tuple[int, ...]] = ()
    ROTATION: ClassVar[np.ndarray] = np.zeros((0, 3, 3))
    LIMIT_BOUNDS: ClassVar[tuple[float, float] | None] = None

    def __post_init__(self):
        if not self.name:
            object.__setattr__(self, "name", type(self).__name__)
        what = f"joint {self.name!r}"
        for frame in (self.frame_a, self.frame_b):
            if not isinstance(frame, Frame):
                raise InputError(f"{what}: expected Frame objects, got {type(frame).__name__}")
        if self.frame_a.body is None and self.frame_b.body is None:
            raise InputError(f"{what}: both frames are on the world; one must be on a body")
        if self.frame_a.body is self.frame_b.body:
            raise InputError(f"{what}: both frames are on body {self.frame_a.body.name!r}")
        if self.limits is not None and self.LIMIT_BOUNDS is None:
            raise InputError(f"{what}: a {type(self).__name__} has no coordinate to limit")
        if self.LIMIT_BOUNDS is not None:
            object.__setattr__(self, "limits", _check_limits(self.limits, self.LIMIT_BOUNDS, what))

    @classmethod
    def at_world(
        cls, body_a: RigidBody | None, body_b: RigidBody | None, position, rotation=None, **kwargs
    ) -> Joint:
        """The joint whose two frames coincide now at the world pose (position, rotation)."""
        return cls(
            Frame.at_world(body_a, position, rotation),
            Frame.at_world(body_b, position, rotation),
            **kwargs,
        )

    @property
    def bodies(self) -> tuple[RigidBody | None, RigidBody | None]:
        return self.frame_a.body, self.frame_b.body

    def row_blocks(self) -> list[RowBlock]:
        """The joint's rows in the constraint protocol (:mod:`~artifem.multibody.
        constraint_rows`): its bilateral rows (:meth:`constraint`, impulses free) and, with
        ``limits``, its limit rows (:meth:`unilateral`, impulses >= 0)."""
        rows = self.constraint()
        blocks = [
            RowBlock.bilateral(
                self, rows.phi, zip(self.bodies, (rows.G_a, rows.G_b)), self.constraint_stiffness
            )
        ]
        if self.limits is not None:
            rows = self.unilateral()
            blocks.append(
                RowBlock.unilateral(
                    self, rows.phi, zip(self.bodies, (rows.G_a, rows.G_b)), self.limit_stiffness
                )
            )
        return blocks

    def constraint_failure(self) -> None:
        """Nothing fails a step: the rows remove the joint's drift (Baumgarte)."""
        return None

    def hold_pairs(self, hold: bool) -> None:
        """Nothing to hold: a joint's rows pair no features (the constraint protocol)."""

    def constraint(self) -> ConstraintRows:
        """phi(q) and its exact velocity Jacobians G_A, G_B at the current poses."""
        blocks = []
        if self.TRANSLATION:
            axes = self.frame_b.world_rotation()[:, list(self.TRANSLATION)].T
            blocks.append(_translation_rows(self.frame_a, self.frame_b, axes))
        if len(self.ROTATION):
            blocks.append(_rotation_rows(self.frame_a, self.frame_b, self.ROTATION))
        return _stack(*blocks)

    def constraint_stiffness(self, lam) -> np.ndarray:
        """d(G^T lambda)/dq of :meth:`Joint.constraint`'s rows at fixed impulses ``lam``
        (12 x 12: [p_A, theta_A, p_B, theta_B], the order of the stiffness helpers at the
        end of this module)."""
        lam = np.asarray(lam, dtype=float)
        K = np.zeros((12, 12))
        n_t = len(self.TRANSLATION)
        if n_t:
            axes = self.frame_b.world_rotation()[:, list(self.TRANSLATION)]
            K += _translation_stiffness(self.frame_a, self.frame_b, axes @ lam[:n_t])
        if len(self.ROTATION):
            K += _rotation_stiffness(
                self.frame_a, self.frame_b, np.einsum("r,rij->ij", lam[n_t:], self.ROTATION)
            )
        return K

    def unilateral(self) -> ConstraintRows:
        """Limit rows [coordinate - lower, upper - coordinate] >= 0; none without limits."""
        if self.limits is None:
            return ConstraintRows(np.zeros(0), np.zeros((0, 6)), np.zeros((0, 6)))
        value, G_a, G_b = self._coordinate_rows()
        lower, upper = self.limits
        return ConstraintRows(
            np.array([value - lower, upper - value]), np.vstack([G_a, -G_a]), np.vstack([G_b, -G_b])
        )

    def limit_stiffness(self, lam) -> np.ndarray:
        """d(G^T lambda)/dq of :meth:`Joint.unilateral`'s two rows (+G, -G) at fixed ``lam``."""
        lam = np.asarray(lam, dtype=float)
        if self.limits is None or not lam.size:
            return np.zeros((12, 12))
        return self._coordinate_stiffness(float(lam[0] - lam[1]))

    def _coordinate_rows(self) -> tuple[float, np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _coordinate_stiffness(self, lam: float) -> np.ndarray:
        raise NotImplementedError


class FixedJoint(Joint):
    """Welds frame A to frame B (ArtiSynth's SolidJoint): 6 rows."""

    TRANSLATION = (0, 1, 2)
    ROTATION = LOCK_ROTATION


class SphericalJoint(Joint):
    """The origins coincide, rotation free (ball joint): 3 rows."""

    TRANSLATION = (0, 1, 2)


class RevoluteJoint(Joint):
    """A hinge about the common z axis of the frames: 5 rows; ``limits`` on the angle (rad)."""

    TRANSLATION = (0, 1, 2)
    ROTATION = ALIGN_Z
    LIMIT_BOUNDS = (-np.pi, np.pi)

    def angle(self) -> float:
        """theta = atan2(a_x . b_y, a_x . b_x): the rotation of A about z relative to B."""
        return self._coordinate_rows()[0]

    def _coordinate_rows(self):
        a_x = self.frame_a.world_rotation()[:, 0]
        B = self.frame_b.world_rotation()
        s, c = a_x @ B[:, 1], a_x @ B[:, 0]
        row = (c * cross(a_x, B[:, 1]) - s * cross(a_x, B[:, 0])) / (c * c + s * s)
        zeros = np.zeros(3)
        return (
            float(np.arctan2(s, c)),
            np.concatenate([zeros, row])[None],
            np.concatenate([zeros, -row])[None],
        )

    def _coordinate_stiffness(self, lam: float) -> np.ndarray:
        """The angle row g = (c (a_x x b_y) - s (a_x x b_x)) / (c^2 + s^2) on [0; g] (A) and
        [0; -g] (B): d(lam g)/dtheta_A and /dtheta_B."""
        K = np.zeros((12, 12))
        a_x = self.frame_a.world_rotation()[:, 0]
        B = self.frame_b.world_rotation()
        b_x, b_y = B[:, 0], B[:, 1]
        s, c = a_x @ b_y, a_x @ b_x
        u, w = cross(a_x, b_y), cross(a_x, b_x)
        n = c * c + s * s
        g = (c * u - s * w) / n
        dn = 2.0 * (c * w + s * u)  # dn = dn . (dtheta_A - dtheta_B)
        base = (np.outer(u, w) - np.outer(w, u) - np.outer(g, dn)) / n
        Ax, By, Bx = skew(a_x), skew(b_y), skew(b_x)
        dA = base + (c * By @ Ax - s * Bx @ Ax) / n
        dB = -base + (-c * Ax @ By + s * Ax @ Bx) / n
        a, b = self.frame_a.body is not None, self.frame_b.body is not None
        for on, r, sign in ((a, 3, 1.0), (b, 9, -1.0)):
            if not on:
                continue
            if a:
                K[r : r + 3, 3:6] = sign * lam * dA
            if b:
                K[r : r + 3, 9:12] = sign * lam * dB
        return K


class SliderJoint(Joint):
    """A prismatic joint along the z axis of frame B: 5 rows; ``limits`` on the distance (m)."""

    TRANSLATION = (0, 1)
    ROTATION = LOCK_ROTATION
    LIMIT_BOUNDS = (-np.inf, np.inf)  # any finite pair

    def distance(self) -> float:
        """s = b_z . (x_A - x_B)."""
        return self._coordinate_rows()[0]

    def _coordinate_rows(self):
        rows = _translation_rows(self.frame_a, self.frame_b, self.frame_b.world_rotation()[:, 2:].T)
        return float(rows.phi[0]), rows.G_a, rows.G_b

    def _coordinate_stiffness(self, lam: float) -> np.ndarray:
        return _translation_stiffness(
            self.frame_a, self.frame_b, lam * self.frame_b.world_rotation()[:, 2]
        )


class PlanarJoint(Joint):
    """Frame A moves in the xy plane of frame B and turns only about z: 3 rows."""

    TRANSLATION = (2,)
    ROTATION = ALIGN_Z


# ---- the rows' geometric stiffness: d(G^T lambda)/dq at fixed lambda -------------------------
#
# Columns and rows in the order [p_A, theta_A, p_B, theta_B] (12), the poses perturbed as
# p += dp, R = exp([dtheta]x) R (world), rows the wrenches G_A^T lambda and G_B^T lambda.
# A frame on the world has no rows and no columns (left zero).


def _translation_stiffness(fa: Frame, fb: Frame, force: np.ndarray) -> np.ndarray:
    """Of translation rows whose reaction is the world force f = sum_k lambda_k b_k at x_A
    (b_k the axes of frame B, turning with body B): on A [f; r_A x f], on B
    -[f; (x_A - p_B) x f]."""
    K = np.zeros((12, 12))
    F = skew(force)
    a, b = fa.body is not None, fb.body is not None
    r_a = fa.lever()
    if a:
        K[3:6, 3:6] = F @ skew(r_a)  # the lever of A turns
    if b:
        e = fa.world_position() - fb.body.position
        K[9:12, 9:12] = skew(e) @ F  # f turns with B, lever fixed
        K[6:9, 9:12] = F  # -f turns with B
        K[9:12, 6:9] = -F  # the lever x_A - p_B shortens with p_B
        if a:
            K[0:3, 9:12] = -F
            K[3:6, 9:12] = -skew(r_a) @ F
            K[9:12, 0:3] = F
            K[9:12, 3:6] = -F @ skew(r_a)
    return K


def _rotation_stiffness(fa: Frame, fb: Frame, M: np.ndarray) -> np.ndarray:
    """Of rotation rows with the torque tau_A = sum_ij M_ij a_i x b_j = -tau_B."""
    K = np.zeros((12, 12))
    A, B = fa.world_rotation(), fb.world_rotation()
    SA, SB = skews(A.T), skews(B.T)  # [a_i]x, [b_j]x
    dA = np.einsum("ij,jkl,ilm->km", M, SB, SA)  # sum M_ij [b_j]x [a_i]x
    dB = -np.einsum("ij,ikl,jlm->km", M, SA, SB)  # -sum M_ij [a_i]x [b_j]x
    a, b = fa.body is not None, fb.body is not None
    for on, sign in ((a, 1.0), (b, -1.0)):
        if not on:
            continue
        r = 3 if sign > 0 else 9
        if a:
            K[r : r + 3, 3:6] = sign * dA
        if b:
            K[r : r + 3, 9:12] = sign * dB
    return K
