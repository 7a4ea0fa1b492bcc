"""``artifem study foot``: a load case of the foot, timed against its parts (the seed
paper's figures), measured, and (``--reduced``) against its reduced model.

    artifem study foot --out DIR [--case standing|lift|heavy] [--level 0|1]
                          [--dt 0.005] [--duration 0.3] [--timing-steps 5]
                          [--reduced [--cache DIR]] [--no-vtx]

It writes, in DIR/<case>/: ``tissue.bp`` (VTX: the tissue's displacement; standing also
``tissue_contact_pressure.bp``, the floor's pressure), ``foot.png`` (bones with ligaments
and muscles; the tissue cut and coloured by von Mises stress), for the standing cases
``plantar_pressure.png`` (beside the published standing figures quoted on it), and
``foot.json``: nodes, elements, the median ms per step of the FEM alone (the tissue with
its bone surfaces fixed), with the bones (no joint contacts, no floor) and with bones and
contact (the case itself), and the case's figures: for standing the floor's force
against load + weight, contact area, peak plantar pressure (rear and fore thirds) and
centre of pressure; for lift the first metatarsal's rise and the talus's dorsiflexion.
``--reduced`` adds the reduced foot (:mod:`~artifem.models.foot.reduced`, its
:data:`~artifem.models.foot.reduced.CONFIGS`: the paper's 6 POD vectors on 100 random
points, and on 100 trained points; the standing model for standing and heavy, the lift
model for lift), trained (or loaded: training resumes from ``--cache``) and run against
the full foot on its held-out input: ms per step of both, the max mean node error, and
``reduced.png``, the error and the ms of every step over the run.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from artifem.arguments import positive_float, positive_int
from artifem.models.cache import user_cache
from artifem.models.foot import mesh as fm
from artifem.models.foot.model import (
    CASES,
    DT,
    DURATION,
    REFERENCE,
    Foot,
    case_figures,
    foot_case,
    sole,
)
from artifem.models.foot.reduced import CONFIGS, HELD_OUT, compare, schedule, train
from artifem.models.foot.render import plot_plantar_pressure, plot_reduced_comparison, render_foot

#: the reduced foot's training cache
REDUCED_CACHE = user_cache("foot-reduced")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument("--case", default="standing", choices=sorted(CASES))
    parser.add_argument(
        "--level",
        type=int,
        default=1,
        choices=sorted(fm.LEVELS),
        help="mesh level: 0 coarse (1,923 nodes), 1 the default (13,453)",
    )
    parser.add_argument("--dt", type=positive_float, default=DT)
    parser.add_argument("--duration", type=positive_float, default=DURATION)
    parser.add_argument(
        "--timing-steps",
        type=positive_int,
        default=5,
        help="steps timed for the FEM alone and with the bones",
    )
    parser.add_argument(
        "--reduced",
        action="store_true",
        help="also the reduced foot against the full one, held-out input",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=REDUCED_CACHE,
        help="the reduced foot's training cache (resumed when interrupted)",
    )
    parser.add_argument("--no-vtx", action="store_true", help="write no VTX series")
    parser.add_argument("--no-progress", action="store_true")


def run(args: argparse.Namespace) -> int:
    from artifem.scene import simulate

    out = args.out / args.case
    out.mkdir(parents=True, exist_ok=True)
    timing = {
        "fem_alone": _time_steps(args, bones=False, floor=False),
        "with_bones": _time_steps(args, joints=False, floor=False),
    }
    foot = foot_case(args.case, args.level)
    rest = {name: body.position.copy() for name, body in foot.bones.items()}
    traj = simulate(
        foot.scene,
        args.duration,
        args.dt,
        vtx=None if args.no_vtx else out,
        progress=not args.no_progress,
        label=f"foot {args.case}",
    )
    timing["with_bones_and_contact"] = traj.ms_per_step
    pressure = sole(foot) if foot.floor is not None else None
    figures = _figures(foot, traj, args, timing, rest, pressure)
    render_foot(out / "foot.png", foot, args.case)
    if pressure is not None:
        plot_plantar_pressure(
            out / "plantar_pressure.png",
            pressure["points"],
            pressure["pressure"],
            pressure["centre"],
            f"foot {args.case}: plantar pressure, level {args.level}",
            REFERENCE,
        )
    (out / "foot.json").write_text(json.dumps(figures, indent=2))  # kept if reducing fails
    if args.reduced:
        configs = {
            name: replace(config, level=args.level, dt=args.dt, duration=args.duration)
            for name, config in CONFIGS.items()
        }
        figures["reduced"] = compare(
            "lift" if args.case == "lift" else "standing",
            configs,
            args.cache,
            progress=not args.no_progress,
        )
        (out / "foot.json").write_text(json.dumps(figures, indent=2))
        plot_reduced_comparison(
            out / "reduced.png",
            figures["reduced"],
            args.dt,
            f"foot {args.case}, level {args.level}: reduced against full on the held-out input",
        )
    print(
        f"foot {args.case} (level {args.level}, {figures['nodes']} nodes): "
        f"{timing['fem_alone']:.0f} ms/step FEM alone, {timing['with_bones']:.0f} with "
        f"bones, {timing['with_bones_and_contact']:.0f} with bones and contact; "
        f"results in {out}/"
    )
    for r in figures.get("reduced", {}).values():
        what = (
            f"reduced foot ({r['pod_vectors']} POD vectors + {r['lift_columns']} lift "
            f"columns, {r['points']} {r['config']['sampling']} points)"
        )
        print(
            f"{what}: stopped: {r['failure']}"
            if "failure" in r
            else f"{what}: {r['reduced_ms_per_step']:.1f} ms/step (median; mean "
            f"{r['reduced_ms_mean']:.1f}) against {r['full_ms_per_step']:.0f} (mean "
            f"{r['full_ms_mean']:.0f}), max mean node error "
            f"{r['max_mean_node_error_mm']:.2f} mm on the held-out input"
        )
    return 0


def _median_ms(scene, steps: int, dt: float) -> float:
    ms = []
    for _ in range(steps):
        tic = time.perf_counter()
        scene.step(dt)
        ms.append(1e3 * (time.perf_counter() - tic))
    return float(np.median(ms))


def _time_steps(args, **parts) -> float:
    """Median ms of ``--timing-steps`` steps of the case built with ``parts``."""
    return _median_ms(foot_case(args.case, args.level, **parts).scene, args.timing_steps, args.dt)


#: the seed paper's foot (13,087 nodes, a quad-core i7-7700), ms per step
PAPER_MS = {"fem_alone": 650.0, "with_bones_and_contact": 2600.0, "reduced": 10.0}


def benchmark(steps: int = 5, quick: bool = False, cache: Path | None = None) -> dict:
    """``artifem bench scenes``: median ms per step (``steps`` steps from rest, the load
    ramping) of the standing foot: the FEM alone, with the bones, with bones and contact,
    and reduced (each of :data:`~artifem.models.foot.reduced.CONFIGS`, trained or loaded
    from ``cache``, on the held-out weight: cases ``reduced`` and ``reduced_trained``); at
    level 1 (``quick``: level 0, 0.1 s training)."""
    level = 0 if quick else 1
    configs = {
        name: replace(config, level=level, duration=0.1 if quick else config.duration)
        for name, config in CONFIGS.items()
    }
    dt = configs["paper"].dt
    cases = {
        "fem_alone": dict(bones=False, floor=False),
        "with_bones": dict(joints=False, floor=False),
        "with_bones_and_contact": {},
    }
    feet = {name: foot_case("standing", level, **parts) for name, parts in cases.items()}
    ms = {name: _median_ms(foot.scene, steps, dt) for name, foot in feet.items()}
    reduced = {}
    for name, config in configs.items():
        model = train("standing", config, cache or REDUCED_CACHE, progress=False)
        scene = model.scene()
        model.model.drive(scene, schedule("standing", HELD_OUT["standing"], config.duration))
        case = "reduced" if name == "paper" else f"reduced_{name}"
        with threadpool_limits(limits=1, user_api="blas"):
            ms[case] = _median_ms(scene, steps, dt)
        reduced[case] = {
            "pod_vectors": config.r,
            "lift_columns": model.r - config.r,
            "points": int(model.points.m),
            "sampling": config.sampling,
        }
    foot = feet["with_bones_and_contact"]
    return {
        "benchmark": "foot",
        "level": level,
        "steps": steps,
        "dt": dt,
        "nodes": foot.tissue.mesh.geometry.index_map().size_global,
        "elements": foot.tissue.mesh.topology.index_map(3).size_global,
        "cases": {name: {"ms_per_step": value} for name, value in ms.items()},
        "reduced": reduced,
        "paper_ms_per_step": PAPER_MS,
    }


def _figures(foot: Foot, traj, args, timing: dict, rest: dict, pressure: dict | None) -> dict:
    tissue = foot.tissue
    figures = {
        "model": "foot",
        "case": args.case,
        "level": args.level,
        "nodes": tissue.mesh.geometry.index_map().size_global,
        "elements": tissue.mesh.topology.index_map(3).size_global,
        "rigid_bodies": len(foot.bones),
        "ligaments": len(foot.ligaments),
        "joint_contacts": len(foot.joints),
        "dt": args.dt,
        "duration": args.duration,
        "steps": int(traj.step_ms.size),
        "halvings": traj.halvings,
        "min_det_F": traj.min_det_F,
        "ms_per_step": {key: round(value, 1) for key, value in timing.items()},
        "timing_steps": args.timing_steps,
        "joint_failures": [f for f in (c.constraint_failure() for c in foot.joints) if f],
    }
    figures.update(case_figures(foot, rest, pressure))
    figures["units"] = {
        "ms_per_step": "median wall ms per step (fem_alone, with_bones: "
        "timing_steps steps of a separate build)",
        "centre_of_pressure_mm": "tibia frame (x forward, z lateral)",
        "centre_of_pressure_from_heel": "fraction of the sole's length",
    }
    return figures
