"""Scene inputs: named scalars a controller sets before each step, beyond the muscle
excitations of an FEM body: load levels and the excitations of path muscles.

An input is a small frozen dataclass with ``apply(scene, value)``; ``value`` is a level
(dimensionless, as an excitation), the input holds the reference it scales:

- :class:`Gravity`: g = value g_ref (every body of the scene);
- :class:`SurfaceLoadLevel`: the surface load ``load`` of FEM body ``body`` (a pressure p or
  a traction t, :meth:`~artifem.fem_body.FemBody.add_pressure`) set to value x reference;
- :class:`PathExcitation`: the excitation of the path muscle ``path``
  (:meth:`~artifem.multibody.frame_paths.PathElement.set_excitation`);
- :class:`LoadLevel`: the ``level`` of the load element named ``load`` (a load element
  that scales its forces by a level it holds, e.g. a body weight's share);
- :class:`PrescribedMotion`: a prescribed (kinematic) rigid body moved by value x a
  reference rigid displacement (attachment motion: the nodes it carries follow it).

Inputs find what they set by name, so the same input drives a freshly built scene and the
same scene with a reduced body in place of a full one (the reduced body reads its full
body's loads; a reductor keeps the names of the paths it carries over). :func:`controller`
turns an :class:`~artifem.excitation.ExcitationSchedule` over input names into a scene
controller; a reductor uses it to train on load cases (``ReducibleScene.loads``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from artifem.errors import InputError, UnknownNameError
from artifem.excitation import ExcitationSchedule
from artifem.multibody.rigid_body import BodyState, exp_so3

__all__ = [
    "SceneInput",
    "Gravity",
    "SurfaceLoadLevel",
    "PathExcitation",
    "LoadLevel",
    "PrescribedMotion",
    "controller",
    "describe",
]


class SceneInput(Protocol):
    """What every input offers (a frozen dataclass: its fields describe it in cache keys)."""

    def check(self, scene) -> None:
        """A clear error when ``scene`` lacks what the input sets."""

    def apply(self, scene, value: float) -> None:
        """Set the input's level to ``value`` (from the next step on)."""


