"""Scene inputs: named scalars a controller sets before each step, beyond the muscle
excitations of an FEM body: load levels and the excitations of path muscles.

An input is a small frozen dataclass with ``apply(scene, value)``; ``value`` is a level
(dimensionless, as an excitation), the input holds the reference it scales:

- :class:`Gravity`: g = value g_ref (every body of the scene);
- :class:`SurfaceLoadLevel`: the surface load ``load`` of FEM body ``body`` (a pressure p or
  a traction t, :meth:`~artifem.fem_body.FemBody.add_pressure`) set to value x reference;
- :class:`PathExcitation`: the excitation of the path muscle ``path``
  (:meth:`~artifem.multibody.frame_paths.PathElement.set_excitation`).

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

from artifem.errors import InputError, UnknownNameError
from artifem.excitation import ExcitationSchedule

__all__ = ["SceneInput", "Gravity", "SurfaceLoadLevel", "PathExcitation", "controller",
           "describe"]


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
            raise InputError(f"Gravity: reference must be 3 finite numbers, got "
                             f"{self.reference!r}")
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
            raise InputError(f"SurfaceLoadLevel {self.body!r}/{self.load!r}: reference must "
                             f"be a finite number or 3 of them, got {self.reference!r}")
        object.__setattr__(self, "reference", float(ref) if ref.shape == () else
                           tuple(float(x) for x in ref))

    def _load(self, scene):
        bodies = scene.fem_bodies + [b.full for b in scene.reduced_bodies]
        body = next((b for b in bodies if b.name == self.body), None)
        if body is None:
            raise UnknownNameError(f"SurfaceLoadLevel: the scene has no FEM body "
                                   f"{self.body!r}; it has {[b.name for b in bodies]}")
        load = body.surface_loads.get(self.load)
        if load is None:
            raise UnknownNameError(f"SurfaceLoadLevel: FEM body {self.body!r} has no surface "
                                   f"load {self.load!r}; it has {sorted(body.surface_loads)}")
        if (load.kind == "pressure") != (np.ndim(self.reference) == 0):
            size = "1 number" if load.kind == "pressure" else "3 numbers"
            raise InputError(f"SurfaceLoadLevel {self.body!r}/{self.load!r}: a {load.kind} "
                             f"needs a reference of {size}, got {self.reference!r}")
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
        excitable = [p for p in [*scene.paths, *scene.forces]
                     if callable(getattr(p, "set_excitation", None))]
        paths = [p for p in excitable if getattr(p, "name", None) == self.path]
        if len(paths) != 1:
            names = [getattr(p, "name", "") for p in excitable]
            raise UnknownNameError(f"PathExcitation: the scene has {len(paths)} paths named "
                                   f"{self.path!r} (need one); its paths are {names}")
        return paths[0]

    def check(self, scene) -> None:
        self._path(scene)

    def apply(self, scene, value: float) -> None:
        self._path(scene).set_excitation(value)


def describe(inputs: Mapping[str, SceneInput]) -> dict:
    """JSON-able {name: {type, fields}} of scene inputs (part of a cache key)."""
    return {name: {"type": type(i).__name__, **asdict(i)} for name, i in inputs.items()}


def controller(schedule: ExcitationSchedule, inputs: Mapping[str, SceneInput]
               ) -> Callable:
    """A scene controller setting each input of ``schedule`` to its value at the step's end
    time; every name of the schedule must be one of ``inputs``."""
    unknown = sorted(set(schedule.values) - set(inputs))
    if unknown:
        raise UnknownNameError(f"the schedule names unknown scene inputs {unknown}; the "
                               f"inputs are {sorted(inputs)}")

    def apply(scene, t0: float, t1: float) -> None:
        for name, value in schedule.at(t1).items():
            inputs[name].apply(scene, value)
    return apply
