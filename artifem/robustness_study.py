"""How often a model runs: random valid excitation schedules of the hard kinds, the full model
with its default settings, what finished and at what cost.

    artifem study robustness MODEL --out DIR [--schedules 20] [--seed 0] [--duration 1.0]
                             [--dt 0.01]

MODEL is ``tongue`` (level 0), ``tongue-level1``, ``tongue-penalty`` (level 0 with the element
penalty instead of the hard incompressibility), ``jaw-tongue``, or ``MODULE:FUNCTION``
returning a :class:`~artifem.reduction.reductor.ReducibleScene` (as for ``artifem study
scene``). Every schedule drives the model's exciters with values in [0, 1], so every one is
a valid input; the kinds (:data:`KINDS`, taken in turn) are the ones that break steppers:

- ``smooth``: 2-4 exciters, random levels at knots every 0.1 s, linear in between;
- ``coactivation``: two exciters (antagonists or not) to 1.0 within 20-100 ms, held;
- ``pulses``: 1-3 exciters switched between 0 and a level in [0.5, 0.8] every 50-100 ms
  (each switch within 1 ms);
- ``all``: every exciter to one level in [0.3, 1.0], stepped (1 ms) or ramped over 0.2 s;
- ``release``: 2-4 exciters ramped to [0.5, 1.0] over 0.1-0.3 s, held, then dropped to 0
  within 1 ms at a time in [0.3, 0.6] s.

Each run starts from the model at rest and reports whether it finished (or the error that
stopped it), min det F, the largest volume change |V / V0 - 1| of the model's FEM body, the
step halvings and the steps the semi-implicit integrator failed and its implicit fallback
completed (``Scene.fallback``), and its cost: its mean wall time per step over the median
of every step that neither fell back nor was halved in the whole study (the semi-implicit
step), measured in one process. DIR/robustness.json holds the figures, DIR/robustness.md the
table, DIR/robustness.png the cost and min det F of each schedule.
"""

from __future__ import annotations

import argparse
import importlib
import json
import time
from pathlib import Path

import numpy as np

from artifem.arguments import positive_float, positive_int
from artifem.errors import InputError
from artifem.excitation import ExcitationSchedule
from artifem.reduction.reductor import ReducibleScene
from artifem.scene import simulate
from artifem.scene_study import load_model

__all__ = [
    "KINDS",
    "MODELS",
    "hard_schedules",
    "robustness_study",
    "write_report",
    "add_arguments",
    "run",
]

KINDS = ("smooth", "coactivation", "pulses", "all", "release")
#: MODEL names of the command line: (MODULE:FUNCTION, its keyword arguments)
MODELS = {
    "tongue": ("artifem.models.tongue.study:reducible_at", {"level": 0}),
    "tongue-level1": ("artifem.models.tongue.study:reducible_at", {"level": 1}),
    "tongue-penalty": (
        "artifem.models.tongue.study:reducible_at",
        {"level": 0, "incompressibility": "penalty"},
    ),
    "jaw-tongue": ("artifem.models.jaw_tongue.reduced:reducible", {}),
}
#: s, how fast a stepped excitation switches (a schedule is piecewise linear)
SWITCH = 1e-3


def _schedule(duration: float, curves: dict[str, list[tuple[float, float]]]) -> ExcitationSchedule:
    """Piecewise-linear curves [(t, a), ...] on one increasing set of knots in [0, duration]
    (each curve interpolated there, held after its last knot)."""
    knots = np.unique(
        np.concatenate(
            [[0.0, duration]] + [[t for t, _ in c if 0 <= t <= duration] for c in curves.values()]
        )
    )
    values = {}
    for name, curve in curves.items():
        t, a = np.array(curve, dtype=float).T
        values[name] = np.clip(np.interp(knots, t, a), 0.0, 1.0)
    return ExcitationSchedule(knots, values)


