"""Springs and muscles routed through frames: force elements of a rigid scene.

A :class:`FramePath` carries a point-path element of
:mod:`artifem.multibody.muscles` (``AxialSpring``, ``ThelenMuscle``) whose
points are the origins of frames on rigid bodies or in the world. At each
step it evaluates the element at the frames' positions and velocities and
hands the scene's step the wrenches G^T f and their stiffness and damping
blocks (:func:`~artifem.multibody.force_elements.point_force_wrenches`), so the
element is implicit in the step.

A muscle's excitation may follow a schedule ``excitation(t)``; its activation
is advanced once per new time t by the step between the previous t and this
one, and an elastic tendon's fiber state is committed when the next step
starts (the previous step was accepted).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from artifem.errors import InputError
from artifem.multibody.rigid_body import Frame
from artifem.multibody.force_elements import point_force_wrenches

__all__ = ["FramePath", "PathElement", "TimedPath"]


class TimedPath:
    """Evaluates a path element at the step's end time t, stepping its time-dependent state.

    On the first evaluation at a new t: the previous result is committed (that
    step was accepted), the excitation is set to ``excitation(t)`` and the
    activation advanced by t - t_previous. Repeated evaluations at the same t
    (force and Jacobians of one step) reuse that state.
    """

    def __init__(self, element, excitation: Callable[[float], float] | None, name: str):
        if excitation is not None and not hasattr(element, "set_excitation"):
            raise InputError(f"path {name!r}: {type(element).__name__} takes no excitation")
        self.element, self.excitation = element, excitation
        self._t = self._dt = self.result = None

    def __call__(self, t: float, positions: np.ndarray, velocities: np.ndarray):
        if self._t is None or t != self._t:
            dt = None if self._t is None else t - self._t
            if self.result is not None:
                self.element.commit(self.result)
            if self.excitation is not None:
                self.element.set_excitation(float(self.excitation(t)))
                if dt is not None and dt > 0 and hasattr(self.element, "update_activation"):
                    self.element.update_activation(dt)
            self._t, self._dt = t, dt
        self.result = self.element.evaluate(positions, velocities, self._dt)
        return self.result

    def tension(self) -> float:
        """The element's tension at the last evaluation (N)."""
        return float(self.result.tension) if self.result is not None else 0.0

    def save_state(self):
        """Everything a step changes: the last time and result, and the element's own
        state (excitation, activation, fiber length: its attributes, copied)."""
        return self._t, self._dt, self.result, dict(vars(self.element))

    def restore_state(self, saved) -> None:
        """Back to a saved state (a rejected step is undone, then retried)."""
        self._t, self._dt, self.result, attributes = saved
        vars(self.element).clear()
        vars(self.element).update(attributes)


class _Constant:
    """e(t) = value."""

    def __init__(self, value: float):
        self.value = value

    def __call__(self, t: float) -> float:
        return self.value


class PathElement:
    """What every path (a spring or muscle through points) shares: its TimedPath
    ``self._timed``, its ``element`` and ``positions()``; tension, energy and the
    time-dependent state a rejected step restores."""

    def tension(self) -> float:
        """The element's tension at the last evaluation (N)."""
        return self._timed.tension()

    def save_state(self):
        """The muscle's time-dependent state (TimedPath.save_state)."""
        return self._timed.save_state()

    def restore_state(self, saved) -> None:
        self._timed.restore_state(saved)

    def set_excitation(self, value: float) -> None:
        """Excite the path's muscle at ``value`` from the next new time on (it replaces the
        schedule ``excitation(t)``; the activation follows as under a schedule): what a
        scene input sets each step (:class:`~artifem.scene.inputs.PathExcitation`)."""
        if not hasattr(self.element, "set_excitation"):
            raise InputError(
                f"path {self.name!r}: {type(self.element).__name__} takes no excitation"
            )
        value = float(value)
        if not np.isfinite(value):
            raise InputError(f"path {self.name!r}: excitation must be finite, got {value!r}")
        self._timed.excitation = _Constant(value)

    @property
    def conservative(self) -> bool:
        """True when the element's ``energy`` is the potential of its tension (springs; a
        rigid-tendon muscle in statics): statics may use it as a merit."""
        return hasattr(self.element, "energy") and getattr(self.element, "conservative", True)

    def potential_energy(self) -> float:
        """The element's stored energy, for elements that have one (:attr:`conservative`)."""
        return float(self.element.energy(self.positions())) if self.conservative else 0.0


class FramePath(PathElement):
    """A spring or muscle through ``frames`` (at least two), a force element of a Scene."""

    def __init__(
        self,
        element,
        frames: Sequence[Frame],
        *,
        excitation: Callable[[float], float] | None = None,
        name: str = "path",
    ):
        if len(frames) < 2:
            raise InputError(
                f"FramePath {name!r}: a path needs at least two frames, got {len(frames)}"
            )
        self.element, self.frames, self.name = element, list(frames), name
        self._timed = TimedPath(element, excitation, f"FramePath {name!r}")

    def positions(self) -> np.ndarray:
        return np.array([f.world_position() for f in self.frames])

    def velocities(self) -> np.ndarray:
        return np.array([f.velocity() for f in self.frames])

    def _evaluate(self, t: float):
        return self._timed(t, self.positions(), self.velocities())

    def wrenches(self, t: float):
        result = self._evaluate(t)
        wrenches, _ = point_force_wrenches(self.frames, result.forces)
        return wrenches

    def jacobians(self, t: float):
        result = self._evaluate(t)
        _, blocks = point_force_wrenches(
            self.frames, result.forces, result.stiffness, result.damping
        )
        return blocks
