"""The registration loop: static solves of a scene under registration forces whose
weight rises on a schedule (Sanchez et al. 2015's continuation: a low weight first, so
that the model's own elasticity and joints keep it whole while it finds the target, then
higher ones to close the distance), stopped when the mean distance stops changing.

Each stage alternates, as ICP does, between finding the closest-point features and a
static solve with them held (Newton on the exact energy itself circles where the
closest points switch features, as they do on noisy data at high weights).
After each stage k (weight w_k) the loop records the mean and largest distance of the
model's vertices to the target (the model-to-target term's |x_i - c_i|, over the pairs
it keeps: not those whose closest point is on a partial target's border); it stops once
the mean changed by less than ``tol`` since the stage before, or after the last weight.
With a ``checkpoint`` file the scene's state and the stages done are written after each
stage, and a later call with the same file resumes after the last stage written.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from artifem.errors import InputError, StepFailed
from artifem.registration.forces import RegistrationForces

__all__ = ["RegistrationResult", "register"]

#: a failed stage is preceded by one at the geometric mean of its weight and the last
#: one, down to weights this close (then the failure is raised)
MIN_WEIGHT_RATIO = 1.05


@dataclass
class RegistrationResult:
    """The stages done: ``weights[k]``, the mean and largest model-to-target distance after
    it (m), the static solves' Newton iterations and the sweeps (solves on held
    features) it took; ``converged`` when the mean changed by
    less than the tolerance."""

    weights: list = field(default_factory=list)
    mean_distance: list = field(default_factory=list)
    max_distance: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    sweeps: list = field(default_factory=list)
    converged: bool = False


def _distances(forces: Sequence[RegistrationForces]) -> np.ndarray:
    return np.concatenate([f.distances() for f in forces])


def _stage(
    scene, forces, w: float, tol: float, rtol: float, max_iterations: int, max_sweeps: int
) -> tuple[float, float, int, int]:
    """One stage at weight w (:func:`register`): (mean distance, largest distance, Newton
    iterations, sweeps)."""
    for f in forces:
        f.weight = w
    iterations, mean = 0, np.inf
    for sweep in range(1, max_sweeps + 1):  # noqa: B007 (returned: the sweeps taken)
        for f in forces:
            f.hold(True)
        try:
            iterations += int(
                sum(scene.solve_static(load_steps=1, rtol=rtol, max_iterations=max_iterations))
            )
        finally:
            for f in forces:
                f.hold(False)
        d = _distances(forces)
        done, mean = abs(float(d.mean()) - mean) < tol, float(d.mean())
        if done:
            break
    return mean, float(d.max()), iterations, sweep


def register(
    scene,
    forces: Sequence[RegistrationForces],
    weights: Sequence[float],
    *,
    tol: float = 1e-5,
    checkpoint: Path | None = None,
    progress=None,
    max_iterations: int = 30,
    max_sweeps: int = 20,
    rtol: float = 1e-6,
) -> RegistrationResult:
    """Register the scene's model surfaces to their targets (module docstring): for each
    weight of ``weights`` (increasing), every element of ``forces`` (already in the
    scene) takes it, and sweeps of ICP's alternation run from the last state: the
    closest-point features are held (:meth:`RegistrationForces.hold`), the scene solved
    statically on them (``scene.solve_static``, one load step to ``rtol``, at most
    ``max_iterations`` Newton iterations: the held energy is smooth, so Newton is
    quadratic), the features found again; until the mean distance changes by less than
    ``tol`` (m) between sweeps, or ``max_sweeps``. The loop stops when a stage changed
    the mean distance by less than ``tol``. A stage whose static solve fails is put back
    and preceded by a stage at the geometric mean of its weight and the last one (the
    continuation refined; ``result.weights`` lists the stages run). ``progress`` (e.g.
    tqdm) is updated once per stage."""
    forces = list(forces)
    weights = [float(w) for w in weights]
    if not forces:
        raise InputError("register: no RegistrationForces given")
    missing = [f.name for f in forces if f not in scene.loads]
    if missing:
        raise InputError(f"register: the registration forces {missing} are not in the scene")
    if (
        not weights
        or any(not (np.isfinite(w) and w > 0) for w in weights)
        or any(b < a for a, b in zip(weights, weights[1:]))
    ):
        raise InputError(f"register: weights must be positive and increasing, got {weights}")
    if not (np.isfinite(tol) and tol > 0):
        raise InputError(f"register: tol must be > 0, got {tol}")
    result = RegistrationResult()
    if checkpoint is not None and Path(checkpoint).exists():
        with open(checkpoint, "rb") as fh:
            saved = pickle.load(fh)
        if saved["schedule"] != weights[: len(saved["schedule"])]:
            raise InputError(
                f"register: the checkpoint {checkpoint} was written for the "
                f"weights {saved['schedule']}, not a start of {weights}"
            )
        scene.restore_state(saved["state"])
        result = saved["result"]
    pending = [w for w in weights if not result.weights or w > result.weights[-1]]
    while pending and not result.converged:
        w = pending[0]
        state = scene.save_state()
        try:
            stage = _stage(scene, forces, w, tol, rtol, max_iterations, max_sweeps)
        except StepFailed as error:
            # continuation: a stage between the last weight and this one first
            scene.restore_state(state)
            last = result.weights[-1] if result.weights else w / 10.0
            if w / last < MIN_WEIGHT_RATIO:
                raise StepFailed(
                    f"registration: the static solve at weight {w:g} failed "
                    f"after the weight {last:g} ({error})"
                ) from error
            pending.insert(0, float(np.sqrt(last * w)))
            continue
        pending.pop(0)
        result.weights.append(w)
        for name, value in zip(("mean_distance", "max_distance", "iterations", "sweeps"), stage):
            getattr(result, name).append(value)
        result.converged = (
            len(result.mean_distance) > 1
            and abs(result.mean_distance[-1] - result.mean_distance[-2]) < tol
        )
        if checkpoint is not None:
            with open(checkpoint, "wb") as fh:
                pickle.dump(
                    {"schedule": weights, "state": scene.save_state(), "result": result}, fh
                )
        if progress is not None:
            progress.update(1)
    return result
