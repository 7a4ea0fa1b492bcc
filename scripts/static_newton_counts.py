"""Newton iterations per load step of the static solve on the cases of docs/verification.md
("Static Newton"): the cantilever of tests/test_surface_loads.py under an open follower
pressure, a 10:1 neo-Hookean beam under a follower pressure on its bottom face, a
nearly incompressible (hard) membrane under a dead traction, the tetrahedral cube of
tests/test_incompressibility.py stretched by a prescribed displacement, and the level-0
foot on its floor (a coupled island of contacts, ligaments and muscles).

    OPENBLAS_NUM_THREADS=1 python scripts/static_newton_counts.py [case ...] [--steps=N|auto]
    OPENBLAS_NUM_THREADS=1 python scripts/static_newton_counts.py --json


Each case runs through Scene.solve_static with the scene's default linear solver and
prints the per-increment Newton iteration counts (hard constraint: multiplier updates'
Newton iterations included) or the failure; ``--json`` runs every case and writes
docs/benchmarks/static_newton.json, whose figures docs/verification.md quotes.
"""

import json
import pathlib
import sys
import time

import numpy as np
from mpi4py import MPI

import artifem as af
from dolfinx import mesh as dmesh

from artifem.errors import StepFailed
from artifem.incompressibility import Incompressible
from artifem.scene import Scene

OUT = pathlib.Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "static_newton.json"


def box(n, size):
    return dmesh.create_box(
        MPI.COMM_SELF,
        [np.zeros(3), np.array(size, dtype=float)],
        list(n),
        dmesh.CellType.hexahedron,
    )


def cantilever(p):
    """tests/test_surface_loads.py cantilever(): 1 x 0.2 x 0.2, E = 1e5, nu = 0.3, open
    follower pressure p on the top face."""
    beam = af.FemBody(
        box((10, 2, 2), (1.0, 0.2, 0.2)), af.NeoHookean.from_young_poisson(1e5, 0.3), 1000.0
    )
    beam.fix_nodes(beam.find_nodes(lambda x: x[0] < 1e-12))
    beam.add_pressure(p, where=lambda x: np.isclose(x[2], 0.2))
    return beam


def long_beam(p, n=(20, 2, 2)):
    """10 x 1 x 1 neo-Hookean (E = 10, nu = 0.3), clamped at x = 0, follower pressure p on
    its bottom face z = 0."""
    beam = af.FemBody(box(n, (10.0, 1.0, 1.0)), af.NeoHookean.from_young_poisson(10.0, 0.3), 1.0)
    beam.fix_nodes(beam.find_nodes(lambda x: x[0] < 1e-12))
    beam.add_pressure(p, where=lambda x: np.isclose(x[2], 0.0))
    return beam


def membrane(n, traction=40.0, hard=True):
    """1 x 1 x 0.05 plate (n x n x 1 hexahedra), neo-Hookean mu = 1e3 (nu = 0.3 on its own)
    made incompressible by the hard constraint (kappa = 10 mu; ``hard=False``: left
    compressible), clamped on the edges x = 0 and x = 1, dead traction (0, 0, -traction)
    on the top face."""
    E, nu = 2.6e3, 0.3
    hard = dict(incompressibility=Incompressible(kappa=10 * E / 2.6)) if hard else {}
    body = af.FemBody(
        box((n, n, 1), (1.0, 1.0, 0.05)), af.NeoHookean.from_young_poisson(E, nu), 1000.0, **hard
    )
    body.fix_nodes(body.find_nodes(lambda x: (x[0] < 1e-12) | (x[0] > 1 - 1e-12)))
    body.add_traction((0.0, 0.0, -traction), where=lambda x: np.isclose(x[2], 0.05))
    return body


