"""``artifem simulate tongue``: a speech motion of the tongue, rendered and measured.

    artifem simulate tongue --motion protrusion [--level 1] [--integrator implicit]
                            [--incompressibility penalty] --out DIR
    artifem simulate tongue --motion all --out DIR      (the seed paper's Fig. 2 analog)
    artifem simulate tongue --schedule FILE.json --out DIR

Per motion it writes DIR/<motion>/tongue.bp (VTX, ParaView; with the hard
incompressibility also the element pressures, DIR/<motion>/tongue_pressure.bp),
DIR/<motion>/tongue.png (rest, t = 0.5 s, t = 1.0 s) and DIR/<motion>/simulate.json with
nodes, elements, steps, ms_per_step, min_det_F, the volume change V / V0 - 1
(at the end and its largest magnitude), the element pressure range (hard
incompressibility, the default; ``--incompressibility penalty`` for the element
penalty) and the displacement of the tip, top and base landmarks in
millimetres. ``--motion all`` adds
DIR/motions.png: rest, protrusion, retroflexion and retraction side by side.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from artifem.arguments import positive_float
from artifem.excitation import ExcitationSchedule
from artifem.models.tongue.model import (
    DT,
    DURATION,
    HARD,
    MOTIONS,
    PENALTY,
    RAMP_TIME,
    Tongue,
    TongueConfig,
)
from artifem.scene import INTEGRATORS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--motion", default="protrusion", choices=list(MOTIONS) + ["all"])
    source.add_argument(
        "--schedule",
        type=Path,
        help='excitation schedule JSON: {"times": [...], "excitations": '
        '{"GGP": [...], ...}} (exciter names)',
    )
    parser.add_argument(
        "--level",
        type=int,
        default=0,
        choices=(0, 1),
        help="0: mesh as shipped (946 nodes); 1: every hexahedron split 2x2x2",
    )
    parser.add_argument("--integrator", default="semi-implicit", choices=sorted(INTEGRATORS))
    parser.add_argument(
        "--incompressibility",
        default="hard",
        choices=("hard", "penalty"),
        help="element volumes held to 1e-4 (augmented Lagrangian; the default), "
        "or the element-wise penalty 100 C10",
    )
    parser.add_argument("--dt", type=positive_float, default=DT)
    parser.add_argument("--duration", type=positive_float, default=DURATION)
    parser.add_argument("--no-progress", action="store_true")


def run(args: argparse.Namespace) -> int:
    from artifem.render import render_bodies
    from artifem.scene import simulate

    hard = args.incompressibility == "hard"
    tongue = Tongue(
        TongueConfig(
            level=args.level,
            integrator=args.integrator,
            incompressibility=HARD if hard else PENALTY,
        )
    )
    if args.schedule is not None:
        runs = {args.schedule.stem: ExcitationSchedule.from_file(args.schedule)}
    else:
        names = list(MOTIONS) if args.motion == "all" else [args.motion]
        runs = {name: Tongue.motion(name) for name in names}
    for schedule in runs.values():
        tongue.bundle_schedule(schedule)  # unknown exciters fail here, before any work
    body, comm = tongue.body, tongue.body.mesh.comm
    shown = (0.0, min(RAMP_TIME, args.duration), args.duration)
    final = {}
    for name, schedule in runs.items():
        out = args.out / name
        if comm.rank == 0:
            out.mkdir(parents=True, exist_ok=True)
        tongue.reset()
        tongue.drive(schedule)
        rest_volume = body.volume()
        record = tongue.landmark_records()
        record["volume_change"] = lambda scene: body.volume() / rest_volume - 1.0
        traj = simulate(
            tongue.scene,
            args.duration,
            args.dt,
            record=record,
            keep=shown,
            vtx=out,
            progress=not args.no_progress,
            label=f"tongue {name}",
        )
        final[name] = traj.snapshots[shown[-1]][body.name]
        render_bodies(
            out / "tongue.png",
            [(body.mesh, traj.snapshots[t][body.name]) for t in shown],
            scalars="displacement",
            scalar_name="displacement (m)",
            titles=["rest"] + [f"{name}, t = {t:g} s" for t in shown[1:]],
            camera="xz",
            show_rest=True,
            window_size=(1800, 600),
        )
        figures = _figures(tongue, traj, name, args, shown)
        if comm.rank == 0:
            (out / "simulate.json").write_text(json.dumps(figures, indent=2))
            tip = figures["landmarks"]["tip"]
            print(
                f"tongue {name} (level {args.level}, {figures['nodes']} nodes): "
                f"{figures['ms_per_step']:.1f} ms/step, tip moved {tip} mm, "
                f"min det F {figures['min_det_F']:.3f}; results in {out}/"
            )
    if len(final) > 1:
        render_bodies(
            args.out / "motions.png",
            [(body.mesh, None)] + [(body.mesh, u) for u in final.values()],
            titles=["rest"] + list(final),
            camera="xz",
            window_size=(2000, 500),
        )
        if comm.rank == 0:
            print(f"side by side: {args.out / 'motions.png'}")
    return 0


def _figures(tongue: Tongue, traj, motion: str, args, shown) -> dict:
    def mm(name, t):
        k = int(np.argmin(abs(traj.times - t)))
        return np.round(1e3 * traj.records[name][k], 3).tolist()

    body = tongue.body
    volume = np.asarray(traj.records.pop("volume_change"), dtype=float)
    vc = body.volume_constraint
    return {
        "model": "artisynth_hex_tongue",
        "motion": motion,
        "level": args.level,
        "nodes": body.mesh.geometry.index_map().size_global,
        "elements": body.mesh.topology.index_map(3).size_global,
        "ranks": body.mesh.comm.size,
        "integrator": args.integrator,
        "linear_solver": tongue.config.linear_solver,
        "dt": args.dt,
        "steps": int(traj.step_ms.size),
        "ms_per_step": traj.ms_per_step,
        "min_det_F": traj.min_det_F,
        "halvings": traj.halvings,
        "incompressibility": args.incompressibility,
        "volume_change": float(volume[-1]),
        "max_volume_change": float(np.abs(volume).max()),
        "pressure_range_Pa": list(vc.pressure_range()) if vc is not None else None,
        "landmarks": {name: mm(name, shown[-1]) for name in traj.records},
        "landmarks_at_ramp_end": {name: mm(name, shown[1]) for name in traj.records},
        "units": {
            "landmarks": "mm, displacement from rest",
            "ms_per_step": "median wall ms",
            "volume_change": "V / V0 - 1 at the end; max_volume_change: max |V / V0 - 1|",
            "pressure_range_Pa": "element pressures (> 0 in compression), hard only",
        },
    }
