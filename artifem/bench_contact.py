"""``artifem bench contact``: milliseconds per step against the number of contact rows, to JSON.

Each case is a scene stepped in this process (semi-implicit, h = 10 ms, gravity), a few
steps untimed, then the median over the timed steps of the step's wall time and of its
parts (``Scene.last_solve["seconds"]``: the detection, the constraints' ``row_blocks``;
the mapping, G P and c; the solve, :func:`~artifem.scene.constraints.solve_constrained`
with its active set), with the path the rule took (:func:`~artifem.scene.constraints.use_kkt`),
the trials of the active set and the factorizations of the step (medians, and those of
the first step, from a cold start). Each case is timed
with its reference, the same scene without rows, their steps interleaved (the machine
may be shared: both see the same load); ``ratio_to_no_contact`` is their ratio:

- ``rigid``: a rigid box (0.2 x 0.2 x 0.1 m, 2 kg) resting on a PlaneContact through an
  n x n grid of points on its bottom face (n^2 normal rows; with friction 3 n^2), against
  the same box with no rows (the plane 10 m below: it falls freely);
- ``fem``: a neo-Hookean hex block of ``--fem`` elements (default 21 x 21 x 20, 10,164
  nodes) resting on a PlaneContact through its bottom nodes nearest the centre (N normal
  rows, 3 N with friction), against the same block with no rows; with ``--schur-max``,
  the same step on the path the rule did not take too where the rows are that few or
  fewer (the cases marked ``forced_path``); ``fem-mid``: the same on a 10 x 10 x 6 block
  (847 nodes), where the paths cross;
- ``plate``: a thin block (default 44 x 44 x 4 elements, 10,125 nodes) on all its 2,025
  bottom nodes.

``--quick``: small sizes for the test (seconds), and a check that the sparse KKT path and
the Schur complement give the same velocities and impulses (``agreement``).

``--tongue``: only the ArtiSynth tongue (level 0, 946 nodes, 740 hexahedra, Mooney-Rivlin
with the hard incompressibility, as the model ships; no fixed nodes) dropped from 5 mm
onto a rigid floor (a PlaneContact through its boundary nodes), every step of the drop
timed from rest for ``TONGUE_DURATION`` and interleaved with the same tongue falling
freely; the deepest node below the floor over the run; and, as a cited reference, a
peer's figure for the same kind of scene (``PEER``).

Unless already set, OMP_NUM_THREADS and OPENBLAS_NUM_THREADS are 1.
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

import numpy as np

H = 0.01
G = 9.81
BOX = np.array([0.2, 0.2, 0.1])
#: default sizes: rigid grids n (n^2 points), FEM contact points, the FEM block and plate
RIGID_GRIDS = (4, 8, 16, 24, 32, 45)
FEM_POINTS = (9, 25, 49, 100, 225, 484)
FEM_BLOCK = (21, 21, 20)
#: a mid-size block (847 nodes) for the crossover of the two paths
MID_BLOCK = (10, 10, 6)
MID_POINTS = (9, 25, 49, 121)
PLATE = (44, 44, 4)
QUICK = {"rigid": (3, 6), "fem_points": (9, 36), "fem": (5, 5, 3), "plate": (7, 7, 2)}


def add_arguments(parser) -> None:
    from artifem.arguments import positive_int

    parser.add_argument("--out", required=True, type=Path, help="JSON file to write")
    parser.add_argument(
        "--steps", type=positive_int, default=5, help="timed steps per case (default: %(default)s)"
    )
    parser.add_argument(
        "--warmup", type=positive_int, default=2, help="untimed steps before (default: %(default)s)"
    )
    parser.add_argument(
        "--schur-max",
        type=int,
        default=500,
        help="FEM cases of at most this many rows are also timed on the "
        "path the rule did not take (default: %(default)s; 0: none)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="small sizes (seconds), with the KKT-Schur agreement check",
    )
    parser.add_argument(
        "--tongue",
        action="store_true",
        help="only the tongue dropped on a floor, beside a peer's figure",
    )


@contextlib.contextmanager
def forced_path(path: str | None):
    """The solve's path forced ("kkt" or "schur"; None: the rule's)."""
    from artifem.scene import constraints

    old = constraints.DEFAULT_PATH
    constraints.DEFAULT_PATH = path or "auto"
    try:
        yield
    finally:
        constraints.DEFAULT_PATH = old


def rigid_scene(n: int, mu: float = 0.0, contact: bool = True):
    """A box resting on z = 0 through an n x n grid on its bottom face (or the plane 10 m
    below: no rows)."""
    import artifem as af

    a, b, c = BOX
    inertia = 2.0 / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    box = af.RigidBody("box", 2.0, inertia, position=(0.0, 0.0, c / 2))
    s = np.linspace(-0.5, 0.5, n)
    grid = np.array([[x * a, y * b, -c / 2] for x in s for y in s])
    plane = (0.0, 0.0, 0.0 if contact else -10.0)
    pc = af.PlaneContact(
        box, plane, (0.0, 0.0, 1.0), mu=mu, points=grid, tolerance=1e-4, margin=1e-3
    )
    scene = af.Scene(gravity=(0.0, 0.0, -G))
    scene.add(box, pc)
    return scene, box, pc


def fem_scene(cells, points: int | None = None, mu: float = 0.0, contact: bool = True):
    """A neo-Hookean block of ``cells`` hexahedra (0.2 x 0.2 m, cubic elements' height
    0.2 / nx each) resting on z = 0 through its ``points`` bottom nodes nearest the
    centre (None: all), or with the plane 10 m below (no rows)."""
    import artifem as af
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    nx, ny, nz = cells
    top = BOX[0] / nx * nz
    msh = dmesh.create_box(
        MPI.COMM_SELF,
        [np.zeros(3), np.array([BOX[0], BOX[1], top])],
        [nx, ny, nz],
        dmesh.CellType.hexahedron,
    )
    body = af.FemBody(
        msh, af.NeoHookean.from_young_poisson(1e6, 0.3), 1000.0, rayleigh=(10.0, 1e-3), name="block"
    )
    x = msh.geometry.x
    bottom = np.flatnonzero(np.isclose(x[:, 2], 0.0))
    centre = np.array([BOX[0] / 2, BOX[1] / 2])
    order = np.argsort(np.linalg.norm(x[bottom, :2] - centre, axis=1), kind="stable")
    chosen = bottom[order[:points]] if points is not None else bottom
    nodes = msh.geometry.input_global_indices[chosen]
    plane = (0.0, 0.0, 0.0 if contact else -10.0)
    pc = af.PlaneContact(
        body, plane, (0.0, 0.0, 1.0), mu=mu, points=nodes, tolerance=1e-4, margin=1e-3
    )
    scene = af.Scene(gravity=(0.0, 0.0, -G))
    scene.add(body, pc)
    return scene, body, pc


#: The tongue drop (``--tongue``): its duration (s) and the peer's figure, measured by a
#: peer on this machine and reported in issue 29 (not run here).
TONGUE_DURATION = 0.4
PEER = {
    "tool": "Drake 1.58 (pip)",
    "scene": "a 946-node tetrahedral tongue dropped on a rigid floor",
    "contact": "compliant (the tongue sinks into the floor)",
    "ms_per_step": 164.0,
    "penetration_mm": 2.3,
    "source": "issue 29, measured by a peer on this machine",
}


def tongue_scene(contact: bool = True):
    """The tongue (level 0, as shipped, free) 5 mm above a floor, or 10 m above it."""
    import artifem as af
    from mpi4py import MPI
    from artifem.io.to_dolfinx import to_dolfinx
    from artifem.forms import MooneyRivlin
    from artifem.models.tongue.model import HARD, TongueConfig, load_tongue_data

    config = TongueConfig()
    domain, _ = to_dolfinx(load_tongue_data(0).mesh, MPI.COMM_SELF)
    body = af.FemBody(
        domain,
        MooneyRivlin(config.C10, C20=config.C20, kappa=config.kappa),
        config.density,
        rayleigh=config.rayleigh,
        incompressibility=HARD,
        name="tongue",
    )
    floor = body.V.tabulate_dof_coordinates()[:, 2].min() - (0.005 if contact else 10.0)
    pc = af.PlaneContact(body, (0.0, 0.0, floor), (0.0, 0.0, 1.0), tolerance=1e-5, margin=0.01)
    scene = af.Scene(gravity=(0.0, 0.0, -G), linear_solver=config.linear_solver)
    scene.add(body, pc)
    return scene, body, pc


def tongue_case() -> dict:
    """The tongue drop and its free fall, interleaved from rest (module docstring)."""
    (scene, body, pc), (free, _, _) = tongue_scene(), tongue_scene(contact=False)
    steps = int(round(TONGUE_DURATION / H))
    timed = {"contact": [], "free": []}
    deepest, rows = 0.0, 0
    for k in range(steps):
        for name, sc in (("contact", scene), ("free", free)):
            tic = time.perf_counter()
            sc.step(H)
            timed[name].append(time.perf_counter() - tic)
        deepest = min(deepest, float(pc.distances().min()))
        rows = max(rows, len(scene.contact_forces(pc).normal))
        if (k + 1) % 10 == 0:
            print(
                f"[bench contact] tongue {k + 1}/{steps} steps, "
                f"{1e3 * np.median(timed['contact']):.1f} ms/step",
                flush=True,
            )
    forces = scene.contact_forces(pc)
    weight = body.total_mass() * G
    return {
        "kind": "tongue",
        "label": "tongue dropped on a floor (level 0, 946 nodes)",
        "nodes": int(body.V.dofmap.index_map.size_global),
        "steps": steps,
        "h": H,
        "step_ms": 1e3 * float(np.median(timed["contact"])),
        "no_contact_step_ms": 1e3 * float(np.median(timed["free"])),
        "ratio_to_no_contact": float(np.median(timed["contact"]) / np.median(timed["free"])),
        "max_rows": rows,
        "active_rows_at_end": int(np.count_nonzero(forces.normal)),
        "deepest_below_floor_mm": -1e3 * deepest,
        "tolerance_mm": 1e3 * pc.tolerance,
        "normal_over_weight_at_end": float(forces.normal.sum() / weight),
        "halvings": int(scene.halvings),
        "peer": PEER,
    }


def time_cases(scenes: list, steps: int, warmup: int) -> list[dict]:
    """Medians (ms) of the step and its parts over ``steps`` timed steps after ``warmup``,
    of each (scene, path) of ``scenes``, their steps interleaved (one step of each in
    turn: the cases of one row see the same machine, other processes included)."""
    recs = [
        {
            "step": [],
            "detection": [],
            "mapping": [],
            "solve": [],
            "trials": [],
            "factorizations": [],
            "active": [],
        }
        for _ in scenes
    ]
    for k in range(warmup + steps):
        for (scene, path), rec in zip(scenes, recs):
            with forced_path(path):
                tic = time.perf_counter()
                scene.step(H)
                toc = time.perf_counter()
            if k == 0:
                rec["first"] = (
                    scene.last_solve.get("trials", 0),
                    scene.last_solve.get("factorizations", 0),
                )
            if k < warmup:
                continue
            rec["step"].append(toc - tic)
            info = scene.last_solve
            for part in ("detection", "mapping", "solve"):
                rec[part].append(info.get("seconds", {}).get(part, 0.0))
            rec["trials"].append(info.get("trials", 0))
            rec["factorizations"].append(info.get("factorizations", 0))
            rec["active"].append(info.get("constraint_rows", 0))
    out = []
    for (scene, _), rec in zip(scenes, recs):
        case = {
            f"{k}_ms": 1e3 * float(np.median(rec[k]))
            for k in ("step", "detection", "mapping", "solve")
        }
        case["first_step_trials"], case["first_step_factorizations"] = rec["first"]
        case["trials_per_step"] = float(np.median(rec["trials"]))
        case["factorizations_per_step"] = float(np.median(rec["factorizations"]))
        case["active_rows"] = int(np.median(rec["active"]))
        case["path"] = scene.last_solve.get("path", "none")
        case["masters"] = scene.last_solve.get("masters", 0)
        out.append(case)
    return out


def _rows(contact) -> int:
    return sum(len(b) for b in contact.row_blocks())


def _say(case: dict) -> None:
    mark = "*" if "forced_path" in case else ""
    print(
        f"[bench contact] {case['kind']:7s} {case['label']:28s} rows {case['rows']:5d} "
        f"active {case['active_rows']:5d} {case['path'] + mark:6s} "
        f"{case['step_ms']:9.1f} ms/step, x{case['ratio_to_no_contact']:.2f} "
        f"(detection {case['detection_ms']:.1f}, mapping {case['mapping_ms']:.1f}, "
        f"solve {case['solve_ms']:.1f}; {case['trials_per_step']:g} trials, "
        f"{case['factorizations_per_step']:g} factorizations; first step "
        f"{case['first_step_trials']}, {case['first_step_factorizations']})",
        flush=True,
    )


def _row(kind, label, make, make_ref, steps, warmup, other=False, **extra) -> list[dict]:
    """The case of ``make()`` (the rule's path), the same without rows (``make_ref``) and,
    with ``other``, on the path the rule did not take: interleaved (:func:`time_cases`)."""
    scene, _, pc = make()
    rows = _rows(pc)
    from artifem.scene.constraints import use_kkt

    scenes = [(scene, None), (make_ref()[0], None)]
    if other:
        taken = "kkt" if use_kkt(scene.step_matrix(H), rows) else "schur"
        scenes.append((make()[0], "schur" if taken == "kkt" else "kkt"))
    timed = time_cases(scenes, steps, warmup)
    ref = dict(timed[1])
    cases = []
    for (_, path), t in zip(scenes, timed):
        if t is timed[1]:
            continue
        case = {
            "kind": kind,
            "label": label,
            "rows": rows,
            **extra,
            **t,
            "no_contact_step_ms": ref["step_ms"],
            "ratio_to_no_contact": t["step_ms"] / ref["step_ms"],
        }
        if path is not None:
            case["forced_path"] = path
        _say(case)
        cases.append(case)
    return cases


def agreement(steps: int = 3) -> dict:
    """Largest differences of the velocities and impulses between the KKT path and the Schur
    complement after ``steps`` steps of a small FEM block with friction (all rows unique)
    and of a rigid box on a grid (redundant rows: velocities and total force only; the
    impulses of redundant rows are not unique). Velocities relative to g h, forces to the
    largest normal force (or their total)."""
    out = {}
    for kind, make in (
        ("fem", lambda: fem_scene(QUICK["fem"], None, mu=0.5)),
        ("rigid", lambda: rigid_scene(5, mu=0.5)),
    ):
        runs = {}
        for path in ("kkt", "schur"):
            scene, body, pc = make()
            with forced_path(path):
                for _ in range(steps):
                    scene.step(H)
            v = body.v.x.array.copy() if hasattr(body, "v") else np.asarray(body.twist).copy()
            f = scene.contact_forces(pc)
            runs[path] = (v, f, scene.last_solve["path"])
        (v1, f1, p1), (v2, f2, p2) = runs["kkt"], runs["schur"]
        assert (p1, p2) == ("kkt", "schur"), (p1, p2)
        entry = {
            "paths": [p1, p2],
            "velocity_over_gh": float(np.abs(v1 - v2).max() / (G * H)),
            "total_normal_rel": float(
                abs(f1.normal.sum() - f2.normal.sum()) / max(abs(f2.normal.sum()), 1e-300)
            ),
        }
        if kind == "fem":
            fs = max(np.abs(f2.normal).max(), 1e-300)
            entry["normal_rel"] = float(np.abs(f1.normal - f2.normal).max() / fs)
            entry["friction_rel"] = float(np.abs(f1.friction - f2.friction).max() / fs)
        out[kind] = entry
    return out


def run(args) -> int:
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    import artifem  # noqa: F401  (before dolfinx / petsc4py)
    from artifem.bench import write_report

    if args.tongue:
        tic = time.perf_counter()
        case = tongue_case()
        print(
            f"[bench contact] tongue: {case['step_ms']:.1f} ms/step "
            f"(x{case['ratio_to_no_contact']:.2f} the free fall), deepest "
            f"{case['deepest_below_floor_mm']:.2g} mm below the floor; the peer: "
            f"{PEER['ms_per_step']:g} ms/step, {PEER['penetration_mm']:g} mm",
            flush=True,
        )
        write_report(
            Path(args.out),
            "contact",
            __doc__.split("\n\n")[0],
            {
                "tongue": True,
                "h": H,
                "duration": TONGUE_DURATION,
                "seconds": time.perf_counter() - tic,
            },
            [case],
            [],
        )
        print(f"[bench contact] wrote {args.out}")
        return 0
    quick = args.quick
    grids = QUICK["rigid"] if quick else RIGID_GRIDS
    points = QUICK["fem_points"] if quick else FEM_POINTS
    block = QUICK["fem"] if quick else FEM_BLOCK
    plate = QUICK["plate"] if quick else PLATE
    steps, warmup = args.steps, args.warmup
    cases = []
    tic = time.perf_counter()
    for n in grids:
        for mu in (0.0, 0.5):
            cases += _row(
                "rigid",
                f"{n}x{n} points, mu {mu:g}",
                lambda: rigid_scene(n, mu),
                lambda: rigid_scene(n, mu, contact=False),
                steps,
                warmup,
                points=n * n,
                mu=mu,
            )
    sweeps = [("fem", block, points, True)]
    if not quick:
        sweeps.append(("fem-mid", MID_BLOCK, MID_POINTS, False))
    for kind, cells, pts, friction in sweeps:
        nodes = int(np.prod(np.array(cells) + 1))
        for npts in pts:
            for mu in (0.0, 0.5) if friction and npts == pts[-1] else (0.0,):
                cases += _row(
                    kind,
                    f"{nodes} nodes, {npts} points, mu {mu:g}",
                    lambda: fem_scene(cells, npts, mu),
                    lambda: fem_scene(cells, npts, mu, contact=False),
                    steps,
                    warmup,
                    other=npts * (3 if mu else 1) <= args.schur_max,
                    points=npts,
                    mu=mu,
                    nodes=nodes,
                )
    pnodes = int(np.prod(np.array(plate) + 1))
    cases += _row(
        "plate",
        f"{pnodes} nodes, all bottom",
        lambda: fem_scene(plate, None),
        lambda: fem_scene(plate, None, contact=False),
        steps,
        warmup,
        points=(plate[0] + 1) * (plate[1] + 1),
        mu=0.0,
        nodes=pnodes,
    )
    extra = {}
    if quick:
        print("[bench contact] agreement of the KKT and Schur paths ...", flush=True)
        extra["agreement"] = agreement()
        print(f"[bench contact] {extra['agreement']}", flush=True)
    write_report(
        Path(args.out),
        "contact",
        __doc__.split("\n\n")[0],
        {
            "steps": steps,
            "warmup": warmup,
            "h": H,
            "quick": quick,
            "schur_max": args.schur_max,
            "fem_block": list(block),
            "plate": list(plate),
            "seconds": time.perf_counter() - tic,
        },
        cases,
        [],
        **extra,
    )
    print(f"[bench contact] wrote {args.out}")
    return 0