def stretched_tets(stretch=1.3):
    """tests/test_incompressibility.py's unit cube (3 x 3 x 3 x 6 tetrahedra, neo-Hookean
    mu = lambda = 1e3, hard incompressibility kappa = 100 mu, nodal pressure) between the
    symmetry planes x = y = z = 0, its face x = 1 prescribed to x = ``stretch``."""
    domain = dmesh.create_box(
        MPI.COMM_SELF, [np.zeros(3), np.ones(3)], [3, 3, 3], dmesh.CellType.tetrahedron
    )
    body = af.FemBody(
        domain,
        af.NeoHookean(1e3, 1e3),
        1000.0,
        incompressibility=Incompressible(kappa=1e5, tol=1e-9),
    )
    for k in range(3):
        body.fix_nodes(body.find_nodes(lambda x, k=k: np.isclose(x[k], 0.0)), components=(k,))
    body.fix_nodes(
        body.find_nodes(lambda x: np.isclose(x[0], 1.0)),
        components=(0,),
        displacement=lambda x: np.vstack([(stretch - 1) * x[0], 0 * x[1], 0 * x[2]]),
    )
    return body


def run(body, load_steps, **options):
    """Solve; a dict of the per-increment counts, the Newton iterations spent on failed
    increments, the load factors reached and min u_z (or the failure)."""
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(body)
    try:
        counts = scene.solve_static(load_steps=load_steps, **options)
    except StepFailed as e:
        return {"load_steps": load_steps, "failed_with": str(e)[:200]}
    u = body.u.x.array.reshape(-1, 3)
    return {
        "load_steps": load_steps,
        "counts": list(counts),
        "failed": counts.failed,
        "total": sum(counts) + counts.failed,
        "max": max(counts),
        "factors": counts.factors,
        "min_uz": float(u[:, 2].min()),
    }


def foot(load):
    """The level-0 foot (models/foot, the test's scene) on the floor: unloaded (its own
    weight) or with ``load`` newtons down the tibia at once."""
    from artifem.models.foot.model import build_foot

    return build_foot(0, load=load, ramp=0.0)


def run_scene(foot_scene, load_steps, **options):
    """run() for a whole scene (the coupled island's Newton), with the floor's balance:
    its normal force over the weight and the load it carries, and the solve's seconds."""
    tic = time.perf_counter()
    try:
        counts = foot_scene.scene.solve_static(load_steps=load_steps, **options)
    except StepFailed as e:
        return {
            "load_steps": load_steps,
            "failed_with": str(e)[:200],
            "seconds": time.perf_counter() - tic,
        }
    seconds = time.perf_counter() - tic
    weight = 9.81 * (
        foot_scene.tissue.total_mass() + sum(b.mass for b in foot_scene.bones.values())
    )
    load = foot_scene.load.force if foot_scene.load is not None else 0.0
    normal = float(foot_scene.scene.contact_forces(foot_scene.floor).normal.sum())
    return {
        "load_steps": load_steps,
        "counts": list(counts),
        "failed": counts.failed,
        "total": sum(counts) + counts.failed,
        "max": max(counts),
        "factors": counts.factors,
        "floor_balance": normal / (weight + load) - 1.0,
        "seconds": seconds,
    }


def first_increment(n=16, traction=10.0, fractions=(16, 64)):
    """Why the membrane's first increment is hard: min u_z of the first Newton step from
    the flat plate (its linear, bending response to the first quarter of the load) and
    of the equilibrium under that load (a stretched membrane); and the first increment's
    Newton iterations when it is 1/16 or 1/64 of the 40 Pa load instead (``smaller``:
    whether smaller load steps make it easier)."""
    body = membrane(n, traction)
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(body)
    solver = scene.linear_solver_for(body)
    body.load_factor.value = 1.0
    body.assemble(tangent=True, diag=1.0)
    rhs = body.R.copy()
    body.zero_fixed(rhs)
    rhs.scale(-1.0)
    step = rhs.duplicate()
    solver.solve(body.K, rhs, step)
    body.zero_fixed(step)
    counts = scene.solve_static(load_steps=1)
    smaller = {}
    for k in fractions:  # the first of k load steps of the full load
        plate = Scene(gravity=(0.0, 0.0, 0.0))
        plate.add(membrane(n, 40.0 / k))
        smaller[f"1/{k}"] = plate.solve_static(load_steps=1)[0]
    return {
        "mesh": n,
        "traction": traction,
        "linear_step_min_uz": float(step.array.reshape(-1, 3)[:, 2].min()),
        "equilibrium_min_uz": float(body.u.x.array.reshape(-1, 3)[:, 2].min()),
        "counts": list(counts),
        "first_increment_at_a_fraction_of_40_pa": smaller,
    }


