"""``artifem bench reduced``: the reduced tongue's step against its floating-point work, to JSON.

The tongue reduced as ``artifem study tongue`` reduces it (trained POD of r vectors, m
trained points, the paper's training: each exciter alone; the reductor's stages cached in
``--cache``) runs the protrusion motion (1 s, dt = 10 ms) in its scene on one BLAS
thread, every step timed. At the last state each part of the step is then timed alone
(median of repeats):

- ``stresses``: psi, P and A at the m points: the fused kernels and their packing
  (:class:`~artifem.reduction.stress_kernel.PointStresses`);
- ``tangent``: K~ = sum_p w_p D_p^T A_p D_p (+ a hard body's constraint terms);
- ``force``: f~ = -sum_p w_p D_p^T vec(P_p) + f~_ext;
- ``kinematics``: vec(H) = vec(H_bar) + D q;
- ``rest``: the step minus those: the scene, the integrator, the r x r solve, the
  health check.

Floating-point work per step: the kernels' operations counted in the C code FFCx
generates for them (+, -, *, / and each call of a math function as one operation; a
statement in a loop counted once per iteration) times their points; the algebra's by
formula: 2 (9 m) r for D q and for D^T (w P), 81 m for w A, 2 (81 r) m for A D,
2 (9 m) r^2 for D^T (A D), 2/3 r^3 for the r x r LU solve. GFLOP/s = work / time.
"""

from __future__ import annotations

import os
import re
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from artifem.arguments import positive_int

#: The issue's target for r = 20, m = 300 (ms per step) and the paper's figures.
TARGET_MS = 0.3
_LOOP = re.compile(r"for \(int \w+ = 0; \w+ < (\d+); \+\+\w+\)")
_CALL = re.compile(
    r"\b(pow|exp|expm1|log|log1p|sqrt|cbrt|fabs|sin|cos|tan|atan2?|acos|asin|"
    r"fmin|fmax|cosh|sinh|tanh)\s*\("
)
_INDEX = re.compile(r"\[[^\[\]]*\]")
_UNARY = re.compile(r"(^|[=(,?:*/+\-])\s*-")
_EXPONENT = re.compile(r"(\d)[eE][+-](\d)")


def count_flops(c_source: str) -> int:
    """Arithmetic operations of the ``tabulate_tensor`` function of an FFCx C source
    (module docstring)."""
    start = c_source.index("void tabulate_tensor")
    body = c_source[c_source.index("{", start) + 1 :]
    count, multipliers, pending = 0, [1], 1
    for line in body.splitlines():
        line = line.strip()
        loop = _LOOP.match(line)
        if loop:
            pending = int(loop.group(1))
            continue
        if line == "{":
            multipliers.append(multipliers[-1] * pending)
            pending = 1
            continue
        if line == "}":
            multipliers.pop()
            if not multipliers:  # the function's end
                break
            continue
        if "=" not in line or line.startswith(("static", "//")):
            continue
        lhs, _, rhs = line.partition("=")
        while _INDEX.search(rhs):
            rhs = _INDEX.sub("", rhs)
        rhs = _EXPONENT.sub(r"\1e\2", rhs)  # 1e-05: a literal, not a minus
        calls = len(_CALL.findall(rhs))
        rhs = _UNARY.sub(r"\1", rhs.replace("==", " ").replace("<=", " ").replace(">=", " "))
        ops = (
            sum(rhs.count(op) for op in "+-*/")
            + calls
            + (lhs.rstrip()[-1:] in ("+", "-", "*", "/"))
        )
        count += ops * multipliers[-1]
    return count


def kernel_flops(kernel) -> int:
    """Operations per point of a :class:`~artifem.reduction.stress_kernel.StressKernel`."""
    import ffcx.options
    from ffcx.compiler import compile_ufl_objects

    code, _ = compile_ufl_objects([kernel.ufl_expression], options=ffcx.options.get_options())
    return count_flops(code[1])


def _median_ms(f, repeats: int) -> float:
    f()
    times = []
    for _ in range(repeats):
        tic = time.perf_counter()
        f()
        times.append(time.perf_counter() - tic)
    return 1e3 * float(np.median(times))


