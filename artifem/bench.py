"""``artifem bench fom`` and ``artifem bench tongue``: step timings to JSON.

Each case (scene x MPI ranks x linear solver) runs in a fresh process,
``mpiexec -n RANKS python -m artifem.bench_worker --scene box|tongue ...``
(the mpiexec beside the running Python), so its peak memory is its own. Both
subcommands share the case loop (:func:`run_cases`), the JSON writing
(:func:`write_report`) and the table (:func:`format_table`); they differ in
the scene and its options:

- ``fom``: a Q1 hex box of tongue size (0.08 x 0.035 x 0.035 m, clamped at
  x = 0, tongue Mooney-Rivlin, density 1040, Rayleigh (40, 0.03), gravity, a
  Blemker-fiber muscle along x in the upper half at excitation 0.3) in named
  sizes; 2 warm-up steps, 10 timed.
- ``tongue``: the ArtiSynth hex tongue at levels 0 (946 nodes) and 1
  (6,699 nodes) running a speech motion (protrusion by default: excitations
  ramp over 0.5 s, then hold); 5 warm-up steps, then 20 timed ones, i.e.
  t = 0.05 ... 0.25 s, inside the ramp where the muscles do work, with the
  tongue's own incompressibility (hard by default, ``--incompressibility
  penalty`` or ``penalty,hard``) and, unless ``--solver`` says otherwise, each
  formulation's own solver (MUMPS for hard, the iterative default for the
  penalty). The JSON carries the seed paper's figure (188.9 ms per step, 2,961
  nodes) as ``reference``.

Every step is semi-implicit backward Euler with dt = 0.01 s through
``Scene.step``. Figures per case: the median over the timed steps of the wall
time per step (MPI barriers around it), of the time in ``FemBody.assemble``
(residual and tangent) and in ``LinearSolver.solve``; ``peak_mb`` is the sum
over ranks of the peak resident memory. Unless already set, OMP_NUM_THREADS
and OPENBLAS_NUM_THREADS are 1, so a case uses as many cores as it has ranks.

One module serves both subcommands: :func:`add_arguments` reads which one from
the name of the parser it is given (``artifem bench tongue`` -> ``tongue``).
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

from artifem.arguments import positive_float, positive_int
from artifem.errors import InputError, InputFileNotFoundError, SolverError

#: Named box sizes (cells along x, y, z) -> about 1,000, 3,000 and 13,000 nodes.
SIZES = {"1k": (15, 7, 7), "3k": (24, 10, 10), "13k": (40, 17, 17)}
#: Targets on 2 cores (ms per step), keyed by size name.
TARGETS = {"3k": 100.0, "13k": 650.0}
TARGET_RANKS = 2
DEFAULT_SOLVER = "cg-gamg-lagged"
CASE_FIELDS = (
    "nodes",
    "elements",
    "ranks",
    "ms_per_step",
    "assembly_ms",
    "solve_ms",
    "peak_mb",
    "solver",
    "iterations",
)
#: The tongue benchmark's defaults and the seed paper's figure (Lloyd et al. 2019).
TONGUE_LEVELS = (0, 1)
TONGUE_STEPS, TONGUE_WARMUP = 20, 5
TONGUE_REFERENCE = {
    "seed_paper_ms_per_step": 188.9,
    "seed_paper_nodes": 2961,
    "machine": "quad-core i7-7700, Pardiso",
}
BENCHMARKS = ("fom", "tongue")
DT = 0.01  # s, the worker's step (artifem.bench_worker.DT)


def _solver_methods() -> tuple[str, ...]:
    # Imported lazily: the CLI builds every parser and should not pull in PETSc.
    from artifem.linear_solver import METHODS

    return METHODS


def parse_sizes(text: str) -> list[tuple[str, tuple[int, int, int]]]:
    """'1k,3k,13k' or '24x10x10' (or a mix) -> [(name, (nx, ny, nz))]."""
    out = []
    for item in (s.strip() for s in text.split(",")):
        if not item:
            continue
        if item in SIZES:
            out.append((item, SIZES[item]))
            continue
        try:
            cells = tuple(int(c) for c in item.lower().split("x"))
        except ValueError:
            cells = ()
        if len(cells) != 3 or min(cells) < 1:
            raise InputError(
                f"--sizes: {item!r} is neither one of {sorted(SIZES)} nor NXxNYxNZ "
                f"with positive integers"
            )
        out.append((item, cells))
    if not out:
        raise InputError("--sizes: no case given")
    return out


def parse_ints(text: str, what: str) -> list[int]:
    try:
        values = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise InputError(f"{what}: expected comma-separated integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise InputError(f"{what}: expected positive integers, got {text!r}")
    return values


def add_fom_arguments(parser) -> None:
    """Arguments of ``artifem bench fom``."""
    _add_arguments(parser, "fom")


def add_tongue_arguments(parser) -> None:
    """Arguments of ``artifem bench tongue``."""
    _add_arguments(parser, "tongue")


def _add_arguments(parser, kind: str) -> None:
    parser.set_defaults(_benchmark=kind)
    parser.add_argument("--out", required=True, type=Path, help="JSON file to write")
    if kind == "tongue":
        parser.add_argument(
            "--levels",
            default=",".join(map(str, TONGUE_LEVELS)),
            help="comma-separated tongue levels: 0 as shipped (946 nodes), "
            "1 split 2x2x2 (6,699 nodes) (default: %(default)s)",
        )
        parser.add_argument(
            "--motion",
            default="protrusion",
            help="speech motion: protrusion, retroflexion, retraction (default: %(default)s)",
        )
        parser.add_argument(
            "--incompressibility",
            default="hard",
            help="comma-separated: hard (element volumes held; "
            "artifem.incompressibility; the tongue's default), penalty "
            "(element penalty 100 C10) (default: %(default)s)",
        )
        steps, warmup = TONGUE_STEPS, TONGUE_WARMUP
        solver_default, solver_help = (
            None,
            f"each formulation's own: mumps for hard, {DEFAULT_SOLVER} for penalty",
        )
    else:
        parser.add_argument(
            "--sizes",
            default="1k,3k,13k",
            help="comma-separated cases: "
            + ", ".join(f"{k}={'x'.join(map(str, v))}" for k, v in SIZES.items())
            + " or NXxNYxNZ cells (default: %(default)s)",
        )
        steps, warmup = 10, 2
        solver_default, solver_help = DEFAULT_SOLVER, DEFAULT_SOLVER
    parser.add_argument(
        "--ranks", default="1,2", help="comma-separated MPI rank counts (default: %(default)s)"
    )
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=steps,
        help="timed steps per case (default: %(default)s)",
    )
    parser.add_argument(
        "--warmup", type=int, default=warmup, help="untimed steps first (default: %(default)s)"
    )
    parser.add_argument(
        "--solver",
        default=solver_default,
        help="linear solver, or a comma-separated list to compare "
        "(mumps, cg-gamg, cg-gamg-lagged, cg-mumps-lagged, cg-hypre; "
        f"default: {solver_help})",
    )
    parser.add_argument(
        "--timeout",
        type=positive_float,
        default=1800.0,
        help="seconds allowed per case (default: %(default)s)",
    )


def find_mpiexec() -> str:
    beside = Path(sys.executable).parent / "mpiexec"
    if beside.exists():
        return str(beside)
    found = shutil.which("mpiexec")
    if found is None:
        raise InputFileNotFoundError(
            f"no mpiexec beside {sys.executable} nor on PATH "
            "(the mpich wheel installs one into the environment's bin/)"
        )
    return found


def worker_command(
    mpiexec: str, ranks: int, scene_args: list[str], solver: str, steps: int, warmup: int
) -> list[str]:
    """``scene_args``: e.g. ['--scene', 'box', '--cells', '24', '10', '10']."""
    return [
        mpiexec,
        "-n",
        str(ranks),
        sys.executable,
        "-m",
        "artifem.bench_worker",
        *scene_args,
        "--solver",
        solver,
        "--steps",
        str(steps),
        "--warmup",
        str(warmup),
    ]


def run_worker(cmd: list[str], timeout: float) -> dict:
    """Run one case; return the worker's JSON or raise RuntimeError with its output."""
    env = dict(os.environ)
    env.setdefault("OMP_NUM_THREADS", "1")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired as exc:
        raise SolverError(f"timed out after {timeout:g} s: {' '.join(cmd)}") from exc
    for line in proc.stdout.splitlines():
        if line.startswith("BENCH_RESULT "):
            return json.loads(line[len("BENCH_RESULT ") :])
    tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-15:])
    raise SolverError(f"exit code {proc.returncode}, no result from: {' '.join(cmd)}\n{tail}")


