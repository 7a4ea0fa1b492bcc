"""Mesh convergence of the tongue motions: level 0 (as shipped) against level 1 (2x2x2 split).

    python -m artifem.models.tongue.convergence [--motions ...] [--out DIR]

Runs each speech motion (semi-implicit, dt = 0.01 s, 1.0 s) on both fidelity
levels, with the element penalty (:data:`~artifem.models.tongue.model.PENALTY`; the
same table with the hard incompressibility, the tongue's default, is in
docs/incompressibility.md, ``artifem study incompressibility``), and compares the displacements of
the tip, top and base landmarks at
the end of the ramp (t = 0.5 s) and at the end (t = 1.0 s). The landmarks are
nodes of the shipped mesh, which level 1 keeps, so the same material point is
compared. Writes docs/tongue_convergence.md and docs/tongue_convergence.json.

Reading the difference: with a per-level error e_l = C h_l^p, halving h gives
d0 - d1 = e0 (1 - 2^-p), so level 0's error is |d0 - d1| / (1 - 2^-p): 4/3 of
the difference for the asymptotic Q1 rate p = 2, twice it for p = 1 (a coarse,
pre-asymptotic mesh). Level 1's own error is about a third (p = 2) to the
whole (p = 1) of the difference.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from artifem.errors import SolverError
from artifem.models.tongue.hard_cases import run_built
from artifem.models.tongue.model import (
    DT,
    DURATION,
    MOTIONS,
    PENALTY,
    RAMP_TIME,
    Tongue,
    TongueConfig,
)

DOCS = Path(__file__).resolve().parents[2] / "docs"
LANDMARK_NAMES = ("tip", "top", "base")


def run_motions(
    level: int, motions=tuple(MOTIONS), integrator: str = "semi-implicit", progress: bool = False
) -> dict[str, dict]:
    """motion -> run_built result (landmarks in mm at t = 0.5 s and 1.0 s) on one level,
    with the element penalty."""
    tongue = Tongue(TongueConfig(level=level, integrator=integrator, incompressibility=PENALTY))
    out = {}
    for motion in motions:
        tongue.reset()
        tongue.drive(Tongue.motion(motion))
        result = run_built(
            tongue,
            DT,
            DURATION,
            record_times=(RAMP_TIME,),
            progress=f"level {level} {motion}" if progress else None,
        )
        if result["outcome"] != "finished":
            raise SolverError(
                f"tongue {motion} at level {level} did not finish: "
                f"{result.get('error') or result.get('inversion')}"
            )
        result["nodes"] = int(tongue.data.mesh.points.shape[0])
        out[motion] = result
    return out


def landmark_mm(result: dict, landmark: str, t: float) -> np.ndarray:
    """Displacement (mm) of a landmark at t (the end of the run or a recorded time)."""
    if abs(t - DURATION) < 1e-9:
        return np.array(result["landmarks_mm"][landmark])
    return np.array(result["landmarks_mm_at"][f"{t:g}"][landmark])


def compare(level0: dict, level1: dict) -> list[dict]:
    rows = []
    for motion in level0:
        for t in (RAMP_TIME, DURATION):
            for name in LANDMARK_NAMES:
                d0, d1 = landmark_mm(level0[motion], name, t), landmark_mm(level1[motion], name, t)
                diff = float(np.linalg.norm(d0 - d1))
                rows.append(
                    {
                        "motion": motion,
                        "t": t,
                        "landmark": name,
                        "level0_mm": np.round(d0, 3).tolist(),
                        "level1_mm": np.round(d1, 3).tolist(),
                        "level0_norm_mm": round(float(np.linalg.norm(d0)), 3),
                        "level1_norm_mm": round(float(np.linalg.norm(d1)), 3),
                        "difference_mm": round(diff, 3),
                        "relative": round(diff / max(float(np.linalg.norm(d1)), 1e-12), 4),
                    }
                )
    return rows


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in v) + ")"


def write_docs(rows: list[dict], level0: dict, level1: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "tongue_convergence.json").write_text(
        json.dumps(
            {
                "units": {
                    "level0_mm": "mm, displacement from rest (x, y, z)",
                    "difference_mm": "|d0 - d1| (mm)",
                    "relative": "|d0 - d1| / |d1|",
                },
                "integrator": "semi-implicit",
                "dt": DT,
                "duration": DURATION,
                "nodes": {
                    "level0": next(iter(level0.values()))["nodes"],
                    "level1": next(iter(level1.values()))["nodes"],
                },
                "runs": {"level0": level0, "level1": level1},
                "rows": rows,
            },
            indent=2,
        )
    )
    final = [r for r in rows if r["t"] == DURATION]
    worst = max(final, key=lambda r: r["difference_mm"])
    worst_rel = max(final, key=lambda r: r["relative"])
    tip = {r["motion"]: r for r in final if r["landmark"] == "tip"}
    lines = [
        "# Tongue: mesh convergence, level 0 against level 1",
        "",
        "Written by `python -m artifem.models.tongue.convergence` "
        "(models/tongue/convergence.py); raw figures in `tongue_convergence.json`.",
        "",
        f"Each motion of the seed paper (ramp over 0.5 s, hold to 1.0 s) is run with the "
        f"semi-implicit integrator, dt = {DT} s, on level 0 (the mesh as shipped, "
        f"{next(iter(level0.values()))['nodes']} nodes) and level 1 (every hexahedron split "
        f"2x2x2, {next(iter(level1.values()))['nodes']} nodes). Landmark displacements are "
        "from rest, in mm, (x, y, z); the difference is |d0 - d1| and the relative "
        "difference |d0 - d1| / |d1|.",
        "",
        "| motion | t (s) | landmark | level 0 (mm) | level 1 (mm) | \\|d0\\| mm | \\|d1\\| mm "
        "| difference mm | relative |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['motion']} | {r['t']:g} | {r['landmark']} | {_vec(r['level0_mm'])} | "
            f"{_vec(r['level1_mm'])} | {r['level0_norm_mm']:.2f} | "
            f"{r['level1_norm_mm']:.2f} | {r['difference_mm']:.2f} | "
            f"{100 * r['relative']:.0f} % |"
        )
    lines += [
        "",
        "Run cost (median ms per step, semi-implicit, serial): "
        + ", ".join(
            f"{m} {level0[m]['ms_per_step']:.0f} (level 0) / {level1[m]['ms_per_step']:.0f} "
            f"(level 1)"
            for m in level0
        )
        + ".",
        "",
        "## What the difference says",
        "",
        "If the error of a level falls as h^p, halving h gives d0 - d1 = e0 (1 - 2^-p): "
        "level 0's error is 4/3 of the difference for the asymptotic rate of Q1 elements "
        "(p = 2) and twice it if the coarse mesh is still pre-asymptotic (p = 1); level 1's "
        "own error is then between a third of the difference and the whole of it. A single "
        "pair of meshes cannot measure p, so read the difference as an estimate of level "
        "0's discretization error to within a factor 4/3 to 2.",
        "",
        f"At t = 1.0 s the largest difference is {worst['difference_mm']:.2f} mm "
        f"({worst['motion']}, {worst['landmark']}, {100 * worst['relative']:.0f} % of "
        f"|d1| = {worst['level1_norm_mm']:.2f} mm); the largest relative difference is "
        f"{100 * worst_rel['relative']:.0f} % ({worst_rel['motion']}, {worst_rel['landmark']}). "
        "The tip differs by "
        + ", ".join(
            f"{r['difference_mm']:.2f} mm ({100 * r['relative']:.0f} %) in {m}"
            for m, r in tip.items()
        )
        + ".",
        "",
        f"What it implies: the level 0 - level 1 differences at t = 1.0 s lie between "
        f"{min(r['difference_mm'] for r in final):.2f} and {worst['difference_mm']:.2f} mm, "
        "about 1 mm whatever the size of the motion, and they are the same at t = 0.5 s and "
        "1.0 s (the damped tongue is close to equilibrium in both). Level 0's discretization "
        "error at the landmarks is therefore about "
        f"{4 / 3 * min(r['difference_mm'] for r in final):.1f}"
        f"-{2 * worst['difference_mm']:.1f} mm (4/3 to 2 times the difference) and level 1's "
        f"about {min(r['difference_mm'] for r in final) / 3:.1f}-{worst['difference_mm']:.1f} mm. "
        "Relative to the motion this is small for the large displacements (retroflexion and "
        "retraction tips: a few %) and large for the small ones (protrusion, which moves the "
        "landmarks by 4-8 mm: 14-24 %; the retroflexion base: over 30 %). Level 0 thus "
        "resolves the shape of the large motions, but a protrusion figure from it carries "
        "an error of order 1-2 mm; level 1 systematically moves protrusion's landmarks "
        "further (|d1| > |d0| for all three), as a stiffer coarse mesh would predict. The "
        "comparisons to the seed paper's millimetre-scale figures should use level 1, or "
        "quote level 0 with this error.",
        "",
    ]
    (out / "tongue_convergence.md").write_text("\n".join(lines))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--motions", nargs="+", default=list(MOTIONS), choices=list(MOTIONS))
    parser.add_argument("--out", type=Path, default=DOCS)
    parser.add_argument(
        "--rewrite",
        action="store_true",
        help="only rewrite the .md from the existing .json (no runs)",
    )
    args = parser.parse_args(argv)
    if args.rewrite:
        data = json.loads((args.out / "tongue_convergence.json").read_text())
        level0, level1 = data["runs"]["level0"], data["runs"]["level1"]
        write_docs(compare(level0, level1), level0, level1, args.out)
        print(f"rewrote {args.out / 'tongue_convergence.md'}")
        return 0
    runs = {}
    for level in (0, 1):
        print(f"level {level}: {', '.join(args.motions)} ...", flush=True)
        runs[level] = run_motions(level, args.motions, progress=True)
        for motion, r in runs[level].items():
            print(
                f"  {motion}: tip {r['landmarks_mm']['tip']} mm, "
                f"{r['ms_per_step']:.0f} ms/step, "
                f"{r['wall_s']:.0f} s, min det F {r['min_det_F']:.3f}",
                flush=True,
            )
    rows = compare(runs[0], runs[1])
    write_docs(rows, runs[0], runs[1], args.out)
    for r in rows:
        print(
            f"{r['motion']:13s} t={r['t']:g} {r['landmark']:5s} d0 {r['level0_mm']} "
            f"d1 {r['level1_mm']} |d0-d1| {r['difference_mm']:.2f} mm "
            f"({100 * r['relative']:.0f} %)"
        )
    print(f"wrote {args.out / 'tongue_convergence.md'} and .json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
