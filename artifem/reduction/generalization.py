"""How a reduced model does on inputs it was not built from: a train/test split.

    report = generalization_study(Reductor(model, training, cache), out,
                                  basis=Basis("pod", 20), points=Points(300), held_out=5,
                                  seed=1000)

For any :class:`~artifem.reduction.reductor.ReducibleScene`: its reductor builds the reduced
model from its training (and a reference twice as rich, for the estimate), then
:func:`~artifem.reduction.evaluation.compare` runs full and reduced scenes on three sets:

- ``training``: the training schedules themselves (what the model was fitted to), the
  error at the training snapshots (no other full run);
- ``motions``: the model's named motions (for the tongue, the seed paper's three);
- ``held-out``: ``held_out`` random multi-exciter schedules
  (:func:`~artifem.reduction.schedules.random_schedules`) drawn with a ``seed`` that no
  training schedule came from (checked: none equals a training schedule).

With ``sources=True``, where the error of each motion and held-out run comes from: the
full run's best approximation in the reduced basis W (its M-orthogonal projection, which
no reduced model of this basis beats at every instant) and the error of the reduced model
of the same basis with every integration point (the cubature's share is the difference
to the reduced model's error; the rest is the reduced dynamics' own, Galerkin, error).

Written to ``out``: generalization.json (the configuration, the training cost, per run
the maximum and mean error, the estimate, ms per step and its worst step against the
median), generalization.md (a table per set), generalization.png (error over time,
estimate dashed, one panel per set) and generalization_worst.png: the full and the reduced
body at the worst moment of the worst held-out run (else motion), coloured by |u| and by
the reduced model's error |u_r - u|.
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
from dolfinx import fem
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from tqdm import tqdm

from artifem.errors import InputError
from artifem.excitation import ExcitationSchedule
from artifem.reduction.evaluation import Comparison, compare, full_run, node_mean_mm, reduced_run
from artifem.reduction.reduced_body import all_points
from artifem.reduction.training import ArtifactCache
from artifem.render import render_bodies
from artifem.reduction.generalization_report import SETS, write_markdown
from artifem.reduction.reductor import (
    Basis,
    Points,
    ReducedModel,
    ReducibleScene,
    Reductor,
    Training,
)
from artifem.reduction.schedules import random_schedules

__all__ = ["generalization_study", "held_out_schedules", "error_sources"]


def held_out_schedules(
    model: ReducibleScene,
    inputs: list[str],
    training: Training,
    count: int,
    seed: int,
    duration: float,
) -> dict:
    """``count`` random schedules of ``seed`` over ``inputs``; an error if one of them is a
    training schedule (the seed was used for training)."""
    schedules = random_schedules(inputs, count, seed=seed, duration=duration, prefix="held-out")
    for name, s in schedules.items():
        for t_name, t in training.schedules.items():
            if (
                np.array_equal(s.times, t.times)
                and s.values.keys() == t.values.keys()
                and all(np.array_equal(s.values[k], t.values[k]) for k in s.values)
            ):
                raise InputError(
                    f"model {model.name!r}: held-out schedule {name!r} is the "
                    f"training schedule {t_name!r}; draw the held-out set with a "
                    "seed the training did not use"
                )
    return schedules


def _plot(results: dict[str, list[Comparison]], png: Path) -> Path:
    sets = [s for s in SETS if results.get(s)]
    fig = Figure(figsize=(4.2 * len(sets), 3.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(sets), sharey=True, squeeze=False)[0]
    for ax, name in zip(axes, sets):
        for k, c in enumerate(results[name]):
            color = f"C{k % 10}"
            ax.plot(c.times, c.error_mm, color=color, lw=1.2, label=c.name)
            if np.any(np.isfinite(c.estimate_mm)):
                ax.plot(c.times, c.estimate_mm, color=color, lw=1.0, ls="--")
        ax.set_title(f"{name} ({len(results[name])} runs)")
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("mean node error (mm); estimate dashed")
    fig.savefig(png, dpi=110)
    return png


def generalization_study(
    reductor: Reductor,
    out: str | Path,
    *,
    basis: Basis = Basis(),
    points: Points = Points(),
    reference: tuple[Basis, Points] | None = None,
    held_out: int = 5,
    seed: int = 1000,
    duration: float = 1.0,
    dt: float | None = None,
    sets=SETS,
    extra_states: tuple[np.ndarray, np.ndarray] | None = None,
    sources: bool = False,
    progress: bool = True,
) -> dict:
    """The train/test study of the module docstring on ``reductor``'s model and training
    (its cache holds every stage and full run); returns generalization.json's content.

    ``reference``: the richer model of the estimate (default: twice the basis size and the
    points, a tenth of the cubature tolerance). ``sets``: which of the three sets to run.
    ``extra_states``: more training states of the reduced model's points (those of a
    greedy enrichment, :func:`~artifem.reduction.enrichment.greedy_points`). ``sources``:
    also where the error comes from (module docstring; a reduced run with every point per
    schedule, O(n) per step).
    """
    out = Path(out)
    unknown = set(sets) - set(SETS)
    if unknown:
        raise InputError(f"generalization_study: unknown sets {sorted(unknown)}; use {SETS}")
    model, training = reductor.model, reductor.training
    dt = dt or training.dt
    inputs = sorted(model.input_names(reductor.body))
    schedules = {
        "training": dict(training.schedules),
        "motions": dict(model.motions),
        "held-out": held_out_schedules(model, inputs, training, held_out, seed, duration)
        if held_out
        else {},
    }
    out.mkdir(parents=True, exist_ok=True)
    reduced: ReducedModel = reductor.reduce(basis, points, extra_states=extra_states)
    reference = reference or (
        Basis(basis.kind, 2 * basis.size),
        Points(
            2 * points.count,
            points.sampling,
            points.tol / 10,
            points.growth,
            points.training_states,
            points.seed,
        ),
    )
    richer = reductor.reduce(*reference)
    known = (
        {name: reductor.training_run(name) for name in training.schedules}
        if "training" in sets
        else {}
    )
    results = {}
    for name in sets:
        if not schedules[name]:
            continue
        trained = name == "training"  # the training's own steps: its snapshots
        results[name] = compare(
            reduced,
            schedules[name],
            duration=training.duration if trained else duration,
            dt=training.dt if trained else dt,
            cache=reductor.cache.root,
            reference=richer,
            known=known if trained else None,
            progress=progress,
        )
    figures = {
        "model": model.name,
        "dt": dt,
        "duration": duration,
        "training_duration": training.duration,
        "held_out_seed": seed,
        "reduced": reduced.training,
        "reference": richer.training,
        "specification": {"basis": asdict(basis), "points": asdict(points)},
        "sets": {name: [c.summary() for c in runs] for name, runs in results.items()},
    }
    if sources:
        for name, runs in figures["sets"].items():
            if name != "training":
                found = error_sources(
                    reductor, reduced, schedules[name], duration, dt, progress=progress
                )
                for run in runs:
                    run.update(found[run["name"]])
    (out / "generalization.json").write_text(json.dumps(figures, indent=1))
    (out / "generalization.md").write_text(write_markdown(figures))
    np.savez(
        out / "generalization_series.npz",
        **{
            f"{name}/{c.name}/{kind}": getattr(c, kind)
            for name, runs in results.items()
            for c in runs
            for kind in ("times", "error_mm", "estimate_mm")
        },
    )
    _plot(results, out / "generalization.png")
    worst = _render_worst(
        reduced, results, schedules, duration, dt, reductor.cache, out / "generalization_worst.png"
    )
    if worst:
        figures["worst"] = worst
        (out / "generalization.json").write_text(json.dumps(figures, indent=1))
        (out / "generalization.md").write_text(write_markdown(figures))
    return figures


def error_sources(
    reductor: Reductor,
    reduced: ReducedModel,
    schedules: dict[str, ExcitationSchedule],
    duration: float,
    dt: float,
    *,
    progress: bool = True,
) -> dict[str, dict]:
    """Per schedule, max over time of the mean node distance to the full run (mm) of the
    full run's M-orthogonal projection on span W, W (W^T M W)^-1 W^T M u (the best
    approximation in the basis), and of the reduced model of W with every integration
    point: {"projection_mm", "every_point_mm"}. The full runs come from the cache."""
    W, mass = reduced.basis, reductor.mass
    MW = np.column_stack([mass(w) for w in W.T]) if callable(mass) else mass[:, None] * W
    gram = W.T @ MW
    # every point at weight 1 (a hard body's constraint on them too: its default weights)
    everything = replace(reduced, points=all_points(reductor.body), pressure_weights=None)
    out = {}
    for name, schedule in tqdm(
        schedules.items(), desc="error sources", unit="run", disable=not progress, leave=False
    ):
        u = full_run(reduced.model, schedule, duration, dt, reductor.cache, progress=False)["u"]
        finite = np.all(np.isfinite(u), axis=1)
        best = np.full_like(u, np.nan)
        best[finite] = np.linalg.solve(gram, (u[finite] @ MW).T).T @ W.T
        u_all = reduced_run(everything, schedule, duration, dt)[0]
        out[name] = {
            "projection_mm": float(np.nanmax(node_mean_mm(best, u))),
            "every_point_mm": float(np.nanmax(node_mean_mm(u_all, u))),
        }
    return out


def _render_worst(
    reduced: ReducedModel,
    results: dict[str, list[Comparison]],
    schedules: dict,
    duration: float,
    dt: float,
    cache: ArtifactCache,
    png: Path,
) -> dict | None:
    """Render the full and the reduced body at the largest error of the held-out runs (else
    of the motions); the full run comes from the cache. Returns what it drew, or None."""
    for name in ("held-out", "motions"):
        runs = [c for c in results.get(name, []) if np.any(np.isfinite(c.error_mm))]
        if runs:
            break
    else:
        return None
    run = max(runs, key=lambda c: np.nanmax(c.error_mm))
    k = int(np.nanargmax(run.error_mm))
    schedule = schedules[name][run.name]
    u_full = full_run(reduced.model, schedule, duration, dt, cache, progress=False)["u"][k]
    u_red = reduced_run(reduced, schedule, duration, dt)[0][k]
    body = reduced.model.fem_body(reduced.model.build())
    fields = []
    for u in (u_full, u_red):
        f = fem.Function(body.V)
        f.x.array[: u.size] = u
        fields.append(f)
    error = 1e3 * np.linalg.norm((u_red - u_full).reshape(-1, 3), axis=1)
    render_bodies(
        png,
        [(body.mesh, f) for f in fields],
        scalars=[1e3 * np.linalg.norm(u_full.reshape(-1, 3), axis=1), error],
        titles=[
            f"full, {run.name}, t = {run.times[k]:.2f} s: displacement (mm)",
            "reduced: error (mm)",
        ],
        scalar_name="mm",
        window_size=(1400, 600),
    )
    return {
        "set": name,
        "run": run.name,
        "time": float(run.times[k]),
        "mean_error_mm": float(run.error_mm[k]),
        "max_node_error_mm": float(error.max()),
        "png": png.name,
    }
