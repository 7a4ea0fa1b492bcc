"""A muscle-driven cantilever: the foundation's demonstration scene.

A 60 x 15 x 15 mm block of tongue tissue (Mooney-Rivlin C10 = 1037 Pa,
C20 = 486 Pa, kappa = 10370 Pa, 1040 kg/m^3, Rayleigh 40 M + 0.03 K) is
clamped at x = 0 and hangs under gravity. Its upper half is a muscle with
fibers along x (Blemker fiber energy); ramping its excitation from 0 to the
target over 0.5 s and holding it until 1 s shortens the top and curls the free
end upward, the way a tongue's longitudinal muscles curl its tip.

``artifem simulate beam --out DIR`` writes DIR/beam.bp (VTX),
DIR/beam.png (rest, t = 0.5 s, t = 1.0 s), DIR/tip.png and DIR/simulate.json.
"""

from __future__ import annotations

import argparse
import json
import platform
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from dolfinx import mesh as dmesh

from artifem.arguments import fraction, positive_float, positive_int
from artifem.excitation import ExcitationSchedule
from artifem.fem_body import FemBody
from artifem.linear_solver import DEFAULT_METHOD
from artifem.forms import BlemkerFiber, MooneyRivlin
from artifem.scene import INTEGRATORS, Scene

LENGTH, WIDTH, HEIGHT = 0.060, 0.015, 0.015


@dataclass(frozen=True)
class BeamConfig:
    cells: tuple[int, int, int] = (24, 6, 6)
    cell_type: str = "hexahedron"
    max_stress: float = 1.0e4  # Pa, peak active fiber stress
    excitation: float = 1.0
    ramp_time: float = 0.5
    duration: float = 1.0
    dt: float = 0.01
    integrator: str = "semi-implicit"
    linear_solver: str = DEFAULT_METHOD


def build_beam(config: BeamConfig, comm=MPI.COMM_WORLD) -> tuple[Scene, FemBody]:
    """The scene with the clamped, muscle-driven beam (excitation schedule attached)."""
    cell = getattr(dmesh.CellType, config.cell_type)
    domain = dmesh.create_box(comm, [[0, 0, 0], [LENGTH, WIDTH, HEIGHT]], list(config.cells), cell)
    body = FemBody(
        domain,
        MooneyRivlin.tongue(),
        density=1040.0,
        rayleigh=(40.0, 0.03),
        gravity=(0.0, 0.0, -9.81),
        name="beam",
    )
    body.fix_nodes(body.find_nodes(lambda x: np.isclose(x[0], 0.0)))
    top = body.find_cells(lambda x: x[2] > 0.5 * HEIGHT)
    body.add_muscle("top", top, (1.0, 0.0, 0.0), BlemkerFiber(max_stress=config.max_stress))
    scene = Scene(
        gravity=(0.0, 0.0, -9.81), integrator=config.integrator, linear_solver=config.linear_solver
    )
    scene.add(body)
    schedule = ExcitationSchedule.ramp_and_hold({"top": config.excitation}, config.ramp_time)
    scene.add_controller(schedule.controller(body))
    return scene, body


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument("--integrator", default="semi-implicit", choices=sorted(INTEGRATORS))
    parser.add_argument(
        "--cells", type=positive_int, nargs=3, default=[24, 6, 6], metavar=("NX", "NY", "NZ")
    )
    parser.add_argument("--excitation", type=fraction, default=1.0)
    parser.add_argument("--dt", type=positive_float, default=0.01)
    parser.add_argument("--duration", type=positive_float, default=1.0)
    parser.add_argument("--no-progress", action="store_true")


def run(args: argparse.Namespace) -> int:
    from artifem.render import render_bodies
    from artifem.scene import simulate

    config = BeamConfig(
        cells=tuple(args.cells),
        excitation=args.excitation,
        dt=args.dt,
        duration=args.duration,
        integrator=args.integrator,
    )
    scene, body = build_beam(config)
    out = Path(args.out)
    comm = body.mesh.comm
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    tip = body.nearest_node((LENGTH, 0.5 * WIDTH, 0.5 * HEIGHT))
    shown = (0.0, 0.5 * config.duration, config.duration)
    traj = simulate(
        scene,
        config.duration,
        config.dt,
        record={"tip": lambda s: body.displacement_at([tip])[0]},
        keep=shown,
        vtx=out,
        progress=not args.no_progress,
        label="muscle beam",
    )
    render_bodies(
        out / "beam.png",
        [(body.mesh, traj.snapshots[t][body.name]) for t in shown],
        scalars="displacement",
        titles=["rest"] + [f"t = {t:g} s" for t in shown[1:]],
        scalar_name="displacement (m)",
        camera="xz",
        show_rest=True,
        window_size=(1500, 500),
    )
    tip_mm = 1e3 * traj.records["tip"]
    n_cells = body.mesh.topology.index_map(3).size_global
    figures = {
        "model": "muscle_beam",
        "nodes": body.mesh.geometry.index_map().size_global,
        "elements": n_cells,
        "ranks": comm.size,
        "integrator": config.integrator,
        "linear_solver": config.linear_solver,
        "dt": config.dt,
        "steps": int(traj.step_ms.size),
        "ms_per_step": traj.ms_per_step,
        "min_det_F": traj.min_det_F,
        "halvings": traj.halvings,
        "tip_displacement_mm": {
            f"t={t:g}": tip_mm[np.argmin(abs(traj.times - t))].tolist() for t in shown[1:]
        },
        "machine": platform.processor() or platform.machine(),
    }
    if comm.rank == 0:
        _plot_tip(out / "tip.png", traj.times, tip_mm, config.ramp_time)
        (out / "simulate.json").write_text(json.dumps(figures, indent=2))
        print(
            f"muscle beam: {figures['nodes']} nodes, {figures['ms_per_step']:.1f} ms/step, "
            f"tip at {config.duration:g} s {np.round(tip_mm[-1], 2).tolist()} mm, min det F "
            f"{figures['min_det_F']:.3f}; results in {out}/"
        )
    return 0


def _plot_tip(png: Path, times: np.ndarray, tip_mm: np.ndarray, ramp_time: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    for k, label in enumerate("xyz"):
        ax.plot(times, tip_mm[:, k], label=f"u_{label}")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("tip displacement (mm)")
    ax.axvline(ramp_time, color="gray", lw=0.8, ls="--", label="end of ramp")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)
