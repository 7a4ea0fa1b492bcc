"""Greedy training: add to the training the inputs the reduced model does worst on, as its
error estimate says, until the estimate meets a tolerance or the training a size.

Given a model, a first training, a pool of candidate schedules (e.g. random multi-exciter
schedules of a seed of their own) and the reduction (basis, points):

    repeat
        reduced   = reduce(model, training, basis, points)
        reference = reduce(model, training, 2 x basis vectors, 2 x points)
        e~(s) = max_t mean over the nodes of |u_reduced(t) - u_reference(t)|, for every
                candidate s not in the training (two reduced runs each, no full run)
        stop when max_s e~(s) <= tol, when the training holds max_runs runs, or when the
             pool is exhausted
        s* = argmax_s e~(s): run the full model on s* (a training run) and add it; a
             candidate whose full run fails (inverted elements) leaves the pool, with
             why, and the next worst is tried

the POD-greedy of Haasdonk & Ohlberger (2008) with the hierarchical estimate of Hain,
Ohlberger, Radic & Urban (2019) (:mod:`artifem.reduction.evaluation`) in place of a
residual bound: the residual-based estimate diverges on this model's strongly excited
states (docs/tongue_study.md). Both the basis and the integration points are retrained from
the enriched training at each iteration. Every stage is cached in the reductor's cache, so
an interrupted greedy training resumes: its full runs are training runs.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from artifem.errors import InputError, SolverError
from artifem.excitation import ExcitationSchedule
from artifem.reduction.evaluation import node_mean_mm, reduced_run
from artifem.reduction.reductor import (Basis, Points, ReducedModel, ReducibleScene, Reductor,
                                        Training)

__all__ = ["GreedyTraining", "greedy_training"]


@dataclass
class GreedyTraining:
    """What :func:`greedy_training` did: the final training and reduced model, why it
    stopped (``"tolerance"``, ``"size"`` or ``"pool"``) and one entry per iteration: the
    runs in the training, each candidate's estimate (mm), the largest, the schedule added
    (None at the last) and the candidates rejected because their full run failed (name ->
    why)."""

    training: Training
    reduced: ReducedModel
    stopped: str
    history: list[dict] = field(default_factory=list)
    #: the reductor of the final training (its stages loaded), for further reductions
    reductor: Reductor | None = None

    def summary(self) -> dict:
        """JSON-able: an estimate whose reduced run failed (inf) is None."""
        def finite(value):
            return value if value is None or np.isfinite(value) else None
        history = [{**entry, "max_estimate_mm": finite(entry["max_estimate_mm"]),
                    "estimates_mm": {k: finite(v) for k, v in entry["estimates_mm"].items()}}
                   for entry in self.history]
        return {"stopped": self.stopped, "runs": len(self.training.schedules),
                "history": history}


def _estimates(reduced: ReducedModel, reference: ReducedModel,
               schedules: Mapping[str, ExcitationSchedule], duration: float, dt: float,
               progress: bool) -> dict[str, float]:
    """max_t e~(t) of each schedule (inf when the reduced run fails: the worst)."""
    out = {}
    for name, schedule in tqdm(schedules.items(), desc="estimates", unit="run",
                               disable=not progress, leave=False):
        u, _, failure = reduced_run(reduced, schedule, duration, dt)
        u_ref, _, _ = reduced_run(reference, schedule, duration, dt)
        estimate = node_mean_mm(u, u_ref)
        out[name] = float("inf") if failure is not None else float(np.nanmax(estimate))
    return out


def greedy_training(model: ReducibleScene, training: Training,
                    candidates: Mapping[str, ExcitationSchedule], *, cache: str | Path,
                    basis: Basis = Basis(), points: Points = Points(), tol: float = 0.0,
                    max_runs: int | None = None, duration: float | None = None,
                    pressure_modes: int = 4, progress: bool = True) -> GreedyTraining:
    """Greedy training of ``model`` from ``training`` over the pool ``candidates`` (module
    docstring): stop when the largest estimate is at most ``tol`` (mm), the training holds
    ``max_runs`` runs, or no candidate is left. ``duration``: of the candidates' reduced
    runs (default: the training's)."""
    if not candidates:
        raise InputError("greedy_training: give at least one candidate schedule")
    clash = sorted(set(candidates) & set(training.schedules))
    if clash:
        raise InputError(f"greedy_training: candidates {clash} are already training "
                         "schedules")
    if not (np.isfinite(tol) and tol >= 0):
        raise InputError(f"greedy_training: tol must be >= 0 (mm), got {tol}")
    if max_runs is not None and max_runs < len(training.schedules):
        raise InputError(f"greedy_training: max_runs ({max_runs}) is below the first "
                         f"training's {len(training.schedules)} runs")
    duration = duration or training.duration
    richer_basis = replace(basis, size=2 * basis.size)
    richer_points = replace(points, count=2 * points.count)
    pool, history = dict(candidates), []
    reductor = Reductor(model, training, cache, pressure_modes=pressure_modes,
                        progress=progress)
    while True:
        reduced = reductor.reduce(basis, points)
        entry = {"runs": len(training.schedules), "estimates_mm": {}, "max_estimate_mm": None,
                 "added": None, "rejected": {}}
        if not pool or (max_runs is not None and len(training.schedules) >= max_runs):
            history.append(entry)
            return GreedyTraining(training, reduced, "pool" if not pool else "size", history,
                                  reductor)
        reference = reductor.reduce(richer_basis, richer_points)
        estimates = _estimates(reduced, reference, pool, duration, training.dt, progress)
        entry.update(estimates_mm=estimates, max_estimate_mm=max(estimates.values()))
        history.append(entry)
        # the worst first; a candidate the full model cannot run (it inverts elements,
        # say) cannot train: it leaves the pool, with why, and the next worst is tried
        for name in sorted(estimates, key=estimates.get, reverse=True):
            if estimates[name] <= tol:
                break
            enriched = replace(training, schedules={**training.schedules, name: pool.pop(name)})
            candidate = Reductor(model, enriched, cache, pressure_modes=pressure_modes,
                                 progress=progress)
            try:
                candidate.train()                  # the candidate's full run, cached
            except SolverError as exc:
                entry["rejected"][name] = str(exc)
                continue
            entry["added"], training, reductor = name, enriched, candidate
            break
        if entry["added"] is None:
            return GreedyTraining(training, reduced, "tolerance" if pool else "pool", history,
                                  reductor)
