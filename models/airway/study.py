"""``artifem study airway``: every tongue motion in the airway, with and without the air,
and (``--reduced``) over the reduced tongue (the model: :mod:`artifem.models.airway.model`).

Measured (0.6 s, dt = 0.01 s, 1 kPa; docs/airway.md): the air moves the tongue's top 2-8 mm
down and forward (tip 3-13 mm) against the same motion without it, widens the oral airway
by up to 40 % when no muscle resists, and opens the jaw by 0.1-0.2 degrees; its resultants
(1.9 N on the tongue, 0.06 N on the jaw, 1.9 N on the palate at rest) sum to zero. Steps
cost 78 ms without the airway's load and 84 ms with the skin and its pressure (G: 5.4 ms,
skin positions 0.09 ms); with the reduced tongue (20 + 12 columns, 300 points) 5.0 and
6.0 ms, the pressure's loads formed without assembling G (docs/benchmarks/scenes.json). The reduced
airway follows the full one within 0.1-1.0 mm mean skin
error without the air and 0.9-1.3 mm with it (a basis trained without air), jaw angles
within 0.33 degrees.

``artifem study airway --out DIR [--reduced]`` writes DIR/airway.json, DIR/airway.png and
DIR/airway_sections.png (docs/airway.md).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from artifem.arguments import nonnegative_float, positive_float
from artifem.errors import InputError
from artifem.models.jaw_tongue import reduced as jtr
from artifem.models.jaw_tongue.study import simulate as simulate_jaw_tongue
from artifem.models.airway.model import (
    DEFAULT_CACHE,
    AirwayConfig,
    AirwayScene,
    build_scene,
    recorded,
    records,
    reduced_tongue,
    run_figures,
)
from artifem.models.airway.render import plot_sections, render
from artifem.models.tongue.model import MOTIONS, Tongue, load_tongue_data
from artifem.scene import simulate as simulate_scene


def simulate(
    a: AirwayScene,
    motion: str | None,
    duration: float,
    dt: float = 0.01,
    *,
    snapshots=(),
    progress: bool = False,
    label: str = "airway",
) -> dict:
    """Run a tongue motion (or none) in the airway scene: jaw_tongue.study.simulate's record plus,
    per step (outside the step timing), the skin's positions ``skin`` (steps + 1, n, 3), the
    section areas, the skin's distance to the tongue, the top landmark and the pressure;
    ``skin_frames``: the skin at the snapshots."""
    out = simulate_jaw_tongue(
        a.jt,
        motion,
        duration,
        dt,
        snapshots=snapshots,
        progress=progress,
        label=label,
        record=records(a),
    )
    out = recorded(a, out)
    out["skin_frames"] = [out["skin"][int(round(t / dt))] for t, *_ in out["frames"]]
    return out


def resultants(a: AirwayScene, t: float) -> dict:
    """Net force (N) of the air on each master and their sum (zero: closed surface): the
    force part of a rigid master's wrench; sum_v w_v f_v on the tongue (full: the sum of
    its nodal forces G^T f, since sum_j N_j = 1; reduced: the force on its material, which
    its generalized force [U, L]^T N^T (w f) does not show)."""
    f_v = a.pressure.vertex_forces(t)
    net = {}
    for i, (m, (_, f)) in enumerate(zip(a.skin.masters, a.pressure.master_loads(t))):
        net[m.name] = (f[:3] if m.kind == "rigid" else a.skin.weights[:, i] @ f_v).tolist()
    net["sum"] = np.sum([v for v in net.values()], axis=0).tolist()
    return net


def compare(a: AirwayScene, full: dict, reduced: dict) -> dict:
    """Reduced against full run of the same motion and pressure, over all steps: skin vertex
    error e_v(t) = |x_v^red - x_v^full| (mm: max over t of the mean over v, max over t and v,
    mean at the end); section area error 100 |A_red - A_full| / A_full over the interior
    sections (max over t and sections, mean over sections at the end); jaw angles; median
    ms per step of both (same process) and their ratio."""
    if full["skin"].shape != reduced["skin"].shape:
        raise InputError(
            f"airway compare: runs of different length {full['skin'].shape} "
            f"and {reduced['skin'].shape}"
        )
    e = 1e3 * np.linalg.norm(reduced["skin"] - full["skin"], axis=2)
    inner = a.sections.interior
    area = 100 * np.abs(reduced["areas"][:, inner] / full["areas"][:, inner] - 1)
    ms_full, ms_red = float(np.median(full["ms"])), float(np.median(reduced["ms"]))
    return {
        "skin_error_mm": {
            "mean_max_over_t": float(e.mean(1).max()),
            "max": float(e.max()),
            "final_mean": float(e[-1].mean()),
        },
        "max_skin_displacement_mm": float(
            1e3 * np.linalg.norm(full["skin"] - full["skin"][0], axis=2).max()
        ),
        "area_error_percent": {"max": float(area.max()), "final_mean": float(area[-1].mean())},
        "jaw_angle_deg": {
            "full": float(np.degrees(full["angle"][-1])),
            "reduced": float(np.degrees(reduced["angle"][-1])),
            "max_difference": float(np.degrees(np.abs(reduced["angle"] - full["angle"]).max())),
        },
        "ms_per_step": {"full": ms_full, "reduced": ms_red, "speedup": ms_full / ms_red},
        "max_attachment_error_m": float(reduced["attachment_error"].max()),
    }


def reduced_table(comparison: dict) -> str:
    """The Markdown table of :func:`compare`'s results per run."""
    lines = [
        "| run | skin error mean / max (mm) | max skin displacement (mm) | "
        "area error max / final mean (%) | jaw full / reduced (deg) | "
        "ms/step full / reduced | speed-up |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, c in comparison.items():
        e, A, j, ms = (
            c["skin_error_mm"],
            c["area_error_percent"],
            c["jaw_angle_deg"],
            c["ms_per_step"],
        )
        lines.append(
            f"| {key} | {e['mean_max_over_t']:.2f} / {e['max']:.2f} | "
            f"{c['max_skin_displacement_mm']:.1f} | {A['max']:.1f} / "
            f"{A['final_mean']:.1f} | {j['full']:.2f} / {j['reduced']:.2f} | "
            f"{ms['full']:.1f} / {ms['reduced']:.1f} | {ms['speedup']:.1f}x |"
        )
    return "\n".join(lines) + "\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument("--duration", type=positive_float, default=0.6)
    parser.add_argument("--dt", type=positive_float, default=0.01)
    parser.add_argument(
        "--pressure",
        type=nonnegative_float,
        default=AirwayConfig.pressure,
        help="air pressure inside the airway (Pa)",
    )
    parser.add_argument(
        "--motions",
        nargs="+",
        default=sorted(MOTIONS),
        choices=sorted(MOTIONS),
        help="tongue motions to run",
    )
    parser.add_argument(
        "--reduced",
        action="store_true",
        help="also run every case over the reduced tongue (jaw_tongue.reduced "
        "training) and compare it with the full one",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=DEFAULT_CACHE,
        help="reduced tongue training cache (default: %(default)s)",
    )


def run(args: argparse.Namespace) -> int:
    figures = report(args)
    if "reduced" in figures:
        print(reduced_table(figures["reduced"]["runs"]))
    return 0


def report(args: argparse.Namespace) -> dict:
    """Rest + each motion, with and without the air pressure: renders, section plot, JSON."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    config = AirwayConfig(pressure=args.pressure)
    data = load_tongue_data(0)
    t0 = time.perf_counter()
    rest = build_scene(config, pressure=True, data=data)
    build_s = time.perf_counter() - t0
    skin = rest.skin
    x0 = skin.positions()
    length0 = rest.sections.length(x0)
    rest_u = rest.jt.tongue.body.u.x.array.copy()
    rest_pose = (rest.jt.jaw.position.copy(), rest.jt.jaw.rotation.copy())
    runs = {}
    # no muscles (gravity and the jaw opener only), then each motion; with and without air
    for motion in [None] + list(args.motions):
        for on in (True, False):
            a = rest if motion is None and on else build_scene(config, pressure=on, data=data)
            key = f"{motion or 'none'}/{'pressure' if on else 'no_pressure'}"
            rec = simulate(
                a, motion, args.duration, args.dt, snapshots=(1.0,), progress=True, label=key
            )
            runs[key] = (a, rec)
            print(
                f"{key}: {np.median(rec['ms']):.0f} ms/step, min interior area "
                f"{1e6 * rec['areas'][-1, a.sections.interior].min():.1f} mm^2",
                flush=True,
            )
    panels = [("rest", rest_u, *rest_pose, x0)]
    inner = rest.sections.interior
    curves = {"rest": (length0[inner], rest.sections.areas(x0)[inner], "k-")}
    styles = {"none": "C7", "protrusion": "C0", "retroflexion": "C1", "retraction": "C2"}
    for key, (_, rec) in runs.items():
        motion, p = key.split("/")
        (_, u, pj, Rj), xs = rec["frames"][-1], rec["skin_frames"][-1]
        if p == "pressure" and motion != "none":
            panels.append(
                (
                    f"{motion}, {args.pressure:g} Pa, t = {rec['t'][-1]:.2f} s, "
                    f"jaw {np.degrees(rec['angle'][-1]):.1f} deg",
                    u,
                    pj,
                    Rj,
                    xs,
                )
            )
        curves[f"{motion}, {'p' if p == 'pressure' else 'no p'}"] = (
            length0[inner],
            rec["areas"][-1][inner],
            styles[motion] + ("-" if p == "pressure" else "--"),
        )
    png = render(out / "airway.png", rest, panels)
    sec_png = plot_sections(out / "airway_sections.png", curves)
    al = rest.alignment
    figures = {
        "model": "airway",
        "dt": args.dt,
        "duration": args.duration,
        "pressure_Pa": args.pressure,
        "pressure_ramp_s": config.pressure_ramp,
        "build_seconds": build_s,
        "alignment": {
            "airway": {
                "method": "axes (x,y,z)->(-x,-y,z), mm->m, trimmed point-to-surface "
                "ICP onto tongue boundary + palate, 5x5 starts",
                "linear": al["linear"].tolist(),
                "translation_m": al["translation"].tolist(),
                "residual_rotation_deg": al["residual_rotation_deg"],
                "trim": al["trim"],
                "trimmed_mean_distance_mm": 1e3 * al["trimmed_mean_distance"],
                "median_distance_mm": 1e3 * al["median_distance"],
                "p75_distance_mm": 1e3 * al["p75_distance"],
                "max_distance_mm": 1e3 * al["max_distance"],
                "fraction_inside_tongue": al["fraction_inside_tongue"],
                "max_depth_inside_tongue_mm": 1e3 * al["max_depth_inside_tongue"],
                "holes_capped": al["holes_capped"],
                "volume_cm3": 1e6 * al["volume_m3"],
            },
            "palate": {
                (k[:-2] + "_mm" if k.endswith("_m") else k): (1e3 * v if k.endswith("_m") else v)
                for k, v in al["palate"].items()
            },
        },
        "skin": {
            "vertices": skin.n,
            "faces": int(len(skin.faces)),
            "masters": [m.name for m in skin.masters],
            "dominant_master_vertices": {
                m.name: int((np.argmax(skin.weights, 1) == i).sum())
                for i, m in enumerate(skin.masters)
            },
            "tongue_weight_ge_0.9": int(rest.tongue_vertices.size),
            "weighting": config.weighting,
            "blending": config.blending,
        },
        "sections": {
            "count": int(len(rest.sections.a)),
            "length_mm": (1e3 * length0).tolist(),
            "rest_area_mm2": (1e6 * rest.sections.areas(x0)).tolist(),
        },
        "resultants_N_at_rest_pressure": resultants(rest, 1.0),
        "runs": {key: run_figures(a, rec) for key, (a, rec) in runs.items()},
        "png": [str(png), str(sec_png)],
    }
    effect = {}
    for motion in ["none"] + list(args.motions):
        on, off = runs[f"{motion}/pressure"][1], runs[f"{motion}/no_pressure"][1]
        effect[motion] = {
            "tip_mm": (1e3 * (on["tip"][-1] - off["tip"][-1])).tolist(),
            "top_mm": (1e3 * (on["top"][-1] - off["top"][-1])).tolist(),
            "opening_angle_deg": float(np.degrees(on["angle"][-1] - off["angle"][-1])),
            "mean_area_change_percent": float(
                100 * (on["areas"][-1].sum() / off["areas"][-1].sum() - 1)
            ),
        }
    figures["pressure_effect_final"] = effect
    if args.reduced:
        figures["reduced"] = report_reduced(out, config, data, runs, args)
    (out / "airway.json").write_text(json.dumps(figures, indent=2))
    short = {k: v for k, v in figures.items() if k in ("alignment", "pressure_effect_final")}
    print(json.dumps(short, indent=2))
    return figures


def report_reduced(
    out: Path, config: AirwayConfig, data, runs: dict, args: argparse.Namespace
) -> dict:
    """Every run of ``runs`` again over the reduced tongue (:func:`reduced_tongue`, cached in
    ``args.cache``), compared with the full one (:func:`compare`); renders full | reduced at
    the end of each motion with the pressure; ``airway_reduced.md``: the table."""
    tic = time.perf_counter()
    model = reduced_tongue(config, args.cache)
    train_s = time.perf_counter() - tic
    base = jtr.ReducedJawTongueConfig()
    comparison, panels = {}, []
    for key, (full_scene, full) in runs.items():
        motion, p = key.split("/")
        a = build_scene(config, pressure=p == "pressure", data=data, reduced=model)
        with threadpool_limits(limits=1, user_api="blas"):  # r x r algebra
            rec = simulate(
                a,
                None if motion == "none" else motion,
                args.duration,
                args.dt,
                snapshots=(1.0,),
                progress=True,
                label=f"{key} reduced",
            )
        comparison[key] = c = compare(full_scene, full, rec)
        print(
            f"{key} reduced: {c['ms_per_step']['reduced']:.1f} ms/step "
            f"(full {c['ms_per_step']['full']:.1f}), skin error mean "
            f"{c['skin_error_mm']['mean_max_over_t']:.2f} mm",
            flush=True,
        )
        if p == "pressure" and motion != "none":
            t = rec["t"][-1]
            for name, r in (("full", full), (f"reduced {base.r}+12", rec)):
                (_, u, pj, Rj), xs = r["frames"][-1], r["skin_frames"][-1]
                title = f"{motion}, {name}, t = {t:.2f} s, jaw {np.degrees(r['angle'][-1]):.2f} deg"
                if r is rec:
                    title += f", skin error {c['skin_error_mm']['final_mean']:.2f} mm"
                panels.append((title, u, pj, Rj, xs))
    png = render(out / "airway_reduced.png", runs["none/pressure"][0], panels)
    (out / "airway_reduced.md").write_text(reduced_table(comparison))
    return {
        "basis": {
            "pod_vectors": base.r,
            "lift_columns": 12,
            "points": base.points,
            "training": "jaw_tongue.reduced.train (each tongue exciter alone at "
            f"{base.training_excitation}, no air pressure)",
            "snapshots": model.training["snapshots"],
            "cache": str(args.cache),
        },
        "training_seconds": train_s,
        "runs": comparison,
        "png": str(png),
    }


def benchmark(
    steps: int = 10,
    dt: float = 0.01,
    data=None,
    reduced: jtr.ReducedJawTongueConfig | None = None,
    cache: Path | None = None,
    quick: bool = False,
) -> dict:
    """Milliseconds per coupled step (median of ``steps``) of the jaw-tongue scene during
    protrusion, with the full and with the reduced tongue (``reduced`` training, default
    the jaw-tongue one, ``jaw_tongue.reduced.quick_config()`` if ``quick``; cached in
    ``cache``, default $XDG_CACHE_HOME/artifem/jaw_tongue_reduced, ~/.cache when unset):
    without the airway's load, then with its skin and pressure; and the cost of one skin update
    (positions), of G
    (jacobian) and of the pressure's master loads."""
    if steps < 1:
        raise InputError(f"benchmark: steps must be >= 1, got {steps}")
    reduced = reduced or (jtr.quick_config() if quick else jtr.ReducedJawTongueConfig())
    data = data or load_tongue_data(0)
    config = AirwayConfig(pressure_start=(steps + 1) * dt)
    model = reduced_tongue(config, cache or DEFAULT_CACHE, reduced)
    cases = {}
    for name, red in (("full", None), ("reduced", model)):
        with threadpool_limits(limits=1, user_api="blas"):
            cases[name] = _benchmark_case(
                build_scene(config, pressure=False, data=data, reduced=red), steps, dt
            )
    ratio = {
        k: cases["full"][k] / cases["reduced"][k]
        for k in ("ms_per_step_without_airway", "ms_per_step_with_skin_pressure")
    }
    return {
        "benchmark": "airway",
        "steps": steps,
        "dt": dt,
        "skin_vertices": [c.pop("skin_vertices") for c in cases.values()][0],
        "reduced": {"pod_vectors": reduced.r, "lift_columns": 12, "points": reduced.points},
        "cases": cases,
        "speedup": ratio,
    }


def _benchmark_case(a: AirwayScene, steps: int, dt: float) -> dict:
    """benchmark() of one airway scene built without its pressure load (added midway)."""
    s = a.jt
    s.scene.add_controller(
        s.tongue.bundle_schedule(Tongue.motion("protrusion")).controller(s.tongue.body)
    )

    def timed(n):  # the controller included
        return simulate_scene(s.scene, n * dt, dt, progress=False).ms_per_step

    timed(1)  # factorization set-up, compile
    plain = timed(steps)
    s.scene.add(a.pressure)  # ramped from now on
    timed(1)
    loaded = timed(steps)

    def cost(f, n=max(3, steps)):
        t0 = time.perf_counter()
        for _ in range(n):
            f()
        return 1e3 * (time.perf_counter() - t0) / n

    t = s.scene.t
    return {
        "skin_vertices": a.skin.n,
        "masters": s.scene.master_count(),
        "ms_per_step_without_airway": plain,
        "ms_per_step_with_skin_pressure": loaded,
        "ms_skin_positions": cost(a.skin.positions),
        "ms_skin_jacobian": cost(a.skin.jacobian),
        "ms_pressure_master_loads": cost(lambda: a.pressure.master_loads(t)),
    }
