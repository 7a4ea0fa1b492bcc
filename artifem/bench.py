"""``artifem bench fom``: full-order FEM step timings to JSON.

Each case (box size x MPI ranks x linear solver) runs in a fresh process,
``mpiexec -n RANKS python -m artifem.bench_worker ...`` (the mpiexec beside
the running Python), so its peak memory is its own. The worker builds a Q1
hex box of tongue size (0.08 x 0.035 x 0.035 m, clamped at x = 0, tongue
Mooney-Rivlin, density 1040, Rayleigh (40, 0.03), gravity, a Blemker-fiber
muscle along x in the upper half at excitation 0.3), takes 2 warm-up steps and
then times semi-implicit steps of dt = 0.01 s through ``System.step``.

Figures per case: the median over the timed steps of the wall time per step
(MPI barriers around it), of the time in ``FemBody.assemble`` (residual and
tangent) and in ``LinearSolver.solve``; ``peak_mb`` is the sum over ranks of
the peak resident memory. Unless already set, OMP_NUM_THREADS and
OPENBLAS_NUM_THREADS are 1, so a case uses as many cores as it has ranks.
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

#: Named box sizes (cells along x, y, z) -> about 1,000, 3,000 and 13,000 nodes.
SIZES = {"1k": (15, 7, 7), "3k": (24, 10, 10), "13k": (40, 17, 17)}
#: Targets on 2 cores (ms per step), keyed by size name.
TARGETS = {"3k": 100.0, "13k": 650.0}
TARGET_RANKS = 2
DEFAULT_SOLVER = "cg-gamg-lagged"
CASE_FIELDS = ("nodes", "elements", "ranks", "ms_per_step", "assembly_ms", "solve_ms", "peak_mb")


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
            raise ValueError(f"--sizes: {item!r} is neither one of {sorted(SIZES)} nor NXxNYxNZ "
                             f"with positive integers")
        out.append((item, cells))
    if not out:
        raise ValueError("--sizes: no case given")
    return out


def parse_ints(text: str, what: str) -> list[int]:
    try:
        values = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise ValueError(f"{what}: expected comma-separated integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise ValueError(f"{what}: expected positive integers, got {text!r}")
    return values


def add_arguments(parser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="JSON file to write")
    parser.add_argument("--sizes", default="1k,3k,13k",
                        help=f"comma-separated cases: {', '.join(f'{k}={'x'.join(map(str, v))}' for k, v in SIZES.items())}"
                             " or NXxNYxNZ cells (default: %(default)s)")
    parser.add_argument("--ranks", default="1,2", help="comma-separated MPI rank counts (default: %(default)s)")
    parser.add_argument("--steps", type=int, default=10, help="timed steps per case (default: %(default)s)")
    parser.add_argument("--warmup", type=int, default=2, help="untimed steps first (default: %(default)s)")
    parser.add_argument("--solver", default=DEFAULT_SOLVER,
                        help="linear solver, or a comma-separated list to compare "
                             "(mumps, cg-gamg, cg-gamg-lagged, cg-mumps-lagged, cg-hypre; "
                             "default: %(default)s)")
    parser.add_argument("--timeout", type=float, default=1800.0,
                        help="seconds allowed per case (default: %(default)s)")


def find_mpiexec() -> str:
    beside = Path(sys.executable).parent / "mpiexec"
    if beside.exists():
        return str(beside)
    found = shutil.which("mpiexec")
    if found is None:
        raise FileNotFoundError(f"no mpiexec beside {sys.executable} nor on PATH "
                                "(the mpich wheel installs one into the environment's bin/)")
    return found


def worker_command(mpiexec: str, ranks: int, cells, solver: str, steps: int, warmup: int) -> list[str]:
    return [mpiexec, "-n", str(ranks), sys.executable, "-m", "artifem.bench_worker",
            "--cells", *map(str, cells), "--solver", solver,
            "--steps", str(steps), "--warmup", str(warmup)]


def run_worker(cmd: list[str], timeout: float) -> dict:
    """Run one case; return the worker's JSON or raise RuntimeError with its output."""
    env = dict(os.environ)
    env.setdefault("OMP_NUM_THREADS", "1")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired as exc:
        raise RuntimeError(f"timed out after {timeout:g} s: {' '.join(cmd)}") from exc
    for line in proc.stdout.splitlines():
        if line.startswith("BENCH_RESULT "):
            return json.loads(line[len("BENCH_RESULT "):])
    tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-15:])
    raise RuntimeError(f"exit code {proc.returncode}, no result from: {' '.join(cmd)}\n{tail}")