def machine_info() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "hostname": platform.node(),
        "cpu": cpu,
        "cores": os.cpu_count(),
        "system": f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
    }


def format_table(cases: list[dict], lead: tuple[str, ...] = ()) -> str:
    """Text table of the cases; ``lead``: case fields shown first (e.g. ('level',))."""
    widths = [max(5, len(k)) for k in lead]
    head = " ".join(f"{k:>{w}}" for k, w in zip(lead, widths)) + (" " if lead else "")
    head += (
        f"{'nodes':>6} {'ranks':>5} {'solver':<16} {'ms/step':>8} {'assembly':>8} "
        f"{'solve':>8} {'iters':>5} {'peak MB':>8}"
    )
    rows = [head, "-" * len(head)]
    for c in cases:
        first = " ".join(f"{c.get(k, ''):>{w}}" for k, w in zip(lead, widths)) + (
            " " if lead else ""
        )
        rows.append(
            first + f"{c['nodes']:>6} {c['ranks']:>5} {c.get('solver', ''):<16} "
            f"{c['ms_per_step']:>8.1f} {c['assembly_ms']:>8.1f} {c['solve_ms']:>8.1f} "
            f"{c.get('iterations', 0):>5.0f} {c['peak_mb']:>8.0f}"
        )
    return "\n".join(rows)


