"""A muscle-driven cantilever: the foundation's demonstration scene.

A 60 x 15 x 15 mm block of tongue tissue (Mooney-Rivlin C10 = 1037 Pa,
C20 = 486 Pa, kappa = 10370 Pa, 1040 kg/m^3, Rayleigh 40 M + 0.03 K) is
clamped at x = 0 and hangs under gravity. Its upper half is a muscle with
fibers along x (Blemker fiber energy); ramping its excitation from 0 to the
target over 0.5 s and holding it until 1 s shortens the top and curls the free
end upward, the way a tongue's longitudinal muscles curl its tip.

``artifem simulate beam --out DIR`` (:mod:`artifem.models.runner`) writes DIR/curl/beam.bp
(VTX), DIR/curl/beam.png (rest, t = 0.5 s, t = 1.0 s), DIR/curl/tip.png and
DIR/curl/simulate.json (with the tip's displacement in mm).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from dolfinx import mesh as dmesh

from artifem.arguments import fraction
from artifem.excitation import ExcitationSchedule
from artifem.fem_body import FemBody
from artifem.linear_solver import DEFAULT_METHOD
from artifem.forms import BlemkerFiber, MooneyRivlin
from artifem.models.runner import Built, Model, command
from artifem.render import render_bodies
from artifem.scene import Scene

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


def build(
    case: str, level: int, integrator: str = "semi-implicit", excitation: float = 1.0
) -> Built:
    """The runner's beam (:mod:`artifem.models.runner`): ``LEVELS[level]`` cells, the top
    muscle ramped to ``excitation``; records the free end's centre."""
    config = BeamConfig(cells=LEVELS[level], excitation=excitation, integrator=integrator)
    scene, body = build_beam(config)
    tip = body.nearest_node((LENGTH, 0.5 * WIDTH, 0.5 * HEIGHT))

    def figures(run) -> dict:
        tip_mm = 1e3 * run.records["tip"]
        return {
            "linear_solver": config.linear_solver,
            "excitation": excitation,
            "tip_displacement_mm": {
                f"t={t:g}": tip_mm[np.argmin(abs(run.times - t))].tolist()
                for t in run.snapshots
                if t > 0
            },
        }

    def render(png, run, shown) -> None:
        render_bodies(
            png,
            [(body.mesh, run.snapshots[t][body.name]) for t in shown],
            scalars="displacement",
            titles=["rest"] + [f"t = {t:g} s" for t in shown[1:]],
            scalar_name="displacement (m)",
            camera="xz",
            show_rest=True,
            window_size=(1500, 500),
        )
        if body.mesh.comm.rank == 0:
            _plot_tip(
                png.with_name("tip.png"), run.times, 1e3 * run.records["tip"], config.ramp_time
            )

    return Built(
        scene,
        record={"tip": lambda s: body.displacement_at([tip])[0]},
        figures=figures,
        render=render,
    )


def _options(group) -> None:
    group.add_argument(
        "--excitation", type=fraction, default=1.0, help="of the top muscle (%(default)s)"
    )


#: level -> cells (x, y, z)
LEVELS = {0: (8, 2, 2), 1: (24, 6, 6), 2: (48, 12, 12)}

MODEL = Model(
    name="beam",
    summary="muscle-driven cantilever beam",
    build=build,
    cases={"curl": "the top muscle ramped over 0.5 s and held: the free end curls up"},
    levels={k: " x ".join(map(str, v)) + " hexahedra" for k, v in LEVELS.items()},
    dt=0.01,
    duration=1.0,
    default_level=1,
    camera="xz",
    options=_options,
)
add_arguments, run = command(MODEL)


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