def measure(
    level: int = 0,
    incompressibility: str = "penalty",
    r: int = 20,
    m: int = 300,
    cache: Path | None = None,
    repeats: int = 300,
    quick: bool = False,
) -> dict:
    """The figures of one reduced tongue (module docstring); ``quick``: the training of
    ``artifem study tongue --quick`` (a smoke test, not figures to quote)."""
    from threadpoolctl import threadpool_limits

    from artifem.models.tongue.model import DT, DURATION, Tongue
    from artifem.models.tongue.study import StudyConfig, TongueStudy, quick_config
    from artifem.reduction.reductor import Basis, Points

    config = replace(
        quick_config(level) if quick else StudyConfig(level=level),
        incompressibility=incompressibility,
        pod_r=r,
        points=(m,),
        held_out=0,
    )
    with tempfile.TemporaryDirectory() as out:
        study = TongueStudy(config, Path(out), cache or Path(out) / "cache")
        reduced = study.reductor.reduce(
            Basis("pod", r),
            Points(
                m,
                tol=config.cubature_tol,
                growth=config.cubature_growth,
                training_states=config.force_snapshots,
            ),
        )
    scene = reduced.scene()
    body = scene.reduced_bodies[0]
    reduced.model.drive(scene, Tongue.motion("protrusion"))
    steps = int(round(DURATION / DT))
    with threadpool_limits(1):
        times = []
        for _ in range(steps):
            tic = time.perf_counter()
            scene.step(DT)
            times.append(time.perf_counter() - tic)
        step_ms = 1e3 * float(np.median(times[1:]))
        H = body._H
        parts = {"stresses": _median_ms(lambda: body._stresses(H), repeats)}
        body._evaluate()
        parts["tangent"] = _median_ms(body.tangent, repeats)
        parts["force"] = _median_ms(body.force, repeats)
        parts["kinematics"] = _median_ms(lambda: body.set_q(body.q), repeats)
        body._evaluate()
        step_again = _median_ms(lambda: scene.step(DT), repeats)
    parts["rest"] = max(step_again - sum(parts.values()), 0.0)
    rr, mm = body.r, body.m
    kernels = [
        {"points": k.n, "fields": len(k.slots), "flops_per_point": kernel_flops(k)}
        for k in body._stresses.kernels
    ]
    flops = {
        "stresses": sum(k["points"] * k["flops_per_point"] for k in kernels),
        "tangent": 81 * mm + 2 * 81 * rr * mm + 2 * 9 * mm * rr * rr,
        "force": 2 * 9 * mm * rr,
        "kinematics": 2 * 9 * mm * rr,
        "rest": int(round(2 / 3 * rr**3)),
    }
    return {
        "level": level,
        "incompressibility": incompressibility,
        "r": rr,
        "m": mm,
        "nodes": int(body.full.V.dofmap.index_map.size_local),
        "training_runs": reduced.training["runs"],
        "ms_per_step": step_ms,
        "ms_per_step_at_rest_of_run": step_again,
        "max_step_over_median": float(max(times[1:]) * 1e3 / step_ms),
        "parts": {
            name: {
                "ms": ms,
                "flops": int(flops[name]),
                "gflops_per_s": flops[name] / (ms * 1e6) if ms > 0 else None,
            }
            for name, ms in parts.items()
        },
        "kernels": kernels,
        "flops_per_step": int(sum(flops.values())),
        "gflops_per_s": sum(flops.values()) / (step_again * 1e6),
        "target_ms": TARGET_MS if (rr, mm) == (20, 300) else None,
        "met": step_ms <= TARGET_MS if (rr, mm) == (20, 300) else None,
    }


def add_arguments(parser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="JSON file to write")
    parser.add_argument("--level", type=int, choices=(0, 1), default=0)
    parser.add_argument(
        "--incompressibility",
        default="penalty,hard",
        help="comma-separated: penalty, hard (default: %(default)s)",
    )
    parser.add_argument(
        "--r", type=positive_int, default=None, help="POD size (default 20; --quick: 8)"
    )
    parser.add_argument(
        "--points",
        type=positive_int,
        default=None,
        help="trained integration points (default 300; --quick: 120)",
    )
    parser.add_argument(
        "--repeats",
        type=positive_int,
        default=300,
        help="repeats of each part's timing (default 300)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a smoke test: the training of 'artifem study tongue --quick' "
        "(its --cache is reused), 20 repeats",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=None,
        help="the reductor's cache (default: a temporary one; the tongue "
        "study's OUT/cache can be given)",
    )


def run(args) -> int:
    from artifem.errors import InputError

    kinds = [k.strip() for k in args.incompressibility.split(",") if k.strip()]
    if not kinds or set(kinds) - {"penalty", "hard"}:
        raise InputError(
            f"--incompressibility: choose from penalty, hard; got {args.incompressibility!r}"
        )
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    from artifem.bench import write_report

    r = args.r or (8 if args.quick else 20)
    points = args.points or (120 if args.quick else 300)
    cases = []
    for kind in kinds:
        print(
            f"[bench reduced] level {args.level}, {kind}: training (cached) and timing ...",
            flush=True,
        )
        case = measure(
            args.level, kind, r, points, args.cache, 20 if args.quick else args.repeats, args.quick
        )
        cases.append(case)
        print(
            f"[bench reduced] {kind}: {case['ms_per_step']:.3f} ms per step, "
            f"{case['flops_per_step'] / 1e6:.2f} MFLOP, {case['gflops_per_s']:.2f} GFLOP/s",
            flush=True,
        )
    write_report(
        Path(args.out),
        "reduced",
        __doc__.split("\n\n")[0],
        {
            "level": args.level,
            "r": r,
            "points": points,
            "repeats": args.repeats,
            "quick": args.quick,
        },
        cases,
        [],
    )
    print(f"[bench reduced] wrote {args.out}")
    return 0