def machine_info() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"hostname": platform.node(), "cpu": cpu, "cores": os.cpu_count(),
            "system": f"{platform.system()} {platform.release()}", "python": platform.python_version()}


def format_table(cases: list[dict]) -> str:
    head = (f"{'nodes':>6} {'ranks':>5} {'solver':<16} {'ms/step':>8} {'assembly':>8} "
            f"{'solve':>8} {'iters':>5} {'peak MB':>8}")
    rows = [head, "-" * len(head)]
    for c in cases:
        rows.append(f"{c['nodes']:>6} {c['ranks']:>5} {c.get('solver', ''):<16} {c['ms_per_step']:>8.1f} "
                    f"{c['assembly_ms']:>8.1f} {c['solve_ms']:>8.1f} {c.get('iterations', 0):>5.0f} "
                    f"{c['peak_mb']:>8.0f}")
    return "\n".join(rows)


def check_targets(cases: list[dict]) -> list[dict]:
    out = []
    for c in cases:
        limit = TARGETS.get(c.get("size"))
        if limit is not None and c["ranks"] == TARGET_RANKS:
            out.append({"size": c["size"], "nodes": c["nodes"], "ranks": c["ranks"],
                        "solver": c.get("solver"), "target_ms_per_step": limit,
                        "ms_per_step": c["ms_per_step"], "met": c["ms_per_step"] <= limit})
    return out


def run(args) -> int:
    from tqdm import tqdm

    try:
        sizes = parse_sizes(args.sizes)
        ranks = parse_ints(args.ranks, "--ranks")
        solvers = [s.strip() for s in args.solver.split(",") if s.strip()]
        unknown = [s for s in solvers if s not in _solver_methods()]
        if unknown or not solvers:
            raise ValueError(f"--solver: unknown {unknown or args.solver!r}; choose from "
                             f"{', '.join(_solver_methods())}")
        if args.steps < 1 or args.warmup < 0:
            raise ValueError("--steps must be >= 1 and --warmup >= 0")
        mpiexec = find_mpiexec()
    except (ValueError, FileNotFoundError) as exc:
        print(f"artifem bench fom: {exc}", file=sys.stderr)
        return 2

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    plan = [(name, cells, r, s) for name, cells in sizes for r in ranks for s in solvers]
    cases, errors = [], []
    bar = tqdm(plan, desc="bench fom", unit="case")
    for name, cells, r, solver in bar:
        bar.set_postfix_str(f"{'x'.join(map(str, cells))} cells, {r} rank(s), {solver}")
        cmd = worker_command(mpiexec, r, cells, solver, args.steps, args.warmup)
        load_before = os.getloadavg()[0]
        try:
            case = run_worker(cmd, args.timeout)
        except RuntimeError as exc:
            errors.append({"size": name, "cells": list(cells), "ranks": r, "solver": solver,
                           "error": str(exc)})
            tqdm.write(f"case {name} / {r} rank(s) / {solver} failed: {exc}", file=sys.stderr)
            continue
        case["size"] = name
        # 1-minute load average before and after: other work on the machine skews timings.
        case["loadavg_before"], case["loadavg_after"] = load_before, os.getloadavg()[0]
        cases.append(case)
    bar.close()

    report = {
        "benchmark": "fom",
        "description": "semi-implicit backward Euler steps (dt = 0.01 s) of a clamped Q1 hex box, "
                       "tongue Mooney-Rivlin + active Blemker fiber; median over timed steps",
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "machine": machine_info(),
        "settings": {"steps": args.steps, "warmup_steps": args.warmup, "ranks": ranks,
                     "solvers": solvers, "sizes": {n: list(c) for n, c in sizes}},
        "targets": check_targets(cases),
        "cases": cases,
    }
    if errors:
        report["errors"] = errors
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(json.dumps(report, indent=2) + "\n")
    tmp.replace(out)

    print(format_table(cases))
    for t in report["targets"]:
        print(f"target {t['size']} on {t['ranks']} ranks ({t['solver']}): {t['ms_per_step']:.1f} ms "
              f"<= {t['target_ms_per_step']:.0f} ms: {'met' if t['met'] else 'NOT met'}")
    print(f"wrote {out}")
    return 1 if errors else 0