def hard_schedules(
    exciters, count: int, *, seed: int, duration: float
) -> dict[str, tuple[str, ExcitationSchedule]]:
    """``count`` schedules over ``exciters`` (module docstring), the kinds in turn, named
    ``{kind}-{seed}-{i}``: name -> (kind, schedule). The same arguments give the same
    schedules."""
    exciters = list(exciters)
    if not exciters or len(set(exciters)) != len(exciters):
        raise InputError(f"hard_schedules: exciters must be distinct names, got {exciters}")
    if int(count) != count or count < 1:
        raise InputError(f"hard_schedules: count must be a positive integer, got {count!r}")
    if not (np.isfinite(duration) and duration > 0):
        raise InputError(f"hard_schedules: duration must be positive, got {duration!r}")
    rng = np.random.default_rng(seed)
    T = float(duration)

    def some(low: int, high: int) -> list[str]:
        k = int(rng.integers(min(low, len(exciters)), min(high, len(exciters)) + 1))
        return [exciters[i] for i in sorted(rng.choice(len(exciters), size=k, replace=False))]

    out = {}
    for i in range(int(count)):
        kind = KINDS[i % len(KINDS)]
        if kind == "smooth":
            knots = np.arange(0.0, T + 0.1, 0.1)
            curves = {
                e: list(zip(knots, rng.uniform(0.0, 1.0, knots.size) * (knots > 0)))
                for e in some(2, 4)
            }
        elif kind == "coactivation":
            rise = rng.uniform(0.02, 0.1)
            curves = {e: [(0.0, 0.0), (rise, 1.0)] for e in some(2, 2)}
        elif kind == "pulses":
            period, level = rng.uniform(0.05, 0.1), rng.uniform(0.5, 0.8)
            starts = np.arange(0.0, T, period)
            curves = {}
            for e in some(1, 3):
                curve = [(0.0, 0.0)]
                for k, t0 in enumerate(starts):
                    on = level if k % 2 == 0 else 0.0
                    curve += [(t0 + SWITCH, on), (t0 + period, on)]
                curves[e] = curve
        elif kind == "all":
            level = rng.uniform(0.3, 1.0)
            rise = SWITCH if rng.uniform() < 0.5 else 0.2
            curves = {e: [(0.0, 0.0), (rise, level)] for e in exciters}
        else:  # release
            off = rng.uniform(0.3, 0.6) * T
            curves = {}
            for e in some(2, 4):
                rise = rng.uniform(0.1, 0.3) * T
                level = rng.uniform(0.5, 1.0)
                curves[e] = [
                    (0.0, 0.0),
                    (min(rise, off - SWITCH), level),
                    (off, level),
                    (off + SWITCH, 0.0),
                ]
        out[f"{kind}-{seed}-{i}"] = (kind, _schedule(T, curves))
    return out


def _run(
    model: ReducibleScene, scene, rest, schedule: ExcitationSchedule, duration: float, dt: float
) -> dict:
    """One schedule from the model at rest (``rest``: the scene's saved state), every input
    the schedule leaves out held at 0: the excitations are inputs, not state, and the last
    run's would otherwise stay on."""
    body = model.fem_body_or_full(scene)
    scene.restore_state(rest)
    scene.controllers.clear()
    schedule = ExcitationSchedule(
        schedule.times,
        {
            name: schedule.values.get(name, np.zeros_like(schedule.times))
            for name in model.input_names(body)
        },
    )
    scene.halvings = scene.fallbacks = 0
    scene.min_det_F = np.inf
    v0 = body.volume()
    model.drive(scene, schedule)
    wall = time.perf_counter()
    run = simulate(
        scene,
        duration,
        dt,
        on_failure="stop",
        progress=False,
        record={
            "volume": lambda s: body.volume() / v0 - 1.0,
            "retried": lambda s: s.fallbacks + s.halvings,
        },
    )
    wall = time.perf_counter() - wall
    error = run.failure
    volume = np.abs(run.records["volume"])
    retried = np.diff(run.records["retried"]) > 0  # per completed step
    return {
        "outcome": "finished" if error is None else type(error).__name__,
        "error": None if error is None else str(error),
        "t_reached": float(scene.t),
        "steps": int(run.step_ms.size),
        "step_ms": run.step_ms.tolist(),
        "plain_steps": (~retried).tolist(),
        "fallbacks": int(run.fallbacks),
        "halvings": int(run.halvings),
        "min_det_F": float(run.min_det_F),
        "max_volume_change": float(volume.max()),
        "wall_s": round(wall, 3),
    }


def robustness_study(
    model: ReducibleScene,
    count: int,
    *,
    seed: int,
    duration: float,
    dt: float,
    progress: bool = True,
) -> dict:
    """:func:`hard_schedules` over the model's exciters, each run on the model built once and
    restored to rest before each; the figures of the module docstring."""
    from tqdm import tqdm

    scene = model.build()
    body = model.fem_body_or_full(scene)
    schedules = hard_schedules(list(model.inputs(body)), count, seed=seed, duration=duration)
    rest = scene.save_state()
    runs = {}
    for name, (kind, schedule) in tqdm(
        schedules.items(), desc=f"robustness {model.name}", unit="schedule", disable=not progress
    ):
        runs[name] = {"kind": kind, **_run(model, scene, rest, schedule, duration, dt)}
    plain = np.concatenate(
        [np.asarray(r["step_ms"])[np.asarray(r["plain_steps"], bool)] for r in runs.values()]
        + [np.zeros(0)]
    )
    # the semi-implicit step: None when no step of the study went without a retry
    reference = float(np.median(plain)) if plain.size else None
    for r in runs.values():
        r["cost"] = (
            float(np.mean(r["step_ms"]) / reference)
            if r["steps"] and reference is not None
            else None
        )
        del r["step_ms"], r["plain_steps"]
    finished = [r for r in runs.values() if r["outcome"] == "finished"]
    costs = np.array([r["cost"] for r in runs.values() if r["cost"] is not None])
    summary = {
        "schedules": len(runs),
        "finished": len(finished),
        "semi_implicit_step_ms": reference,
        "median_cost": float(np.median(costs)) if costs.size else None,
        "worst_cost": float(costs.max()) if costs.size else None,
        "min_det_F": min((r["min_det_F"] for r in finished), default=None),
        "max_volume_change": max((r["max_volume_change"] for r in finished), default=None),
        "fallbacks": sum(r["fallbacks"] for r in runs.values()),
        "halvings": sum(r["halvings"] for r in runs.values()),
        "by_kind": {
            k: f"{sum(r['outcome'] == 'finished' for r in runs.values() if r['kind'] == k)}"
            f"/{sum(r['kind'] == k for r in runs.values())}"
            for k in KINDS
        },
    }
    return {
        "model": model.name,
        "identity": model.identity(),
        "duration": duration,
        "dt": dt,
        "summary": summary,
        "runs": runs,
        "units": {
            "cost": "mean ms per step / the median semi-implicit step (no fallback, "
            "no halving) of the study",
            "semi_implicit_step_ms": "ms",
            "max_volume_change": "max |V / V0 - 1| over the run",
        },
    }