def check_targets(cases: list[dict]) -> list[dict]:
    out = []
    for c in cases:
        limit = TARGETS.get(c.get("size"))
        if limit is not None and c["ranks"] == TARGET_RANKS:
            out.append(
                {
                    "size": c["size"],
                    "nodes": c["nodes"],
                    "ranks": c["ranks"],
                    "solver": c.get("solver"),
                    "target_ms_per_step": limit,
                    "ms_per_step": c["ms_per_step"],
                    "met": c["ms_per_step"] <= limit,
                }
            )
    return out


def parse_solvers(text: str) -> list[str]:
    solvers = [s.strip() for s in text.split(",") if s.strip()]
    unknown = [s for s in solvers if s not in _solver_methods()]
    if unknown or not solvers:
        raise InputError(
            f"--solver: unknown {unknown or text!r}; choose from {', '.join(_solver_methods())}"
        )
    return solvers


def parse_levels(text: str) -> list[int]:
    try:
        levels = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        levels = []
    if not levels or any(level not in TONGUE_LEVELS for level in levels):
        raise InputError(
            f"--levels: expected comma-separated levels among "
            f"{', '.join(map(str, TONGUE_LEVELS))}, got {text!r}"
        )
    return levels


def run_cases(
    title: str, plan: list[dict], steps: int, warmup: int, timeout: float, mpiexec: str
) -> tuple[list[dict], list[dict]]:
    """Run each planned case in its own process: (cases, errors).

    A plan item: {"label": str, "scene_args": [...], "ranks": int, "solver": str,
    "fields": {...}} (fields identify the case in the JSON, e.g. {"size": "3k"}).
    """
    from tqdm import tqdm

    cases, errors = [], []
    bar = tqdm(plan, desc=title, unit="case")
    for item in bar:
        r, solver = item["ranks"], item["solver"]
        bar.set_postfix_str(f"{item['label']}, {r} rank(s), {solver}")
        cmd = worker_command(mpiexec, r, item["scene_args"], solver, steps, warmup)
        load_before = os.getloadavg()[0]
        try:
            case = run_worker(cmd, timeout)
        except RuntimeError as exc:
            errors.append({**item["fields"], "ranks": r, "solver": solver, "error": str(exc)})
            tqdm.write(
                f"case {item['label']} / {r} rank(s) / {solver} failed: {exc}", file=sys.stderr
            )
            continue
        case.update(item["fields"])
        # 1-minute load average before and after: other work on the machine skews timings.
        case["loadavg_before"], case["loadavg_after"] = load_before, os.getloadavg()[0]
        cases.append(case)
    bar.close()
    return cases, errors


def write_report(
    out: Path,
    benchmark: str,
    description: str,
    settings: dict,
    cases: list[dict],
    errors: list[dict],
    **extra,
) -> dict:
    """Write the JSON (atomically) and return it."""
    report = {
        "benchmark": benchmark,
        "description": description,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "machine": machine_info(),
        "settings": settings,
        **extra,
        "cases": cases,
    }
    if errors:
        report["errors"] = errors
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(json.dumps(report, indent=2) + "\n")
    tmp.replace(out)
    return report


def _tongue_motions() -> tuple[str, ...]:
    from artifem.models.tongue.model import MOTIONS

    return tuple(MOTIONS)