@dataclass(frozen=True)
class Gravity:
    """g = value * ``reference`` (m/s^2, world), on every body of the scene."""

    reference: tuple[float, float, float] = (0.0, 0.0, -9.81)

    def __post_init__(self):
        g = np.asarray(self.reference, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise InputError(f"Gravity: reference must be 3 finite numbers, got {self.reference!r}")
        object.__setattr__(self, "reference", tuple(float(x) for x in g))

    def check(self, scene) -> None:
        """Nothing to find."""

    def apply(self, scene, value: float) -> None:
        scene.gravity = float(value) * np.asarray(self.reference)


@dataclass(frozen=True)
class SurfaceLoadLevel:
    """The surface load ``load`` of FEM body ``body`` set to value * ``reference`` (Pa: a
    pressure, or 3 numbers, a traction)."""

    body: str
    load: str
    reference: float | tuple[float, float, float]

    def __post_init__(self):
        ref = np.asarray(self.reference, dtype=float)
        if ref.shape not in ((), (3,)) or not np.all(np.isfinite(ref)):
            raise InputError(
                f"SurfaceLoadLevel {self.body!r}/{self.load!r}: reference must "
                f"be a finite number or 3 of them, got {self.reference!r}"
            )
        object.__setattr__(
            self, "reference", float(ref) if ref.shape == () else tuple(float(x) for x in ref)
        )

    def _load(self, scene):
        bodies = scene.fem_bodies + [b.full for b in scene.reduced_bodies]
        body = next((b for b in bodies if b.name == self.body), None)
        if body is None:
            raise UnknownNameError(
                f"SurfaceLoadLevel: the scene has no FEM body "
                f"{self.body!r}; it has {[b.name for b in bodies]}"
            )
        load = body.surface_loads.get(self.load)
        if load is None:
            raise UnknownNameError(
                f"SurfaceLoadLevel: FEM body {self.body!r} has no surface "
                f"load {self.load!r}; it has {sorted(body.surface_loads)}"
            )
        if (load.kind == "pressure") != (np.ndim(self.reference) == 0):
            size = "1 number" if load.kind == "pressure" else "3 numbers"
            raise InputError(
                f"SurfaceLoadLevel {self.body!r}/{self.load!r}: a {load.kind} "
                f"needs a reference of {size}, got {self.reference!r}"
            )
        return load

    def check(self, scene) -> None:
        self._load(scene)

    def apply(self, scene, value: float) -> None:
        self._load(scene).set(float(value) * np.asarray(self.reference))


@dataclass(frozen=True)
class PathExcitation:
    """The excitation of the path muscle named ``path`` (a point or frame path)."""

    path: str

    def _path(self, scene):
        excitable = [
            p for p in [*scene.paths, *scene.forces] if callable(getattr(p, "set_excitation", None))
        ]
        paths = [p for p in excitable if getattr(p, "name", None) == self.path]
        if len(paths) != 1:
            names = [getattr(p, "name", "") for p in excitable]
            raise UnknownNameError(
                f"PathExcitation: the scene has {len(paths)} paths named "
                f"{self.path!r} (need one); its paths are {names}"
            )
        return paths[0]

    def check(self, scene) -> None:
        self._path(scene)

    def apply(self, scene, value: float) -> None:
        self._path(scene).set_excitation(value)


@dataclass(frozen=True)
class LoadLevel:
    """The ``level`` of the load element named ``load`` (its forces scale with it)."""

    load: str

    def _load(self, scene):
        found = [
            e for e in scene.loads if getattr(e, "name", None) == self.load and hasattr(e, "level")
        ]
        if len(found) != 1:
            names = [getattr(e, "name", "") for e in scene.loads if hasattr(e, "level")]
            raise UnknownNameError(
                f"LoadLevel: the scene has {len(found)} load elements "
                f"with a level named {self.load!r} (need one); those "
                f"it has are {names}"
            )
        return found[0]

    def check(self, scene) -> None:
        self._load(scene)

    def apply(self, scene, value: float) -> None:
        self._load(scene).level = float(value)


@dataclass(frozen=True)
class PrescribedMotion:
    """The prescribed rigid body ``body`` moved by value x a reference rigid displacement
    from where its own trajectory (p_b, R_b) puts it: turned by ``rotation`` (a rotation
    vector theta, rad) about the world point ``pivot``, then translated by ``translation``
    (m):

        Q = exp(value [theta]x),   p = c + Q (p_b - c) + value d,   R = Q R_b.

    Like every input the level holds from the end of the step on: over the step from t0
    (when it is set) the body moves at the secant velocity from its pose (p0, R0) then,
    v = (p - p0) / (t - t0), w = log(R R0^T) / (t - t0), which is what the scene's known
    velocities of the nodes it carries are (the secant of their exact motion)."""

    body: str
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pivot: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        for name in ("translation", "rotation", "pivot"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise InputError(
                    f"PrescribedMotion {self.body!r}: {name} must be 3 finite "
                    f"numbers, got {getattr(self, name)!r}"
                )
            object.__setattr__(self, name, tuple(float(x) for x in value))

    def _body(self, scene):
        body = next((b for b in scene.rigid_bodies if b.name == self.body), None)
        if body is None:
            raise UnknownNameError(
                f"PrescribedMotion: the scene has no rigid body "
                f"{self.body!r}; it has "
                f"{[b.name for b in scene.rigid_bodies]}"
            )
        if body.motion != "prescribed":
            raise InputError(
                f"PrescribedMotion: rigid body {self.body!r} is {body.motion}; "
                "an input can only move a prescribed body (motion='prescribed' "
                "with its own trajectory, e.g. at rest)"
            )
        return body

    def check(self, scene) -> None:
        self._body(scene)

    def apply(self, scene, value: float) -> None:
        body = self._body(scene)
        base = getattr(body.trajectory, "base", body.trajectory)
        body.trajectory = _Displaced(
            base, self, float(value), float(scene.t), body.position.copy(), body.rotation.copy()
        )

    def pose(self, base: BodyState, value: float) -> tuple[np.ndarray, np.ndarray]:
        """(p, R) at level ``value`` of the base pose (class docstring)."""
        Q = exp_so3(value * np.asarray(self.rotation))
        c = np.asarray(self.pivot)
        return c + Q @ (base.position - c) + value * np.asarray(self.translation), Q @ base.rotation


@dataclass(frozen=True)
class _Displaced:
    """The trajectory a :class:`PrescribedMotion` gives its body from t0 on: its pose at the
    level, reached at the secant velocity from (p0, R0) (the body's own trajectory is
    ``base``, kept for the next level)."""

    base: Callable
    motion: PrescribedMotion
    level: float
    t0: float
    p0: np.ndarray
    R0: np.ndarray

    def __call__(self, t: float) -> BodyState:
        if t <= self.t0:
            return BodyState(self.p0, self.R0, np.zeros(3), np.zeros(3))
        p, R = self.motion.pose(BodyState(*self.base(t)), self.level)
        dt = t - self.t0
        turn = Rotation.from_matrix(R @ self.R0.T).as_rotvec()
        return BodyState(p, R, (p - self.p0) / dt, turn / dt)


def describe(inputs: Mapping[str, SceneInput]) -> dict:
    """JSON-able {name: {type, fields}} of scene inputs (part of a cache key)."""
    return {name: {"type": type(i).__name__, **asdict(i)} for name, i in inputs.items()}


def controller(schedule: ExcitationSchedule, inputs: Mapping[str, SceneInput]) -> Callable:
    """A scene controller setting each input of ``schedule`` to its value at the step's end
    time; every name of the schedule must be one of ``inputs``."""
    unknown = sorted(set(schedule.values) - set(inputs))
    if unknown:
        raise UnknownNameError(
            f"the schedule names unknown scene inputs {unknown}; the inputs are {sorted(inputs)}"
        )

    def apply(scene, t0: float, t1: float) -> None:
        for name, value in schedule.at(t1).items():
            inputs[name].apply(scene, value)

    return apply
