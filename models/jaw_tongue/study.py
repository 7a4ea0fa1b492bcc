"""Jaw and tongue with a *reduced* tongue, side by side with the full one.

The scene is :mod:`artifem.models.jaw_tongue.model` (level-0 tongue, rigid jaw on a
TMJ hinge with limits, opener muscle, closer spring, gravity); only the tongue
changes. Its 59 jaw-attachment nodes ride on the jaw, which a reduced body
cannot express with node slaves, so the basis carries the jaw
(:mod:`artifem.reduction.rigid_lift`):

    u = U q + L g,     g = [p - p_0; vec(R - R_0)]  (the jaw's pose, 12 numbers),

L the 12 lift columns (exact rigid motion of the attachment nodes, extended
by the rest tangent), U a trained POD basis that vanishes on the attachment
and hyoid nodes. In the Scene g is a slave of the jaw
(:class:`LiftAttachment`); the masters are q and the jaw's twist.

Training (:mod:`artifem.models.jaw_tongue.reduced`) is the reductor's
(:func:`artifem.reduction.reductor.reduce`, cached on disk
by the inputs): the *full* jaw-tongue scene run with each exciter alone at
``training_excitation`` (ramped over the paper's 0.5 s) while the jaw opens by its own
schedule; snapshots of u - L g (zero on the attachment and hyoid nodes) every
``snapshot_every`` steps; U = the r leading mass-weighted POD vectors; integration
points by ECSW (non-negative least squares) on the reduced forces of the basis [U, L]
at those states. The reductor finds the jaw's node attachment in the scene, builds L
and turns the attachment into a :class:`LiftAttachment`.

Comparison (``artifem study jaw-tongue --out DIR``): the three speech motions,
full and reduced scene in one process; per motion the mean nodal tongue error
over time (mm), the jaw angle of both, ms per step and the speed-up; JSON,
Markdown table and a side-by-side render at each motion's largest error; then the
train/test split (:mod:`artifem.reduction.generalization`, ``--held-out N``, default 5):
the training schedules, the motions and N held-out random tongue schedules, error beside
the hierarchical estimate.
``--quick`` (:func:`quick_config`): a smoke run, protrusion for 0.15 s over a small
training (0.15 s runs, r = 12, 150 points; about a minute on 2 cores, seconds once
the training is in ``--cache``).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from artifem.arguments import nonnegative_int, positive_float, positive_int
from artifem.errors import InputError
from artifem.excitation import ExcitationSchedule
from artifem.models.jaw_tongue import model as jt
from artifem.models.jaw_tongue.model import JawTongueScene, records
from artifem.models.jaw_tongue.reduced import (
    ReducedJawTongueConfig,
    build_reduced_scene,
    quick_config,
    reducible,
    specification,
    train,
    training,
)
from artifem.models.jaw_tongue.render import render
from artifem.models.cache import user_cache
from artifem.models.tongue.model import MOTIONS, Tongue
from artifem.reduction.reductor import (
    Reductor,
)
from artifem.reduction.generalization import generalization_study
from artifem.reduction.generalization_report import write_markdown
from artifem.scene import simulate as simulate_scene

__all__ = ["compare", "benchmark", "simulate"]


#: ``--quick``: motions and duration of the comparison (unless given).
QUICK_MOTIONS, QUICK_DURATION = ("protrusion",), 0.15


def simulate(
    s: JawTongueScene,
    motion: str | ExcitationSchedule | None,
    duration: float,
    dt: float = 0.01,
    *,
    snapshots=(),
    record=None,
    progress: bool = False,
    label: str = "jaw-tongue",
) -> dict:
    """Run the tongue motion (a name of MOTIONS, with the paper's ramp, or an exciter
    schedule, added to the scene's controllers) with the scene's jaw through
    :func:`artifem.scene.simulate`; record, at the start and after every step: time ``t``,
    opening ``angle``, ``tip`` displacement, ``attachment_error`` and ``joint_error``,
    ``jaw_nodes_dz``, ``opener_tension``, the tongue displacement ``u`` (steps + 1, n) and the
    jaw pose ``jaw_position``, ``jaw_rotation``; ``ms``: wall time of each step. ``record``:
    more name -> f(scene) recorded the same way (outside the step timing), added to the
    result. ``frames``: (t, u, p, R) after the steps nearest the ``snapshots`` fractions of
    the run. A step the scene cannot complete raises its ElementInversionError or
    StepFailed (after its step halvings: ``s.scene.halvings``, ``s.scene.min_det_F``)."""
    body = s.tongue.body
    if body.mesh.comm.size > 1:  # the tip, u and the render are one rank's
        raise InputError(
            f"jaw_tongue.study.simulate: the tongue is distributed over "
            f"{body.mesh.comm.size} MPI ranks; it records a serial scene: "
            f"build_scene(comm=MPI.COMM_SELF)"
        )
    if isinstance(motion, str):
        motion = Tongue.motion(motion)
    control = s.tongue.bundle_schedule(motion).controller(body) if motion else None
    quantities = {**records(s), **(record or {})}
    if control is not None:
        s.scene.add_controller(control)  # for this run only (removed at its end)
    try:  # controllers, halving, det F: the Scene's
        run = simulate_scene(
            s.scene, duration, dt, record=quantities, progress=progress, label=label, leave=False
        )
    finally:
        if control is not None:
            s.scene.controllers.remove(control)
    out = {"t": run.times, "ms": run.step_ms, **run.records}
    n = int(round(duration / dt))
    out["frames"] = [
        (float(run.times[k]), out["u"][k], out["jaw_position"][k], out["jaw_rotation"][k])
        for k in sorted({int(round(f * n)) for f in snapshots})
        if 1 <= k <= n
    ]
    return out


def _run(s: jt.JawTongueScene, motion: str, duration: float, dt: float) -> dict:
    """simulate() with the jaw pose at every step as ``poses`` (p, R) (its tongue
    displacement ``u`` and the pose are recorded outside the timing)."""
    rec = simulate(s, motion, duration, dt)
    rec["poses"] = list(zip(rec["jaw_position"], rec["jaw_rotation"]))
    return rec


def compare(
    config: ReducedJawTongueConfig,
    out: Path,
    *,
    motions=tuple(MOTIONS),
    duration: float = 0.6,
    cache: Path | None = None,
) -> dict:
    """Full against reduced jaw-tongue scene for ``motions``: JSON, report, renders."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tic = time.perf_counter()
    model = train(config, cache or out / "cache")
    train_s = time.perf_counter() - tic
    results = {}
    for motion in motions:
        full = jt.build_scene(config.jaw)
        rf = _run(full, motion, duration, config.dt)
        reduced = build_reduced_scene(model, config)
        with threadpool_limits(limits=1, user_api="blas"):  # r x r algebra
            rr = _run(reduced, motion, duration, config.dt)
        node_error = 1e3 * np.linalg.norm((rr["u"] - rf["u"]).reshape(len(rf["u"]), -1, 3), axis=2)
        mean_error = node_error.mean(axis=1)
        worst = int(np.argmax(mean_error))
        results[motion] = {
            "full_ms_per_step": float(np.median(rf["ms"])),
            "reduced_ms_per_step": float(np.median(rr["ms"])),
            "speedup": float(np.median(rf["ms"]) / np.median(rr["ms"])),
            "max_mean_error_mm": float(mean_error.max()),
            "max_node_error_mm": float(node_error.max()),
            "max_tip_displacement_mm": float(1e3 * np.linalg.norm(rf["tip"], axis=1).max()),
            "max_angle_deg": {
                "full": float(np.degrees(rf["angle"].max())),
                "reduced": float(np.degrees(rr["angle"].max())),
            },
            "max_angle_difference_deg": float(np.degrees(np.abs(rf["angle"] - rr["angle"]).max())),
            "max_attachment_error_m": float(rr["attachment_error"].max()),
            "max_joint_error": float(rr["joint_error"].max()),
            "worst_time_s": float(worst * config.dt),
        }
        png = out / f"jaw_tongue_reduced_{motion}.png"
        t = worst * config.dt
        render(
            png,
            full,
            [
                (f"full, t = {t:.2f} s", rf["u"][worst], *rf["poses"][worst]),
                (
                    f"reduced r = {config.r}+12, {config.points} pts, t = {t:.2f} s, "
                    f"error {mean_error[worst]:.2f} mm",
                    rr["u"][worst],
                    *rr["poses"][worst],
                ),
            ],
        )
        results[motion]["png"] = png.name
    figures = {
        "model": "jaw_tongue_reduced",
        "level": 0,
        "dt": config.dt,
        "duration": duration,
        "basis": {
            "pod_vectors": config.r,
            "lift_columns": 12,
            "training": "full jaw-tongue scene, each exciter alone at "
            f"{config.training_excitation}, jaw opener on",
            "snapshots": model.training["snapshots"],
        },
        "points": {
            "count": int(model.points.m),
            "kind": "trained (ECSW NNLS)",
            "training_residual": model.points.residual,
        },
        "training_seconds": sum(model.training["seconds"].values()),
        "reduce_seconds": train_s,
        "motions": results,
    }
    (out / "jaw_tongue_reduced.json").write_text(json.dumps(figures, indent=2))
    (out / "jaw_tongue_reduced.md").write_text(report(figures))
    return figures


def report(figures: dict) -> str:
    lines = [
        "# Jaw and tongue: full against reduced tongue",
        "",
        f"Level-0 tongue, dt = {figures['dt']} s, {figures['duration']} s per motion; "
        f"reduced: {figures['basis']['pod_vectors']} POD vectors + 12 jaw-lift columns, "
        f"{figures['points']['count']} trained points.",
        "",
        "| motion | full ms/step | reduced ms/step | speed-up | max mean error (mm) | "
        "max node error (mm) | jaw angle full / reduced (deg) |",
        "|---|---|---|---|---|---|---|",
    ]
    for motion, r in figures["motions"].items():
        lines.append(
            f"| {motion} | {r['full_ms_per_step']:.1f} | "
            f"{r['reduced_ms_per_step']:.2f} | {r['speedup']:.0f}x | "
            f"{r['max_mean_error_mm']:.2f} | {r['max_node_error_mm']:.2f} | "
            f"{r['max_angle_deg']['full']:.2f} / {r['max_angle_deg']['reduced']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    quick = quick_config()
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument(
        "--motions",
        nargs="+",
        default=None,
        choices=sorted(MOTIONS),
        help=f"default: all ({', '.join(sorted(MOTIONS))}); with --quick {' '.join(QUICK_MOTIONS)}",
    )
    parser.add_argument(
        "--duration",
        type=positive_float,
        default=None,
        help=f"seconds per motion (default 0.6; with --quick {QUICK_DURATION})",
    )
    parser.add_argument(
        "--r",
        type=positive_int,
        default=None,
        help=f"POD vectors (default {ReducedJawTongueConfig.r}; with --quick {quick.r})",
    )
    parser.add_argument(
        "--points",
        type=positive_int,
        default=None,
        help=f"trained integration points (default "
        f"{ReducedJawTongueConfig.points}; with --quick "
        f"{quick.points})",
    )
    parser.add_argument(
        "--cache", type=Path, default=None, help="training cache (default OUT/cache)"
    )
    parser.add_argument(
        "--held-out",
        type=nonnegative_int,
        default=None,
        help="held-out random tongue schedules for the train/test split "
        "(generalization.json, .md, .png; default 5, --quick 0)",
    )
    parser.add_argument("--held-out-seed", type=int, default=1000, help="their seed (default 1000)")
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"a small smoke-test study: the quick training "
        f"({quick.training_duration} s runs, r = {quick.r}, "
        f"{quick.points} points), "
        f"{' '.join(QUICK_MOTIONS)} for {QUICK_DURATION} s",
    )


def run(args: argparse.Namespace) -> int:
    config = quick_config() if args.quick else ReducedJawTongueConfig()
    config = replace(
        config, **{k: v for k, v in (("r", args.r), ("points", args.points)) if v is not None}
    )
    motions = args.motions or (QUICK_MOTIONS if args.quick else sorted(MOTIONS))
    duration = args.duration or (QUICK_DURATION if args.quick else 0.6)
    figures = compare(config, args.out, motions=tuple(motions), duration=duration, cache=args.cache)
    print(report(figures))
    held_out = args.held_out if args.held_out is not None else (0 if args.quick else 5)
    if held_out:
        basis, points = specification(config)
        reductor = Reductor(reducible(config), training(config), args.cache or args.out / "cache")
        split = generalization_study(
            reductor,
            args.out,
            basis=basis,
            points=points,
            held_out=held_out,
            seed=args.held_out_seed,
            duration=duration,
            dt=config.dt,
        )
        print(write_markdown(split))
    return 0


def benchmark(
    steps: int = 20,
    warmup: int = 3,
    config: ReducedJawTongueConfig | None = None,
    cache: Path | None = None,
    quick: bool = False,
) -> dict:
    """Milliseconds per coupled step (median of ``steps`` after ``warmup``) of the jaw-tongue
    scene during protrusion with the full and with the reduced tongue (training cached in
    ``cache``, default $XDG_CACHE_HOME/artifem/jaw_tongue_reduced, ~/.cache when unset).
    ``quick``: the reduced tongue of :func:`quick_config` (unless ``config`` is given), a
    smoke test of the timings."""
    if steps < 1 or warmup < 0:
        raise InputError(f"benchmark: need steps >= 1 and warmup >= 0, got {steps}, {warmup}")
    config = config or (quick_config() if quick else ReducedJawTongueConfig())
    cache = cache or user_cache("jaw_tongue_reduced")
    model = train(config, cache)
    cases = {}
    for name, build in (
        ("full", lambda: jt.build_scene(config.jaw)),
        ("reduced", lambda: build_reduced_scene(model, config)),
    ):
        s = build()
        with threadpool_limits(limits=1, user_api="blas"):
            rec = simulate(s, "protrusion", (warmup + steps) * config.dt, config.dt)
        cases[name] = {
            "ms_per_step": float(np.median(rec["ms"][warmup:])),
            "masters": s.scene.master_count(),
        }
    cases["speedup"] = cases["full"]["ms_per_step"] / cases["reduced"]["ms_per_step"]
    return {
        "benchmark": "jaw-tongue",
        "steps": steps,
        "dt": config.dt,
        "reduced": {"pod_vectors": config.r, "lift_columns": 12, "points": config.points},
        "cases": cases,
    }