def _own_solver(incompressibility: str) -> str:
    """The solver TongueConfig chooses for a formulation ("hard" or "penalty")."""
    from artifem.models.tongue.model import HARD, PENALTY, TongueConfig

    formulation = HARD if incompressibility == "hard" else PENALTY
    return TongueConfig(incompressibility=formulation).linear_solver


def run(args) -> int:
    kind = args._benchmark
    ranks = parse_ints(args.ranks, "--ranks")
    solvers = parse_solvers(args.solver) if args.solver is not None else None
    if args.steps < 1 or args.warmup < 0:
        raise InputError("--steps must be >= 1 and --warmup >= 0")
    if kind == "tongue":
        levels = parse_levels(args.levels)
        if args.motion not in _tongue_motions():
            raise InputError(
                f"--motion: unknown {args.motion!r}; choose from {', '.join(_tongue_motions())}"
            )
        kinds = [k.strip() for k in args.incompressibility.split(",") if k.strip()]
        if not kinds or any(k not in ("penalty", "hard") for k in kinds):
            raise InputError(
                f"--incompressibility: expected penalty and/or hard, got {args.incompressibility!r}"
            )
        solvers_of = {inc: solvers or [_own_solver(inc)] for inc in kinds}
        solvers = solvers or list(
            dict.fromkeys(s for listed in solvers_of.values() for s in listed)
        )
    else:
        sizes = parse_sizes(args.sizes)
    mpiexec = find_mpiexec()

    settings = {
        "steps": args.steps,
        "warmup_steps": args.warmup,
        "ranks": ranks,
        "solvers": solvers,
    }
    if kind == "tongue":
        plan = [
            {
                "label": f"level {level}, {inc}",
                "ranks": r,
                "solver": s,
                "fields": {"level": level, "incompressibility": inc},
                "scene_args": [
                    "--scene",
                    "tongue",
                    "--level",
                    str(level),
                    "--motion",
                    args.motion,
                    "--incompressibility",
                    inc,
                ],
            }
            for level in levels
            for inc in kinds
            for r in ranks
            for s in solvers_of[inc]
        ]
    else:
        plan = [
            {
                "label": f"{'x'.join(map(str, cells))} cells",
                "ranks": r,
                "solver": s,
                "fields": {"size": name, "cells": list(cells)},
                "scene_args": ["--scene", "box", "--cells", *map(str, cells)],
            }
            for name, cells in sizes
            for r in ranks
            for s in solvers
        ]
    cases, errors = run_cases(f"bench {kind}", plan, args.steps, args.warmup, args.timeout, mpiexec)

    out = Path(args.out)
    if kind == "tongue":
        settings.update(
            levels=levels,
            motion=args.motion,
            incompressibility=kinds,
            integrator="semi-implicit",
            dt=DT,
            timed_window_s=[
                round(args.warmup * DT, 10),
                round((args.warmup + args.steps) * DT, 10),
            ],
        )
        write_report(
            out,
            "tongue",
            f"semi-implicit backward Euler steps (dt = 0.01 s) of the ArtiSynth hex tongue "
            f"running {args.motion} (excitations ramp over 0.5 s, then hold); "
            f"{args.warmup} warm-up steps, median over the next {args.steps}",
            settings,
            cases,
            errors,
            reference=dict(TONGUE_REFERENCE),
        )
        print(format_table(cases, lead=("level", "incompressibility")))
        ref = TONGUE_REFERENCE
        print(
            f"seed paper: {ref['seed_paper_ms_per_step']} ms/step for its "
            f"{ref['seed_paper_nodes']:,}-node tongue ({ref['machine']})"
        )
    else:
        settings["sizes"] = {n: list(c) for n, c in sizes}
        report = write_report(
            out,
            "fom",
            "semi-implicit backward Euler steps (dt = 0.01 s) of a clamped Q1 hex box, "
            "tongue Mooney-Rivlin + active Blemker fiber; median over timed steps",
            settings,
            cases,
            errors,
            targets=check_targets(cases),
        )
        print(format_table(cases))
        for t in report["targets"]:
            print(
                f"target {t['size']} on {t['ranks']} ranks ({t['solver']}): "
                f"{t['ms_per_step']:.1f} ms "
                f"<= {t['target_ms_per_step']:.0f} ms: {'met' if t['met'] else 'NOT met'}"
            )
    print(f"wrote {out}")
    return 1 if errors else 0
