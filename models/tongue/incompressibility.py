"""``artifem study incompressibility``: the tongue's motions with the element penalty and with
the hard constraint, side by side.

    artifem study incompressibility --out DIR [--levels 0,1] [--motions all]
                                    [--duration 1.0] [--no-progress]

For every level and motion (protrusion, retroflexion, retraction: the seed paper's Fig. 2)
the tongue runs twice, with FemBody's element penalty (kappa_inc = 100 C10, the model's
default, CG + AMG) and with the hard constraint (:data:`~artifem.models.tongue.model.HARD`:
element volumes held to 1e-4 by an augmented Lagrangian; MUMPS, ``HARD_SOLVER``). It writes

- DIR/incompressibility.json: per run the volume change V / V0 - 1 at the end and its
  largest magnitude over the run, the tip, top and base landmarks (mm) at the end, the
  median ms per step (and the pressure iterations per step), the element pressure range,
  min det F and halvings; with two levels, the landmarks' level-0 / level-1 differences;
- DIR/report.md: the same as tables;
- DIR/motions_<penalty|hard>_level<L>.png: rest and the three motions at the end (the
  layout of Fig. 2), displacement magnitude in colour.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from artifem.arguments import positive_float
from artifem.errors import InputError
from artifem.models.tongue.model import (
    DT,
    DURATION,
    HARD,
    HARD_SOLVER,
    MOTIONS,
    PENALTY,
    Tongue,
    TongueConfig,
)

KINDS = ("penalty", "hard")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument(
        "--levels",
        default="0,1",
        help="comma-separated tongue levels, 0 and/or 1 (default: %(default)s)",
    )
    parser.add_argument(
        "--motions",
        default="all",
        help=f"comma-separated motions from {', '.join(MOTIONS)}, or all (default: %(default)s)",
    )
    parser.add_argument(
        "--duration",
        type=positive_float,
        default=DURATION,
        help="simulated seconds per run (default: %(default)s)",
    )
    parser.add_argument("--no-progress", action="store_true")


def _parse(args) -> tuple[list[int], list[str]]:
    try:
        levels = sorted({int(s) for s in args.levels.split(",") if s.strip()})
    except ValueError:
        raise InputError(f"--levels: expected 0 and/or 1, got {args.levels!r}") from None
    if not levels or any(level not in (0, 1) for level in levels):
        raise InputError(f"--levels: expected 0 and/or 1, got {args.levels!r}")
    motions = (
        list(MOTIONS)
        if args.motions == "all"
        else [m.strip() for m in args.motions.split(",") if m.strip()]
    )
    unknown = [m for m in motions if m not in MOTIONS]
    if unknown or not motions:
        raise InputError(
            f"--motions: unknown {unknown or args.motions!r}; choose from "
            f"{', '.join(MOTIONS)} or all"
        )
    return levels, motions


def run_motion(
    tongue: Tongue, motion: str, duration: float, progress: bool
) -> tuple[dict, np.ndarray]:
    """One motion from rest: (its figures, the final displacement)."""
    from artifem.scene import simulate

    body = tongue.body
    vc = body.volume_constraint
    tongue.reset()
    tongue.drive(Tongue.motion(motion))
    rest = body.volume()
    record = tongue.landmark_records()
    record["volume_change"] = lambda scene: body.volume() / rest - 1.0
    record["pressure_iterations"] = lambda scene: vc.updates if vc is not None else 0
    run = simulate(
        tongue.scene,
        duration,
        DT,
        record=record,
        keep=(duration,),
        progress=progress,
        label=f"{motion}",
    )
    volume = np.asarray(run.records["volume_change"], dtype=float)
    iterations = np.asarray(run.records["pressure_iterations"], dtype=float)
    figures = {
        "volume_change": float(volume[-1]),
        "max_volume_change": float(np.abs(volume).max()),
        "landmarks_mm": {
            name: np.round(1e3 * np.asarray(run.records[name][-1]), 3).tolist()
            for name in tongue.data.landmarks
        },
        "ms_per_step": run.ms_per_step,
        "pressure_iterations": float(np.median(iterations)),
        "max_pressure_iterations": int(iterations.max()),
        "pressure_range_Pa": list(vc.pressure_range()) if vc is not None else None,
        "min_det_F": run.min_det_F,
        "halvings": run.halvings,
    }
    return figures, run.snapshots[duration][body.name]


def run(args: argparse.Namespace) -> int:
    from mpi4py import MPI

    from artifem.render import render_bodies

    levels, motions = _parse(args)
    comm = MPI.COMM_WORLD
    out = Path(args.out)
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    runs: dict = {}
    finals: dict = {}
    for level in levels:
        for kind in KINDS:
            config = TongueConfig(
                level=level, incompressibility=HARD if kind == "hard" else PENALTY
            )
            tongue = Tongue(config, comm=comm)
            for motion in motions:
                figures, u = run_motion(tongue, motion, args.duration, not args.no_progress)
                runs.setdefault(f"level {level}", {}).setdefault(motion, {})[kind] = figures
                finals.setdefault((level, kind), (tongue.body.mesh, []))[1].append(u)
    report = {
        "model": "artisynth_hex_tongue",
        "levels": levels,
        "motions": motions,
        "duration_s": args.duration,
        "dt": DT,
        "ranks": comm.size,
        "hard": {"kappa_Pa": HARD.kappa, "tol": HARD.tol, "linear_solver": HARD_SOLVER},
        "penalty_linear_solver": TongueConfig(incompressibility=PENALTY).linear_solver,
        "penalty_kappa_inc_Pa": PENALTY,
        "runs": runs,
    }
    if len(levels) == 2:
        report["level_difference_mm"] = {
            motion: {
                kind: {
                    name: float(
                        np.linalg.norm(
                            np.subtract(
                                runs["level 1"][motion][kind]["landmarks_mm"][name],
                                runs["level 0"][motion][kind]["landmarks_mm"][name],
                            )
                        )
                    )
                    for name in runs["level 0"][motion][kind]["landmarks_mm"]
                }
                for kind in KINDS
            }
            for motion in motions
        }
    if comm.rank == 0:
        (out / "incompressibility.json").write_text(json.dumps(report, indent=2))
        (out / "report.md").write_text(format_report(report))
    for (level, kind), (mesh, us) in finals.items():  # the figures are written first
        render_bodies(
            out / f"motions_{kind}_level{level}.png",
            [(mesh, None)] + [(mesh, u) for u in us],
            titles=["rest"] + [f"{m} ({kind})" for m in motions],
            camera="xz",
            window_size=(500 * (1 + len(motions)), 500),
        )
    if comm.rank == 0:
        print(
            f"wrote {out / 'incompressibility.json'}, {out / 'report.md'} and "
            f"{len(finals)} pictures"
        )
    return 0


def format_report(report: dict) -> str:
    """The JSON's figures as Markdown tables."""
    lines = [
        "# The tongue with the element penalty and with hard incompressibility",
        "",
        f"{report['duration_s']:g} s of each motion, dt = {report['dt']:g} s, "
        f"{report['ranks']} rank(s). Penalty: kappa_inc = "
        f"{report['penalty_kappa_inc_Pa']:,.0f} Pa; hard: element volumes to "
        f"{report['hard']['tol']:g} (augmentation {report['hard']['kappa_Pa']:,.0f} Pa).",
        "",
        "| level | motion | formulation | volume change (end, max) | tip (mm) | "
        "top (mm) | base (mm) | ms/step | pressure iterations | pressure (kPa) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for level, motions in report["runs"].items():
        for motion, kinds in motions.items():
            for kind, r in kinds.items():
                lm = r["landmarks_mm"]
                pr = r["pressure_range_Pa"]
                lines.append(
                    f"| {level.split()[-1]} | {motion} | {kind} | "
                    f"{100 * r['volume_change']:+.3f} %,"
                    f" {100 * r['max_volume_change']:.3f} % | "
                    + " | ".join(
                        ", ".join(f"{x:+.2f}" for x in lm[n]) for n in ("tip", "top", "base")
                    )
                    + f" | {r['ms_per_step']:.0f} | {r['pressure_iterations']:.0f} "
                    f"(max {r['max_pressure_iterations']}) | "
                    + (f"{pr[0] / 1e3:.1f} .. {pr[1] / 1e3:.1f}" if pr else "-")
                    + " |"
                )
    if "level_difference_mm" in report:
        lines += [
            "",
            "Landmark change from level 0 to level 1 (mm):",
            "",
            "| motion | formulation | tip | top | base |",
            "|---|---|---|---|---|",
        ]
        for motion, kinds in report["level_difference_mm"].items():
            for kind, d in kinds.items():
                lines.append(
                    f"| {motion} | {kind} | {d['tip']:.2f} | {d['top']:.2f} | {d['base']:.2f} |"
                )
    return "\n".join(lines) + "\n"


def format_speed_table(bench: dict) -> str:
    """The step times of ``artifem bench tongue --incompressibility penalty,hard`` (its
    JSON) as a Markdown table (docs/incompressibility.md quotes it)."""
    lines = [
        "| level | nodes | ranks | formulation | solver | ms/step | assembly | solve | "
        "pressure iterations | volume change |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in bench["cases"]:
        lines.append(
            f"| {c['level']} | {c['nodes']:,} | {c['ranks']} | {c['incompressibility']} "
            f"| {c['solver']} | {c['ms_per_step']:.1f} | {c['assembly_ms']:.1f} | "
            f"{c['solve_ms']:.1f} | {c['pressure_iterations']:.0f} | "
            f"{100 * c['volume_change']:+.3f} % |"
        )
    return "\n".join(lines) + "\n"


def format_reduced_table(study: dict) -> str:
    """The trained-POD rows of ``artifem study tongue --incompressibility hard`` (its
    study.json) as a Markdown table (docs/incompressibility.md quotes it): per point count
    and sampling, the step time, the largest mean node error against the hard full model,
    and the largest volume change of the reduced and of the full run, per motion."""
    runs = [r for r in study["runs"] if r["basis"] == "trained-pod"]
    lines = [
        "| points | sampling | motion | ms/step | max error (mm) | volume change, reduced | full |",
        "|---|---|---|---|---|---|---|",
    ]
    order = list(MOTIONS)
    for r in sorted(runs, key=lambda r: (r["sampling"], -r["points"], order.index(r["motion"]))):
        lines.append(
            f"| {r['points']} | {r['sampling']} | {r['motion']} | "
            f"{r['ms_per_step']:.2f} | {r['max_error_mm']:.2f} | "
            f"{100 * r['max_volume_change']:.3f} % | "
            f"{100 * r['full_max_volume_change']:.3f} % |"
        )
    return "\n".join(lines) + "\n"
