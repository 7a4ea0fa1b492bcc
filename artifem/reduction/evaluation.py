"""A reduced model against its full model on given input schedules.

For each schedule: the full scene's run (cached in the reductor's cache, keyed by the model
and the schedule), the reduced scene's run (timed per step, BLAS on one thread: r x r
algebra), and at every step the error

    e(t) = mean over the body's nodes of |u_reduced(t) - u_full(t)|      (mm).

With a ``reference`` reduced model (a richer one: more vectors, more points), the estimate

    e~(t) = mean over the nodes of |u_reduced(t) - u_reference(t)|,

a hierarchical error estimate (Hain, Ohlberger, Radic & Urban 2019): it needs no full run,
only the reference's reduced run, and is close to e(t) when the reference's own error is
small against the reduced model's. A run that fails (the reduced step, or the full model's,
cannot be completed) ends there and says why; the error is known up to the first failure.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from artifem.errors import InputError
from artifem.excitation import ExcitationSchedule
from artifem.reduction.reductor import ReducedModel, ReducibleScene
from artifem.reduction.training import ArtifactCache
from artifem.scene import simulate

__all__ = ["Comparison", "full_run", "reduced_run", "node_mean_mm", "compare"]


@dataclass
class Comparison:
    """One schedule: times (steps + 1), the error e(t) and the estimate e~(t) (mm, NaN after
    a failure, without a reference, or between training snapshots), ms per step of the full
    (NaN when its run was the training's) and the reduced runs."""

    name: str
    times: np.ndarray
    error_mm: np.ndarray
    estimate_mm: np.ndarray
    full_ms: np.ndarray
    reduced_ms: np.ndarray
    failure: str | None = None
    #: why the full model stopped early: the error is known up to there only
    full_failure: str | None = None

    def summary(self) -> dict:
        """The figures of the run (JSON-able)."""
        ms = float(np.median(self.reduced_ms)) if self.reduced_ms.size else float("nan")
        full = float(np.median(self.full_ms)) if np.all(np.isfinite(self.full_ms)) else None
        worst = float(np.nanmax(self.error_mm))
        seen = np.isfinite(self.error_mm)  # the estimate where the error is known
        estimate = (
            float(np.nanmax(self.estimate_mm[seen]))
            if np.any(np.isfinite(self.estimate_mm[seen]))
            else float("nan")
        )
        return {
            "name": self.name,
            "max_error_mm": worst,
            "mean_error_mm": float(np.nanmean(self.error_mm)),
            "max_estimate_mm": estimate,
            "estimate_ratio": estimate / worst if worst > 0 else float("nan"),
            "reduced_ms_per_step": ms,
            "full_ms_per_step": full,
            "speedup": None if full is None else full / ms,
            # the first step also sets the scene up (layout, first evaluation)
            "first_step_ms": float(self.reduced_ms[0]) if self.reduced_ms.size else float("nan"),
            "max_step_over_median": float(self.reduced_ms[1:].max() / ms)
            if self.reduced_ms.size > 1
            else float("nan"),
            "failed": self.failure is not None,
            **({"error": self.failure} if self.failure else {}),
            "full_failed": self.full_failure is not None,
            **({"full_error": self.full_failure} if self.full_failure else {}),
        }


def _schedule_key(schedule: ExcitationSchedule) -> dict:
    return {"times": schedule.times, "values": schedule.values}


def full_run(
    model: ReducibleScene,
    schedule: ExcitationSchedule,
    duration: float,
    dt: float,
    cache: ArtifactCache,
    *,
    label: str = "full",
    progress: bool = True,
) -> dict:
    """The body's displacements (steps + 1, ndofs; NaN after a failure) and step times of the
    full scene driven by ``schedule``, and ``failure``: why the full model stopped early
    (e.g. inverted elements under a strong schedule), else empty. Cached."""
    key = cache.key(
        "full-run", **model.identity(), duration=duration, dt=dt, **_schedule_key(schedule)
    )

    def compute():
        scene = model.build()
        body = model.fem_body(scene)
        model.drive(scene, schedule)
        n = 3 * body.V.dofmap.index_map.size_local
        run = simulate(
            scene,
            duration,
            dt,
            record={"u": lambda s: body.u.x.array[:n].copy()},
            on_failure="stop",
            progress=progress,
            label=label,
            leave=False,
        )
        u = np.full((int(round(duration / dt)) + 1, n), np.nan)
        u[: len(run.records["u"])] = run.records["u"]
        return {
            "u": u,
            "ms": run.step_ms,
            "failure": np.array("" if run.failure is None else str(run.failure)),
        }

    return cache.get(key, compute)


def reduced_run(
    reduced: ReducedModel, schedule: ExcitationSchedule, duration: float, dt: float
) -> tuple[np.ndarray, np.ndarray, str | None]:
    """(displacements (steps + 1, ndofs), NaN after a failure; ms per step; the failure)."""
    scene = reduced.scene()
    body = next(b for b in scene.reduced_bodies if b.name == reduced.model.body)
    reduced.model.drive(scene, schedule)
    run = simulate(  # on one BLAS thread (artifem.scene.run)
        scene,
        duration,
        dt,
        record={"q": lambda s: body.q.copy()},
        on_failure="stop",
        progress=False,
    )
    steps = int(round(duration / dt))
    q = np.full((steps + 1, body.r), np.nan)
    q[: len(run.records["q"])] = run.records["q"]
    return q @ body.U.T + body.u_bar, run.step_ms, None if run.failure is None else str(run.failure)


def node_mean_mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per row (time): the mean over the nodes of |a - b|, in mm (a, b: (steps, 3 n), m)."""
    return 1e3 * np.linalg.norm((a - b).reshape(a.shape[0], -1, 3), axis=2).mean(axis=1)


def compare(
    reduced: ReducedModel,
    schedules: dict[str, ExcitationSchedule],
    *,
    duration: float,
    dt: float,
    cache: str | Path,
    reference: ReducedModel | None = None,
    known: dict | None = None,
    progress: bool = True,
) -> list[Comparison]:
    """Full against reduced runs of ``schedules`` (module docstring). ``known``: name ->
    (steps, displacements) of full runs already at hand (the training snapshots): the
    error is then taken at those steps only, NaN at the others, and no full run is made."""
    if not schedules:
        raise InputError("compare: give at least one schedule")
    if reference is not None and reference.model.identity() != reduced.model.identity():
        raise InputError("compare: the reference is a reduced model of another model")
    store = ArtifactCache(cache)
    out = []
    for name, schedule in tqdm(
        schedules.items(),
        desc=f"{reduced.model.name}: full vs reduced",
        unit="run",
        disable=not progress,
    ):
        u, ms, failure = reduced_run(reduced, schedule, duration, dt)
        error = np.full(u.shape[0], np.nan)
        if known is not None and name in known:
            steps, u_full = known[name]
            keep = steps < u.shape[0]
            error[steps[keep]] = node_mean_mm(u[steps[keep]], u_full[keep])
            full_ms, full_failure = np.full(1, np.nan), None
        else:
            full = full_run(
                reduced.model,
                schedule,
                duration,
                dt,
                store,
                label=f"full {name}",
                progress=progress,
            )
            error = node_mean_mm(u, full["u"])
            full_ms = np.asarray(full["ms"])
            full_failure = str(full["failure"]) or None
        estimate = np.full(u.shape[0], np.nan)
        if reference is not None:
            estimate = node_mean_mm(u, reduced_run(reference, schedule, duration, dt)[0])
        out.append(
            Comparison(
                name,
                np.arange(u.shape[0]) * dt,
                error,
                estimate,
                full_ms,
                ms,
                failure,
                full_failure,
            )
        )
    return out
