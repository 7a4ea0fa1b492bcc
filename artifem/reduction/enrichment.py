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

Greedy enrichment of the points alone (:func:`greedy_points`), for a fixed basis W and no
full run at all: the points' error indicator on a candidate schedule is the cubature's
relative residual at the states its reduced run visits,

    rho(s) = ||b - G_S w|| / ||b||,   b = sum over every point of W^T f_point(W q_t; a_t),

(G the ECSW training matrix at those states, :func:`~artifem.reduction.training.
force_training_matrix`: one evaluation of every point's force per state, no solve), the
quantity the trained points were fitted to make small on the training states. Each round
adds the visited states of the candidate with the largest rho to the points' training
states and retrains the points (the same count and tolerance), until rho <= tol on every
candidate left, ``max_rounds`` rounds, or the pool is exhausted.
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
from artifem.reduction.reductor import (
    Basis,
    Points,
    ReducedModel,
    ReducibleScene,
    Reductor,
    Training,
)
from artifem.reduction.training import force_training_matrix
from artifem.scene import simulate

__all__ = [
    "GreedyTraining",
    "greedy_training",
    "GreedyPoints",
    "greedy_points",
    "visited_states",
    "cubature_residual",
]


def _finite(value):
    """JSON-able: an infinite value (a failed run's) as None."""
    return value if value is None or np.isfinite(value) else None


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
        history = [
            {
                **entry,
                "max_estimate_mm": _finite(entry["max_estimate_mm"]),
                "estimates_mm": {k: _finite(v) for k, v in entry["estimates_mm"].items()},
            }
            for entry in self.history
        ]
        return {"stopped": self.stopped, "runs": len(self.training.schedules), "history": history}


def _estimates(
    reduced: ReducedModel,
    reference: ReducedModel,
    schedules: Mapping[str, ExcitationSchedule],
    duration: float,
    dt: float,
    progress: bool,
) -> dict[str, float]:
    """max_t e~(t) of each schedule (inf when the reduced run fails: the worst)."""
    out = {}
    for name, schedule in tqdm(
        schedules.items(), desc="estimates", unit="run", disable=not progress, leave=False
    ):
        u, _, failure = reduced_run(reduced, schedule, duration, dt)
        u_ref, _, _ = reduced_run(reference, schedule, duration, dt)
        estimate = node_mean_mm(u, u_ref)
        out[name] = float("inf") if failure is not None else float(np.nanmax(estimate))
    return out


def greedy_training(
    model: ReducibleScene,
    training: Training,
    candidates: Mapping[str, ExcitationSchedule],
    *,
    cache: str | Path,
    basis: Basis = Basis(),
    points: Points = Points(),
    tol: float = 0.0,
    max_runs: int | None = None,
    duration: float | None = None,
    pressure_modes: int = 4,
    progress: bool = True,
) -> GreedyTraining:
    """Greedy training of ``model`` from ``training`` over the pool ``candidates`` (module
    docstring): stop when the largest estimate is at most ``tol`` (mm), the training holds
    ``max_runs`` runs, or no candidate is left. ``duration``: of the candidates' reduced
    runs (default: the training's)."""
    if not candidates:
        raise InputError("greedy_training: give at least one candidate schedule")
    clash = sorted(set(candidates) & set(training.schedules))
    if clash:
        raise InputError(f"greedy_training: candidates {clash} are already training schedules")
    if not (np.isfinite(tol) and tol >= 0):
        raise InputError(f"greedy_training: tol must be >= 0 (mm), got {tol}")
    if max_runs is not None and max_runs < len(training.schedules):
        raise InputError(
            f"greedy_training: max_runs ({max_runs}) is below the first "
            f"training's {len(training.schedules)} runs"
        )
    duration = duration or training.duration
    richer_basis = replace(basis, size=2 * basis.size)
    richer_points = replace(points, count=2 * points.count)
    pool, history = dict(candidates), []
    reductor = Reductor(model, training, cache, pressure_modes=pressure_modes, progress=progress)
    while True:
        reduced = reductor.reduce(basis, points)
        entry = {
            "runs": len(training.schedules),
            "estimates_mm": {},
            "max_estimate_mm": None,
            "added": None,
            "rejected": {},
        }
        if not pool or (max_runs is not None and len(training.schedules) >= max_runs):
            history.append(entry)
            return GreedyTraining(
                training, reduced, "pool" if not pool else "size", history, reductor
            )
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
            candidate = Reductor(
                model, enriched, cache, pressure_modes=pressure_modes, progress=progress
            )
            try:
                candidate.train()  # the candidate's full run, cached
            except SolverError as exc:
                entry["rejected"][name] = str(exc)
                continue
            entry["added"], training, reductor = name, enriched, candidate
            break
        if entry["added"] is None:
            return GreedyTraining(
                training, reduced, "tolerance" if pool else "pool", history, reductor
            )


@dataclass
class GreedyPoints:
    """What :func:`greedy_points` did: the final reduced model, the states added to the
    points' training (q (k, r), excitations (k, muscles)), why it stopped
    (``"tolerance"``, ``"rounds"`` or ``"stalled"``: the last round did not lower the
    largest indicator, is marked ``undone``, and the model is the round's before) and one
    entry per round: the points' count and training residual, each candidate's indicator
    rho and the candidate whose visited states were added (None at the last)."""

    reduced: ReducedModel
    states: tuple[np.ndarray, np.ndarray] | None
    stopped: str
    history: list[dict] = field(default_factory=list)

    def summary(self) -> dict:
        """JSON-able."""
        history = [
            {
                **entry,
                "max_indicator": _finite(entry["max_indicator"]),
                "indicators": {k: _finite(v) for k, v in entry["indicators"].items()},
            }
            for entry in self.history
        ]
        return {
            "stopped": self.stopped,
            "rounds": len(self.history) - 1,
            "extra_states": 0 if self.states is None else int(self.states[0].shape[0]),
            "history": history,
        }


def visited_states(
    reduced: ReducedModel, schedule: ExcitationSchedule, duration: float, dt: float, count: int
) -> tuple[np.ndarray, np.ndarray, str | None]:
    """(q (k, r), the body's muscle excitations there (k, muscles), the failure or None):
    ``count`` states evenly spaced over the reduced run of ``schedule`` (up to a failure)."""
    scene = reduced.scene()
    body = next(b for b in scene.reduced_bodies if b.name == reduced.model.body)
    muscles = list(body.full.muscles.values())
    reduced.model.drive(scene, schedule)
    run = simulate(
        scene,
        duration,
        dt,
        on_failure="stop",
        progress=False,
        record={
            "q": lambda s: body.q.copy(),
            "a": lambda s: np.array([float(m.excitation.value) for m in muscles]),
        },
    )
    q, a = np.asarray(run.records["q"]), np.asarray(run.records["a"]).reshape(-1, len(muscles))
    rows = (
        np.unique(np.linspace(1, len(q) - 1, min(count, len(q) - 1)).round().astype(int))
        if len(q) > 1
        else np.zeros(0, dtype=int)
    )  # none past the initial state
    return q[rows], a[rows], None if run.failure is None else str(run.failure)


def cubature_residual(
    reductor: Reductor, reduced: ReducedModel, q: np.ndarray, a: np.ndarray
) -> float:
    """rho = ||b - G_S w|| / ||b|| of the reduced model's points at the states (q, a)
    (module docstring); inf when there is no state or none has a finite force."""
    if len(q) == 0:
        return float("inf")
    try:
        G, b = force_training_matrix(reductor.body, reduced.basis, q, a, progress=False)
    except InputError:  # every state inverts an element
        return float("inf")
    pts = reduced.points
    norm = float(np.linalg.norm(b))
    return float(np.linalg.norm(b - G[:, pts.indices] @ pts.weights)) / norm if norm > 0 else 0.0


def greedy_points(
    reductor: Reductor,
    candidates: Mapping[str, ExcitationSchedule],
    *,
    basis: Basis = Basis(),
    points: Points = Points(),
    tol: float = 0.0,
    max_rounds: int = 3,
    duration: float | None = None,
    states_per_run: int = 10,
    progress: bool = True,
) -> GreedyPoints:
    """Greedy enrichment of trained points over the pool ``candidates`` (module docstring):
    the basis stays; each round the points are retrained (``points``: their largest count
    and tolerance) on the training states plus the states visited by the worst candidate
    of every round so far. Every candidate is measured every round; a round that does not
    lower the largest indicator is undone and ends the enrichment (``"stalled"``).
    ``duration``: of the candidates' reduced runs (default: the training's)."""
    if not candidates:
        raise InputError("greedy_points: give at least one candidate schedule")
    if points.sampling != "trained":
        raise InputError(
            f"greedy_points: only trained points are enriched, got {points.sampling!r} ones"
        )
    if not (np.isfinite(tol) and tol >= 0):
        raise InputError(f"greedy_points: tol must be >= 0, got {tol}")
    if int(max_rounds) != max_rounds or max_rounds < 0:
        raise InputError(f"greedy_points: max_rounds must be an integer >= 0, got {max_rounds!r}")
    for name, schedule in candidates.items():
        reductor.model.check_schedule(reductor.body, schedule, f"candidate {name!r}")
    duration = duration or reductor.training.duration
    dt = reductor.training.dt
    extra, history, best = None, [], None
    while True:
        reduced = reductor.reduce(basis, points, extra_states=extra)
        entry = {
            "points": int(reduced.points.m),
            "residual": reduced.points.residual,
            "indicators": {},
            "max_indicator": None,
            "added": None,
        }
        visited = {}
        for name, schedule in tqdm(
            candidates.items(),
            desc="points' indicators",
            unit="run",
            disable=not progress,
            leave=False,
        ):
            q, a, _ = visited_states(reduced, schedule, duration, dt, states_per_run)
            visited[name] = (q, a)
            entry["indicators"][name] = cubature_residual(reductor, reduced, q, a)
        worst = max(entry["indicators"], key=entry["indicators"].get)
        entry["max_indicator"] = entry["indicators"][worst]
        history.append(entry)
        if best is not None and entry["max_indicator"] >= best.max_indicator:
            entry["undone"] = True
            return GreedyPoints(best.reduced, best.states, "stalled", history)
        best = _Round(reduced, extra, entry["max_indicator"])
        if entry["max_indicator"] <= tol:
            return GreedyPoints(reduced, extra, "tolerance", history)
        if len(history) > max_rounds:
            return GreedyPoints(reduced, extra, "rounds", history)
        entry["added"] = worst
        q, a = visited[worst]
        extra = (q, a) if extra is None else (np.vstack([extra[0], q]), np.vstack([extra[1], a]))


@dataclass
class _Round:
    """The model of a round of :func:`greedy_points`, its extra states and largest
    indicator."""

    reduced: ReducedModel
    states: tuple[np.ndarray, np.ndarray] | None
    max_indicator: float
