"""One benchmark case, run in its own process (``artifem bench fom|tongue``).

    mpiexec -n RANKS python -m artifem.bench_worker --scene box --cells NX NY NZ \
        --solver S --steps N
    mpiexec -n RANKS python -m artifem.bench_worker --scene tongue --level L --motion M --solver S

Scenes (one function each, :data:`SCENES`, returning a :class:`Case`: the
scene, the body and how many steps to skip before timing):

- ``box``: a Q1 hex box of tongue size clamped at x = 0 (tongue
  Mooney-Rivlin, density 1040, Rayleigh (40, 0.03), gravity, a Blemker-fiber
  muscle along x in the upper half at excitation 0.3); 2 warm-up steps.
- ``tongue``: the ArtiSynth hex tongue (``artifem.models.tongue``, level 0
  as shipped or level 1 split 2x2x2) driven by a speech motion (its
  excitations ramp over 0.5 s, then hold); 5 warm-up steps, so the default
  20 timed steps cover t = 0.05 ... 0.25 s, the active part of the ramp.

The case takes ``--warmup`` untimed steps (default: the scene's) and then
``--steps`` timed semi-implicit steps of dt = 0.01 s through
:meth:`Scene.step` (inversion check and controllers included), and prints
one line ``BENCH_RESULT {json}`` on rank 0.

Per step it measures the wall time of ``Scene.step`` (MPI barriers before
and after), and inside it the time spent in ``FemBody.assemble`` (R and K) and
in ``LinearSolver.solve``, each the maximum over ranks. ``peak_mb`` is the sum
over ranks of the peak resident set size of the process.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from typing import NamedTuple

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)

import numpy as np
from mpi4py import MPI

from dolfinx import mesh as dmesh

from artifem.errors import SolverError
from artifem.fem_body import FemBody
from artifem.forms import BlemkerFiber, MooneyRivlin
from artifem.linear_solver import METHODS
from artifem.scene import Scene

#: Box extent in metres (tongue scale); clamped at x = 0, fibers along x.
BOX = (0.08, 0.035, 0.035)
DT = 0.01
DENSITY = 1040.0
RAYLEIGH = (40.0, 0.03)
GRAVITY = (0.0, 0.0, -9.81)
MAX_STRESS = 5.0e3  # Pa, Blemker fiber (peak isometric stress of the model muscle)
EXCITATION = 0.3


def build(comm, cells, box=BOX, excitation=EXCITATION) -> FemBody:
    """The benchmark body: tongue material, clamped at x = 0, muscle in the upper half."""
    nx, ny, nz = cells
    domain = dmesh.create_box(
        comm, [np.zeros(3), np.asarray(box, dtype=float)], [nx, ny, nz], dmesh.CellType.hexahedron
    )
    body = FemBody(
        domain, MooneyRivlin.tongue(), DENSITY, rayleigh=RAYLEIGH, gravity=GRAVITY, name="box"
    )
    # Clamped end: input indices of the nodes at x = 0, gathered from every rank.
    x = domain.geometry.x
    inputs = np.asarray(domain.geometry.input_global_indices)
    local_fixed = inputs[np.isclose(x[:, 0], 0.0, atol=1e-9 * box[0])]
    fixed = np.unique(np.concatenate(comm.allgather(local_fixed)))
    body.fix_nodes(fixed)
    # Muscle: cells whose centroid lies in the upper half (z > H/2), fibers along x.
    tdim = domain.topology.dim
    n_owned = domain.topology.index_map(tdim).size_local
    geom = domain.geometry.dofmaps[0][:n_owned]
    centroid_z = x[geom, 2].mean(axis=1)
    local_cells = np.asarray(domain.topology.original_cell_index)[:n_owned][
        centroid_z > 0.5 * box[2]
    ]
    muscle_cells = np.unique(np.concatenate(comm.allgather(local_cells)))
    body.add_muscle(
        "upper",
        muscle_cells,
        (1.0, 0.0, 0.0),
        BlemkerFiber(max_stress=MAX_STRESS),
        excitation=excitation,
    )
    return body


class Case(NamedTuple):
    """What a case times: ``scene.step(DT)`` moving ``body``."""

    scene: Scene
    body: FemBody
    warmup: int  # steps to skip before timing, unless --warmup says otherwise
    probe: int  # input node whose final displacement is reported
    info: dict  # scene fields for the JSON


def box_scene(comm, solver: str, cells) -> Case:
    """The clamped box of :func:`build`; probe: the node at (L, W, H)."""
    body = build(comm, cells)
    scene = Scene(gravity=GRAVITY, linear_solver=solver)
    scene.add(body)
    n_nodes = body.mesh.geometry.index_map().size_global
    return Case(scene, body, 2, n_nodes - 1, {"cells": list(cells), "box_m": list(BOX)})


def tongue_scene(
    comm, solver: str, level: int, motion: str, incompressibility: str = "penalty"
) -> Case:
    """The ArtiSynth tongue at ``level`` running ``motion``, with its element penalty or the
    hard constraint (``incompressibility``: "penalty" or "hard"); probe: the tip landmark."""
    from artifem.models.tongue.model import DT as TONGUE_DT
    from artifem.models.tongue.model import HARD, MOTIONS, PENALTY, RAMP_TIME, Tongue, TongueConfig

    if TONGUE_DT != DT:
        raise SolverError(
            f"the tongue model's dt ({TONGUE_DT}) differs from the benchmark's ({DT})"
        )
    config = TongueConfig(
        level=level,
        integrator="semi-implicit",
        linear_solver=solver,
        incompressibility=HARD if incompressibility == "hard" else PENALTY,
    )
    tongue = Tongue(config, comm=comm)
    tongue.drive(Tongue.motion(motion))
    return Case(
        tongue.scene,
        tongue.body,
        5,
        tongue.data.landmarks["tip"],
        {
            "level": level,
            "motion": motion,
            "peak_excitations": MOTIONS[motion],
            "ramp_s": RAMP_TIME,
            "incompressibility": incompressibility,
        },
    )


#: scene name -> function(comm, solver, **scene options) -> Case
SCENES = {"box": box_scene, "tongue": tongue_scene}


class _Timed:
    """Wrap a callable and accumulate its wall time (seconds) in ``total``."""

    def __init__(self, fn):
        self.fn, self.total = fn, 0.0

    def __call__(self, *args, **kwargs):
        t0 = time.perf_counter()
        try:
            return self.fn(*args, **kwargs)
        finally:
            self.total += time.perf_counter() - t0


def gather_displacement(body: FemBody) -> np.ndarray | None:
    """Displacement of every input node, ordered by input index (rank 0; None elsewhere)."""
    comm = body.mesh.comm
    geom = body.mesh.geometry
    dofs = body.V.dofmap.list.reshape(-1)
    node_dof = np.empty(geom.x.shape[0], dtype=np.int64)
    node_dof[geom.dofmaps[0].reshape(-1)] = dofs
    u = body.u.x.array.reshape(-1, 3)[node_dof]
    parts = comm.gather((np.asarray(geom.input_global_indices), u), root=0)
    if comm.rank != 0:
        return None
    n = geom.index_map().size_global
    out = np.zeros((n, 3))
    for idx, vals in parts:
        out[idx] = vals
    return out


def run_case(
    comm, case: Case, solver: str, steps: int, warmup: int | None = None, dump: str | None = None
) -> dict | None:
    """Time ``steps`` steps of ``case`` after ``warmup`` (default: the case's) untimed ones."""
    scene, body = case.scene, case.body
    warmup = case.warmup if warmup is None else warmup
    linear = scene.linear_solver_for(body)
    assemble = body.assemble = _Timed(body.assemble)
    solve = linear.solve = _Timed(linear.solve)

    rows = []
    t_start = None
    rest_volume = body.volume()
    vc = body.volume_constraint
    for k in range(warmup + steps):
        if k == warmup:
            t_start = scene.t
        assemble.total = solve.total = 0.0
        halvings = scene.halvings
        comm.Barrier()
        t0 = time.perf_counter()
        scene.step(DT)
        comm.Barrier()
        wall = time.perf_counter() - t0
        if k >= warmup:
            rows.append(
                (
                    wall,
                    comm.allreduce(assemble.total, op=MPI.MAX),
                    comm.allreduce(solve.total, op=MPI.MAX),
                    linear.iterations,
                    scene.halvings - halvings,
                    vc.updates if vc is not None else 0,
                )
            )

    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux
    peak_mb = comm.allreduce(rss_mb, op=MPI.SUM)
    n_nodes = body.mesh.geometry.index_map().size_global
    n_cells = body.mesh.topology.index_map(3).size_global
    probe = body.displacement_at([case.probe])[0]
    volume_change = body.volume() / rest_volume - 1.0
    u_dump = gather_displacement(body) if dump else None
    if comm.rank != 0:
        return None
    if dump:
        np.save(dump, u_dump)
    a = np.asarray(rows, dtype=float)
    ms = 1e3 * a[:, :3]
    return {
        "nodes": int(n_nodes),
        "elements": int(n_cells),
        **case.info,
        "ranks": comm.size,
        "solver": solver,
        "ms_per_step": float(np.median(ms[:, 0])),
        "assembly_ms": float(np.median(ms[:, 1])),
        "solve_ms": float(np.median(ms[:, 2])),
        "other_ms": float(np.median(ms[:, 0] - ms[:, 1] - ms[:, 2])),
        "mean_ms_per_step": float(ms[:, 0].mean()),
        "max_ms_per_step": float(ms[:, 0].max()),
        "iterations": float(np.median(a[:, 3])),
        "max_iterations": int(a[:, 3].max()),
        "peak_mb": float(peak_mb),
        "steps": steps,
        "warmup_steps": warmup,
        "dt": DT,
        "timed_window_s": [round(t_start, 10), round(scene.t, 10)],
        "halvings": int(a[:, 4].sum()),
        "preconditioner_setups": int(linear.setups),
        "iterations_per_step": [int(i) for i in a[:, 3]],
        "pressure_iterations": float(np.median(a[:, 5])),
        "max_pressure_iterations": int(a[:, 5].max()),
        "volume_change": float(volume_change),
        "tip_displacement_m": [float(t) for t in probe],
        "dofs": int(3 * n_nodes),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m artifem.bench_worker", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--scene", choices=sorted(SCENES), default="box")
    parser.add_argument("--cells", type=int, nargs=3, metavar=("NX", "NY", "NZ"), help="box scene")
    parser.add_argument("--level", type=int, choices=(0, 1), default=0, help="tongue scene")
    parser.add_argument("--motion", default="protrusion", help="tongue scene")
    parser.add_argument(
        "--incompressibility", choices=("penalty", "hard"), default="penalty", help="tongue scene"
    )
    parser.add_argument("--solver", choices=METHODS, required=True)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--warmup", type=int, help="untimed steps first (default: the scene's)")
    parser.add_argument(
        "--dump", help="save the final displacement (input node order) to this .npy"
    )
    args = parser.parse_args(argv)
    if args.steps < 1 or (args.warmup is not None and args.warmup < 0):
        parser.error("steps must be >= 1, warmup >= 0")
    if args.scene == "box":
        if args.cells is None or min(args.cells) < 1:
            parser.error("the box scene needs --cells NX NY NZ, each >= 1")
        options = {"cells": tuple(args.cells)}
    else:
        options = {
            "level": args.level,
            "motion": args.motion,
            "incompressibility": args.incompressibility,
        }
    comm = MPI.COMM_WORLD
    case = SCENES[args.scene](comm, args.solver, **options)
    result = run_case(comm, case, args.solver, args.steps, args.warmup, args.dump)
    if comm.rank == 0:
        import dolfinx
        from petsc4py import PETSc

        result["scene"] = args.scene
        result["python"] = sys.version.split()[0]
        result["dolfinx"] = dolfinx.__version__
        result["petsc"] = ".".join(str(v) for v in PETSc.Sys.getVersion())
        print("BENCH_RESULT " + json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