def render(result) -> str:
    """The table cell of docs/verification.md: the counts (runs of equal counts as
    'c (xk)'), their max and the iterations in all, failed increments included."""
    if "counts" not in result:
        return "fails"
    runs = []
    for c in result["counts"]:
        if runs and runs[-1][0] == c:
            runs[-1][1] += 1
        else:
            runs.append([c, 1])
    text = ", ".join(f"{c} (x{k})" if k > 2 else ", ".join([str(c)] * k) for c, k in runs)
    failed = f", {result['failed']} in failed increments" if result["failed"] else ""
    return f"{text} (max {result['max']}; {result['total']} in all{failed})"


CASES = {
    "cantilever150": lambda s: run(cantilever(150.0), s or 12),
    "cantilever600": lambda s: run(cantilever(600.0), s or 12),
    "cantilever1200": lambda s: run(cantilever(1200.0), s or 12),
    "beam5": lambda s: run(long_beam(0.004), s or 5),
    "beam20": lambda s: run(long_beam(0.004), s or 20),
    "beam_auto": lambda s: run(long_beam(0.004), s or "auto"),
    "beam_auto_max6": lambda s: run(long_beam(0.004), s or "auto", max_iterations=6),
    "beam_tenth": lambda s: run(long_beam(0.0004), s or 5),
    "membrane8": lambda s: run(membrane(8), s or 4),
    "membrane8_auto": lambda s: run(membrane(8), s or "auto"),
    "membrane16": lambda s: run(membrane(16), s or 4),
    "membrane16_auto": lambda s: run(membrane(16), s or "auto"),
    "membrane16_auto_max6": lambda s: run(membrane(16), s or "auto", max_iterations=6),
    "membrane32": lambda s: run(membrane(32), s or 4),
    "membrane32_auto": lambda s: run(membrane(32), s or "auto"),
    "membrane16_compressible": lambda s: run(membrane(16, hard=False), s or 4),
    "tet_stretch": lambda s: run(stretched_tets(), s or 2),
    "tet_stretch_auto": lambda s: run(stretched_tets(), s or "auto"),
    "foot_unloaded": lambda s: run_scene(foot(0.0), s or 1),
    "foot_standing": lambda s: run_scene(foot(0.5 * 70.0 * 9.81), s or 1),
    "foot_standing_auto": lambda s: run_scene(foot(0.5 * 70.0 * 9.81), s or "auto"),
}

if __name__ == "__main__":
    names = [a for a in sys.argv[1:] if not a.startswith("--")] or list(CASES)
    steps = [a for a in sys.argv[1:] if a.startswith("--steps=")]
    steps = steps[0].split("=")[1] if steps else None
    if steps is not None and steps != "auto":
        steps = int(steps)
    results = {}
    for name in names:
        results[name] = CASES[name](steps)
        print(f"{name}: {render(results[name])}", flush=True)
    if "--json" in sys.argv:
        results["membrane16_first_increment"] = first_increment()
        print(f"membrane16_first_increment: {results['membrane16_first_increment']}")
        if steps is not None or set(names) != set(CASES):
            sys.exit("--json writes every case at its own load steps: give no case or --steps")
        OUT.write_text(json.dumps(results, indent=1) + "\n")
        print(f"wrote {OUT}")
