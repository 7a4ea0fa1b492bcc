"""Contact of a body's surface points with a fixed plane: hard normal rows, Coulomb friction.

The plane holds the points x with n . x = d (n the unit normal, d = n . p_0); the free
side is n . x > d. The contact points are the body's (:mod:`artifem.contact_points`): a
rigid body's points r_i (body frame, about the COM: x_i = p + R r_i), a full FEM body's
boundary nodes (x_i = X_i + u_i) or a reduced body's (x_i = X_i + u_bar_i + U_i q). Each
point within ``margin`` of the plane (phi_i < margin) gives rows in the constraint
protocol (:mod:`~artifem.multibody.constraint_rows`), one block per step:

    normal:    phi_i = n . x_i - d >= 0,   lambda_n,i in [0, inf),
    friction:  t_1, t_2 (the x and y axes of ``axis_rotation(n)``), phi = 0,
               -mu lambda_n,i <= lambda_t,i <= mu lambda_n,i   (when mu > 0),

each row a direction e (n, t_1 or t_2) at the point, phi' = e . x_i' with

    rigid body (twist [v; w]):  G = [e^T, (r_i x e)^T],   r_i = R r_i (world),
    FEM body (nodal velocities): G = e^T on the node's 3 velocity dofs,
    reduced body (q'):           G = e^T U_i (the reaction reaches q through U_i^T e).

The step asks G z+ >= -phi / h while phi > 0: a point reaches the plane within the step
and stops on it (an inelastic impact: no rebound, no energy gained), and a crossed point
is pushed back by -beta phi / h. Friction rows ask G z+ = 0 (stick) while |lambda_t| <
mu lambda_n, else hold lambda_t at the bound against the slip. Each tangent direction is
bounded on its own: the friction pyramid, not the cone (sliding along a diagonal of t_1,
t_2 meets up to sqrt(2) mu lambda_n, and its direction leans to the nearer axis). The
bounds take the normal impulses of the same step (``RowBlock.friction``: a sliding row
is held at +-mu lambda_n of the same solve, :mod:`artifem.scene.constraints`), so
friction holds from the first step of a contact: ArtiSynth's
normal impulses of the previous step would let a body resting on an incline slip for
one step (h^2 g sin(theta) there) and slide without friction in its first step.

Penetration: the rows are linear in the velocities, so an FEM node (x+ = x + h v+) stops
on the plane to round-off; a rigid body's point moves by h v + (exp(h [w]x) - 1) r, so a
turning body crosses by O(h^2 |w|^2 |r|), pushed back in the next step. ``tolerance`` is
the penetration allowed: deeper after a step fails the step (it is retried and halved
like an inverted element), deeper at the start is an error before the run. A point that
comes from beyond ``margin`` within one step has no row and may cross: give a margin of at
least the largest approach speed times the step.

The rows' geometric stiffness (their levers turn with a rigid body): the force f = lambda e
at r_i gives the torque r_i x f, d(r_i x f)/dtheta = [f]x [r_i]x; an FEM node's rows do
not turn (zero).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy import sparse

from artifem.errors import InputError
from artifem.multibody.constraint_rows import Friction, RowBlock
from artifem.multibody.joints import axis_rotation

__all__ = ["ContactForces", "PlaneContact"]


class ContactForces(NamedTuple):
    """The forces the plane applied at the contact points over the last step (lambda / h).

    points: the points that had rows (a rigid body's: indices into its contact points;
        an FEM body's: input node indices); normal: (k,) the normal force of each (N, >= 0);
        friction: (k, 3) the friction force of each (world, N).
    """

    points: np.ndarray
    normal: np.ndarray
    friction: np.ndarray


@dataclass(frozen=True, eq=False)
class PlaneContactRows(RowBlock):
    """A :class:`PlaneContact`'s rows: k normal rows, then k along t_1 and k along t_2
    (with friction) at its ``points`` (indices into the contact's points); the rows' keys
    are (point, direction: 0 normal, 1 t_1, 2 t_2)."""

    points: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))


def check_options(what: str, mu: float, tolerance: float, margin: float) -> None:
    """A contact's options: mu >= 0, tolerance > 0, a finite margin above the tolerance;
    else an InputError naming the contact (``what``)."""
    if not (np.isfinite(mu) and mu >= 0):
        raise InputError(f"{what}: the friction coefficient mu must be >= 0, got {mu!r}")
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise InputError(f"{what}: tolerance must be > 0, got {tolerance!r}")
    if not (np.isfinite(margin) and margin > tolerance):
        raise InputError(
            f"{what}: margin must be finite and > tolerance ({tolerance:g}), got {margin!r}"
        )


class PlaneContact:
    """A body's surface points against the fixed plane through ``point`` with unit
    normal along ``normal`` (module docstring).

    Args:
        body: a rigid, full FEM or reduced FEM body (one with ``contact_points``; embedded
            bodies not yet).
        point, normal: a point of the plane and its normal (towards the free side).
        mu: the Coulomb friction coefficient (>= 0; 0: frictionless, no friction rows).
        points: a rigid body's contact points (n, 3) in its body frame about the COM
            (default: its surface's vertices); an FEM or reduced body's input node indices
            (default: every boundary node).
        tolerance: the penetration allowed (m): deeper fails a step, or the start.
        margin: points closer to the plane than this (m) get rows.
        name: used in errors.
        foundation: None (hard normal rows), or an
            :class:`~artifem.multibody.foundation.ElasticFoundation`: compliant normal rows
            (C = t / (K A) per point, A its facing area; penetration allowed up to
            max(tolerance, t)).
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "contacts"

    def __init__(
        self,
        body,
        point,
        normal,
        *,
        mu: float = 0.0,
        points=None,
        tolerance: float = 1e-5,
        margin: float = 1e-2,
        name: str = "",
        foundation=None,
    ):
        self.name = name or f"contact of {getattr(body, 'name', body)!r}"
        what = f"contact {self.name!r}"
        n = np.asarray(normal, dtype=float)
        norm = np.linalg.norm(n) if n.shape == (3,) and np.all(np.isfinite(n)) else 0.0
        if not norm > 0:
            raise InputError(
                f"{what}: the plane normal must be a non-zero finite 3-vector, got {normal!r}"
            )
        p0 = np.asarray(point, dtype=float)
        if p0.shape != (3,) or not np.all(np.isfinite(p0)):
            raise InputError(f"{what}: the plane point must be 3 finite numbers, got {point!r}")
        check_options(what, mu, tolerance, margin)
        if not callable(getattr(body, "contact_points", None)):
            raise InputError(
                f"{what}: {type(body).__name__} {getattr(body, 'name', '')!r} "
                "has no contact points (rigid, full and reduced FEM bodies do)"
            )
        self._points = body.contact_points(points)
        self.body, self._given = body, points
        basis = axis_rotation(n)
        self.normal, self.tangents = basis[:, 2], basis[:, :2].T
        self.offset = float(self.normal @ p0)
        self.mu, self.tolerance, self.margin = float(mu), float(tolerance), float(margin)
        self.foundation = None if foundation is None else foundation.checked(what)
        if self.foundation is not None:  # the points know their areas
            self._points.facing_areas(np.zeros(0, dtype=int), np.zeros((0, 3)))

    @property
    def bodies(self) -> tuple:
        """The scene body the rows act on (an embedded mesh's: its master)."""
        return (self._points.body,)

    def onto_reduced(self, reduced, lift=None) -> PlaneContact:
        """The same contact on the reduced body that replaces this one's (the reductor:
        :mod:`artifem.reduction.reductor`), on the same nodes."""
        return PlaneContact(
            reduced,
            self.offset * self.normal,
            self.normal,
            mu=self.mu,
            points=self._given,
            tolerance=self.tolerance,
            margin=self.margin,
            name=self.name,
            foundation=self.foundation,
        )

    @property
    def labels(self) -> np.ndarray:
        """The contact points, in the order of :meth:`distances`: a rigid body's indices
        into its points, an FEM body's input node indices."""
        return self._points.labels

    def distances(self) -> np.ndarray:
        """phi = n . x_i - d of every contact point (negative: below the plane)."""
        return self._points.positions() @ self.normal - self.offset

    def row_blocks(self) -> list[RowBlock]:
        """One block: the normal rows and, with mu > 0, the friction rows of the points
        within ``margin`` (module docstring); none when no point is that close."""
        phi = self.distances()
        near = np.flatnonzero(phi < self.margin)
        k = near.size
        if not k:
            return []
        directions = np.vstack(
            [np.tile(self.normal, (k, 1))]
            + ([np.repeat(t[None], k, axis=0) for t in self.tangents] if self.mu > 0 else [])
        )
        idx = np.tile(near, len(directions) // k)
        m = len(idx)
        lo = np.zeros(m)
        hi = np.zeros(m)
        hi[:k] = np.inf
        W = sparse.csr_matrix((np.ones(m), (np.arange(m), idx)), shape=(m, len(self._points)))
        G = self._points.rows(W, directions)
        return [
            PlaneContactRows(
                self,
                np.concatenate([phi[near], np.zeros(m - k)]),
                ((self._points.body, G),),
                lo,
                hi,
                lambda lam: self._points.stiffness(W, lam[:, None] * directions),
                Friction.tangents(k, self.mu) if self.mu > 0 else None,
                np.column_stack([idx, np.repeat(np.arange(m // k), k)]),
                points=near,
                compliance=self._compliance(near, m),
            )
        ]

    def _compliance(self, near: np.ndarray, m: int):
        """The normal rows' compliance of the foundation (friction rows hard), or None."""
        if self.foundation is None:
            return None
        areas = self._points.facing_areas(near, np.tile(self.normal, (len(near), 1)))
        return np.concatenate([self.foundation.compliance(areas), np.zeros(m - len(near))])

    @property
    def allowed_depth(self) -> float:
        """The penetration a step may end with: ``tolerance``, or with a foundation
        max(tolerance, its thickness)."""
        return (
            self.tolerance
            if self.foundation is None
            else max(self.tolerance, self.foundation.thickness)
        )

    def hold_pairs(self, hold: bool) -> None:
        """Nothing to hold: every point meets the one plane (the constraint protocol)."""

    def constraint_failure(self) -> str | None:
        """The first point deeper than ``allowed_depth`` below the plane, if any."""
        phi = self.distances()
        deep = np.flatnonzero(phi < -self.allowed_depth)
        if not deep.size:
            return None
        i = int(deep[0])
        return (
            f"contact {self.name!r}: {self._points.describe(i)} of {self.body.name!r} is "
            f"{-phi[i]:.3g} below the plane ({deep.size} points deeper than the tolerance "
            f"{self.allowed_depth:g}, the deepest {-phi.min():.3g}; a point that comes from "
            f"beyond the margin {self.margin:g} within one step has no row: the margin "
            "should be at least the largest approach speed times the step)"
        )

    def forces(self, parts: list, h: float) -> ContactForces:
        """The forces of the impulses ``parts`` [(block, lambda)] of a step of size h."""
        if not parts:
            return ContactForces(np.zeros(0, dtype=int), np.zeros(0), np.zeros((0, 3)))
        ((block, lam),) = parts
        k = len(block.points)
        friction = np.zeros((k, 3))
        if self.mu > 0:
            friction = (
                np.outer(lam[k : 2 * k], self.tangents[0])
                + np.outer(lam[2 * k :], self.tangents[1])
            ) / h
        return ContactForces(self.labels[block.points], lam[:k] / h, friction)

    def normal_forces(self, parts: list, h: float) -> list:
        """[(the body's contact points, the normal force on each (N))] over the last step:
        the point sets a contact pressure is given on
        (:func:`~artifem.multibody.contact_pressure.contact_pressure`)."""
        f = np.zeros(len(self._points))
        for block, lam in parts:
            f[block.points] += lam[: len(block.points)] / h
        return [(self._points, f)]