def _fmt(value, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def write_report(result: dict, out: Path) -> None:
    """DIR/robustness.json, .md and .png (module docstring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    (out / "robustness.json").write_text(json.dumps(result, indent=2))
    s, runs = result["summary"], result["runs"]
    lines = [
        f"# Robustness of {result['model']}",
        "",
        f"Written by `artifem study robustness` ({s['schedules']} random valid schedules, "
        f"{result['duration']:g} s at dt = {result['dt']:g} s, default settings); figures "
        "in `robustness.json`.",
        "",
        f"- finished: **{s['finished']} / {s['schedules']}** (by kind: "
        + ", ".join(f"{k} {v}" for k, v in s["by_kind"].items())
        + ")",
        f"- cost per step against the semi-implicit step "
        f"({_fmt(s['semi_implicit_step_ms'], '.1f')} ms): "
        f"median {_fmt(s['median_cost'], '.2f')}x, worst "
        f"{_fmt(s['worst_cost'], '.2f')}x",
        f"- steps completed by the implicit fallback: {s['fallbacks']}; halvings: {s['halvings']}",
        f"- finished runs: min det F {_fmt(s['min_det_F'], '.3f')}, largest volume "
        f"change {_fmt(s['max_volume_change'], '.1e')}",
        "",
        "| schedule | outcome | t reached (s) | cost | fallbacks | halvings | min det F | "
        "max \\|V/V0 - 1\\| | wall s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in runs.items():
        outcome = (
            r["outcome"]
            if r["error"] is None
            else f"{r['outcome']}: {r['error'][:160]}".replace("|", "/")
        )
        lines.append(
            f"| {name} | {outcome} | {r['t_reached']:.3g} | {_fmt(r['cost'], '.2f')} | "
            f"{r['fallbacks']} | {r['halvings']} | {r['min_det_F']:.3f} | "
            f"{r['max_volume_change']:.1e} | {r['wall_s']:.1f} |"
        )
    (out / "robustness.md").write_text("\n".join(lines) + "\n")

    names = list(runs)
    x = np.arange(len(names))
    colors = ["tab:green" if runs[n]["outcome"] == "finished" else "tab:red" for n in names]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(max(6.0, 0.45 * len(names)), 6), sharex=True)
    ax1.bar(x, [runs[n]["cost"] or 0.0 for n in names], color=colors)
    ax1.axhline(1.0, color="k", lw=0.8)
    ax1.set_ylabel("cost / semi-implicit step")
    ax1.set_title(
        f"{result['model']}: {s['finished']}/{s['schedules']} finished "
        "(green: finished, red: stopped)"
    )
    ax2.bar(x, [runs[n]["min_det_F"] for n in names], color=colors)
    ax2.set_ylabel("min det F")
    ax2.set_xticks(x, names, rotation=70, ha="right", fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "robustness.png", dpi=120)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "model", help=f"one of {sorted(MODELS)}, or MODULE:FUNCTION returning a ReducibleScene"
    )
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument(
        "--schedules",
        type=positive_int,
        default=20,
        help="how many random schedules (the kinds in turn)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--duration", type=positive_float, default=1.0)
    parser.add_argument("--dt", type=positive_float, default=0.01)
    parser.add_argument("--no-progress", action="store_true")


def load(spec: str) -> ReducibleScene:
    """A model of :data:`MODELS` by name, or ``MODULE:FUNCTION``."""
    if spec in MODELS:
        target, kwargs = MODELS[spec]
        module, _, name = target.partition(":")
        return getattr(importlib.import_module(module), name)(**kwargs)
    if ":" not in spec:
        raise InputError(
            f"study robustness: unknown model {spec!r}; choose one of "
            f"{sorted(MODELS)} or give MODULE:FUNCTION"
        )
    return load_model(spec)


def run(args: argparse.Namespace) -> int:
    model = load(args.model)
    result = robustness_study(
        model,
        args.schedules,
        seed=args.seed,
        duration=args.duration,
        dt=args.dt,
        progress=not args.no_progress,
    )
    write_report(result, args.out)
    s = result["summary"]
    print(
        f"{model.name}: {s['finished']}/{s['schedules']} schedules finished, cost median "
        f"{_fmt(s['median_cost'], '.2f')}x, worst {_fmt(s['worst_cost'], '.2f')}x the "
        "semi-implicit step; "
        f"report in {args.out}/robustness.md"
    )
    return 0
