"""Springs and muscles through points on FEM bodies, rigid frames and world points."""

from __future__ import annotations

import numpy as np

from artifem.errors import InputError
from artifem.multibody.attachments import FemPoint
from artifem.multibody.frame_paths import PathElement, TimedPath
from artifem.multibody.rigid_body import Frame


class PointPath(PathElement):
    """A spring or muscle (``AxialSpring``, ``ThelenMuscle``: ``evaluate(x, v, dt)``) through
    ``points``: :class:`FemPoint` objects, rigid-body or world ``Frame`` objects, or fixed
    world points (3 numbers). Add it to a :class:`Scene` (artifem.scene.scene docstring: path
    elements).

    ``excitation(t)``, if given, sets the muscle's excitation at the step's end time; the
    activation advances once per new time (as ``FramePath``).
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "paths"

    def __init__(self, element, points, *, excitation=None, name: str = "path"):
        pts = []
        for p in points:
            if isinstance(p, (FemPoint, Frame)):
                pts.append(p)
            else:
                x = np.asarray(p, dtype=float)
                if x.shape != (3,) or not np.all(np.isfinite(x)):
                    raise InputError(
                        f"PointPath {name!r}: a point is a FemPoint, a Frame or 3 "
                        f"finite numbers (a fixed world point), got {p!r}"
                    )
                pts.append(Frame(None, x))
        if len(pts) < 2:
            raise InputError(
                f"PointPath {name!r}: a path needs at least two points, got {len(pts)}"
            )
        self.element, self.points, self.name = element, pts, name
        self._timed = TimedPath(element, excitation, f"PointPath {name!r}")

    @property
    def bodies(self) -> tuple:
        """The scene bodies its points are on (FEM, reduced or rigid; world points: none)."""
        return tuple(
            p.fem if isinstance(p, FemPoint) else p.body
            for p in self.points
            if isinstance(p, FemPoint) or p.body is not None
        )

    def __repr__(self) -> str:
        return f"PointPath({self.name!r}, {len(self.points)} points)"

    def onto_reduced(self, reduced, lift=None) -> "PointPath":
        """This path for ``reduced``, the reduced body of an FEM body it passes through:
        its points there keep their weights, now with G = sum_j w_j U_j (:class:`FemPoint`).
        The element and its excitation schedule are this path's (a reductor swaps the
        path at rest, before any step). ``lift``: unused, a path carries no nodes."""
        points = [
            FemPoint(reduced, p.weights, name=p.name)
            if isinstance(p, FemPoint) and p.fem is reduced.full
            else p
            for p in self.points
        ]
        if all(a is b for a, b in zip(points, self.points)):
            raise InputError(
                f"PointPath {self.name!r}: no point of it is on "
                f"{reduced.full.name!r}, the body {reduced.name!r} reduces"
            )
        return PointPath(self.element, points, excitation=self._timed.excitation, name=self.name)

    def positions(self) -> np.ndarray:
        return np.array(
            [p.position() if isinstance(p, FemPoint) else p.world_position() for p in self.points]
        )

    def velocities(self) -> np.ndarray:
        return np.array([p.velocity() for p in self.points])

    def evaluate(self, t: float):
        """The element's PathForces at the current positions and velocities, time t."""
        return self._timed(t, self.positions(), self.velocities())

    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.positions(), axis=0), axis=1).sum())
