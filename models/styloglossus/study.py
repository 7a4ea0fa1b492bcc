"""``artifem study styloglossus``: the external styloglossus on 4 versus 24 support
nodes, signed or non-negative weights, equal excitation or equal tension, full or reduced
tongue (the model: :mod:`artifem.models.styloglossus.model`).

Measured (``artifem study styloglossus --out DIR``: 1 s, serial, left side; the scene is
symmetric to 1e-4; ms/step medians of one run; docs/img/styloglossus.json, tables in
docs/styloglossus.md):

| run | tension | peak von Mises near attachment | attachment moved | min det F | ms/step |
|---|---|---|---|---|---|
| Thelen, 4 nodes | 1.51 N | 12.5 kPa | 18.7 mm | 0.41 | 76 |
| Thelen, 24 nodes | 2.25 N | 20.0 kPa | 12.6 mm | 0.72 | 77 |
| 1.5 N, 4 nodes | 1.50 N | 12.3 kPa | 18.6 mm | 0.41 | 73 |
| 1.5 N, 24 min-norm | 1.50 N | 11.4 kPa | 9.7 mm | 0.77 | 71 |
| 1.5 N, 24 w >= 0 | 1.50 N | 23.0 kPa | 12.6 mm | 0.66 | 72 |
| reduced, 4 nodes | 1.50 N | 10.0 kPa | 18.0 mm | 0.49 | 1.3 |
| reduced, 24 min-norm | 1.50 N | 10.5 kPa | 9.4 mm | 0.77 | 1.7 |
| reduced, 24 w >= 0 | 1.50 N | 19.6 kPa | 12.1 mm | 0.65 | 1.5 |

At equal excitation the comparison is not at equal load (the 4-node point sinks further, the
Thelen fiber shortens, its force drops to 1.51 N against 2.25 N). At equal tension the 24
min-norm nodes lower the peak near the attachment by 7% (11.4 / 12.3 kPa), halve the
attachment displacement and keep min det F at 0.77 instead of 0.41: the paper's claim holds.
With non-negative weights it does not: the force stays on one facet and the peak doubles
(23.0 kPa). Reduced against full (same support): attachment error 0.8-1.1 mm, mean nodal
error 0.4-0.6 mm, peak stress 8-19% lower (the basis smooths the attachment), 43-56x faster.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from artifem.arguments import nonnegative_float, positive_float, positive_int
from artifem.errors import InputError
from artifem.excitation import ExcitationSchedule
from artifem.models.styloglossus.model import (
    DT,
    DURATION,
    LABELS,
    MAX_FORCE,
    RAMP,
    STYLOID,
    SUPPORTS,
    TENSION,
    ReducedConfig,
    build_scene,
    cells_near,
    reducible,
    von_mises_dg0,
)
from artifem.models.tongue.model import PENALTY, TongueConfig, load_tongue_data
from artifem.reduction.reductor import Basis, Points, ReducedModel, Reductor, Training
from artifem.scene import simulate as simulate_scene


def simulate(
    support: int = 4,
    *,
    nonnegative: bool = False,
    load: str = "thelen",
    tension: float = TENSION,
    sides=tuple(STYLOID),
    reduced: ReducedModel | None = None,
    duration: float = DURATION,
    dt: float = DT,
    radius: float = 0.012,
    data=None,
    config: TongueConfig = TongueConfig(level=0, incompressibility=PENALTY),
) -> dict:
    """One run of :func:`build_scene`'s scene over e(t), on the full tongue or with the
    reduced tongue of ``reduced`` in place (its paths then pull on the reduced body).
    Returns the figures and, under "_" keys, the (full) body and the stress."""
    scene = build_scene(
        support,
        nonnegative=nonnegative,
        load=load,
        tension=tension,
        sides=sides,
        data=data,
        config=config,
    )
    body = scene.fem_bodies[0]
    if reduced is not None:
        master, _ = reduced.put_in(scene)
    paths = {p.name.removeprefix("STY_"): p for p in scene.paths}
    fem_points = {side: path.points[-1] for side, path in paths.items()}
    points = {side: fp.weights.rest_position for side, fp in fem_points.items()}
    start = {s: fp.position().copy() for s, fp in fem_points.items()}
    n = int(round(duration / dt))
    with threadpool_limits(limits=1, user_api="blas"):
        run = simulate_scene(scene, n * dt, dt, progress=False)
    if reduced is not None:
        master.to_full()  # u = U q on the full mesh, observed
    vm = von_mises_dg0(body, config)
    peaks = {s: float(vm.x.array[cells_near(body, p, radius)].max()) for s, p in points.items()}
    return {
        "support_nodes": support,
        "nonnegative": nonnegative,
        "load": load,
        "model": "full" if reduced is None else "reduced",
        "attachment_points": {s: p.tolist() for s, p in points.items()},
        "weights": {s: fp.weights.weights.tolist() for s, fp in fem_points.items()},
        "peak_von_mises_near_attachment_Pa": peaks,
        "peak_von_mises_Pa": float(vm.x.array.max()),
        "attachment_displacement_m": {
            s: (fem_points[s].position() - start[s]).tolist() for s in points
        },
        "tension_N": {s: paths[s].tension() for s in points},
        "ms_per_step": run.ms_per_step,
        "steps": n,
        "dt": dt,
        "radius_m": radius,
        "min_det_F": float(np.nanmin(body.det_F())),
        "_body": body,
        "_vm": vm,
        "_support_dofs": {s: fp.weights.dofs for s, fp in fem_points.items()},
    }


def check_training_size(rc: ReducedConfig, duration: float, dt: float = DT) -> None:
    """A clear error, before any run, when the training cannot hold ``rc.r`` POD vectors:
    each side alone gives one snapshot every ``rc.snapshot_every`` steps."""
    snapshots = len(STYLOID) * (int(round(duration / dt)) // rc.snapshot_every)
    if rc.r > snapshots:
        raise InputError(
            f"styloglossus: r = {rc.r} POD vectors need as many training "
            f"snapshots; {duration:g} s at dt = {dt:g} s, one every "
            f"{rc.snapshot_every} steps, on {len(STYLOID)} runs gives {snapshots}: "
            "lengthen --duration or lower --r"
        )


def reduce_tongue(
    support: str,
    cache: Path,
    rc: ReducedConfig = ReducedConfig(),
    *,
    data=None,
    duration: float = DURATION,
    dt: float = DT,
) -> ReducedModel:
    """The reduced tongue of support ``support``: POD and ECSW points of full runs with each
    side alone, ramped as e(t) to ``rc.training_tension`` (module docstring), cached."""
    check_training_size(rc, duration, dt)
    training = Training(
        {side: ExcitationSchedule.ramp_and_hold({side: 1.0}, RAMP) for side in STYLOID},
        duration=duration,
        dt=dt,
        snapshot_every=rc.snapshot_every,
    )
    return Reductor(reducible(support, rc, data=data), training, cache).reduce(
        Basis("pod", rc.r),
        Points(rc.points, tol=rc.cubature_tol, training_states=rc.force_snapshots),
    )


def _summary(r: dict) -> dict:
    return {k: v for k, v in r.items() if not k.startswith("_")}


def _row(name: str, r: dict) -> dict:
    """One table row (left side; the scene is symmetric to 1e-4)."""
    return {
        "config": name,
        "model": r["model"],
        "load": r["load"],
        "tension_N": r["tension_N"]["left"],
        "peak_von_mises_near_attachment_kPa": 1e-3 * r["peak_von_mises_near_attachment_Pa"]["left"],
        "attachment_displacement_mm": 1e3
        * float(np.linalg.norm(r["attachment_displacement_m"]["left"])),
        "min_det_F": r["min_det_F"],
        "ms_per_step": r["ms_per_step"],
        "min_weight": float(min(r["weights"]["left"])),
    }


def report(args: argparse.Namespace) -> dict:
    """Equal excitation (Thelen), equal tension (prescribed), full and reduced: JSON, Markdown
    table and the side-by-side stress renders in ``args.out``."""
    out = Path(args.out)
    if not args.no_reduced:
        check_training_size(ReducedConfig(r=args.r, points=args.points), args.duration)
    out.mkdir(parents=True, exist_ok=True)
    data = load_tongue_data(0)
    runs = {}
    for k in (4, 24):
        runs[f"excitation {k}"] = simulate(k, duration=args.duration, data=data)
    for name, (k, nn) in SUPPORTS.items():
        runs[f"tension {name}"] = simulate(
            k,
            nonnegative=nn,
            load="tension",
            tension=args.tension,
            duration=args.duration,
            data=data,
        )
    figures = {
        "styloid_points_m": {s: p.tolist() for s, p in STYLOID.items()},
        "max_isometric_force_N": MAX_FORCE,
        "tension_N": args.tension,
        "duration_s": args.duration,
        "dt": DT,
    }
    pngs = {
        "excitation": out / "styloglossus_stress.png",
        "tension": out / "styloglossus_tension.png",
    }
    render_panels(
        pngs["excitation"], [[(f"{k} nodes, Thelen", runs[f"excitation {k}"]) for k in (4, 24)]]
    )
    render_panels(pngs["tension"], [[(LABELS[n], runs[f"tension {n}"]) for n in SUPPORTS]])
    if not args.no_reduced:
        rc = ReducedConfig(r=args.r, points=args.points)
        models = {}
        for name in SUPPORTS:
            tic = time.perf_counter()
            models[name] = reduce_tongue(
                name, args.cache or out / "cache", rc, data=data, duration=args.duration
            )
            models[name].training["wall_seconds"] = time.perf_counter() - tic
        figures["reduced"] = {
            "pod_vectors": rc.r,
            "points_asked": rc.points,
            "training_tension_N": rc.training_tension,
            "training": {n: m.training for n, m in models.items()},
        }
        for name, (k, nn) in SUPPORTS.items():
            red = simulate(
                k,
                nonnegative=nn,
                load="tension",
                tension=args.tension,
                reduced=models[name],
                duration=args.duration,
                data=data,
            )
            full = runs[f"tension {name}"]
            n = 3 * full["_body"].V.dofmap.index_map.size_local
            du = (red["_body"].u.x.array[:n] - full["_body"].u.x.array[:n]).reshape(-1, 3)
            red["error_vs_full"] = {
                "mean_node_mm": 1e3 * float(np.linalg.norm(du, axis=1).mean()),
                "max_node_mm": 1e3 * float(np.linalg.norm(du, axis=1).max()),
                "attachment_mm": 1e3
                * float(
                    np.linalg.norm(
                        np.subtract(
                            red["attachment_displacement_m"]["left"],
                            full["attachment_displacement_m"]["left"],
                        )
                    )
                ),
                "speedup": full["ms_per_step"] / red["ms_per_step"],
            }
            runs[f"reduced {name}"] = red
        pngs["reduced"] = out / "styloglossus_reduced.png"
        render_panels(
            pngs["reduced"],
            [
                [(f"full, {LABELS[n]}", runs[f"tension {n}"]) for n in SUPPORTS],
                [
                    (
                        f"reduced ({rc.r}, {models[n].points.m} pts), {LABELS[n]}",
                        runs[f"reduced {n}"],
                    )
                    for n in SUPPORTS
                ],
            ],
        )
    figures["runs"] = {name: _summary(r) for name, r in runs.items()}
    figures["table"] = [
        _row(name, r) | ({"error_vs_full": r["error_vs_full"]} if "error_vs_full" in r else {})
        for name, r in runs.items()
    ]
    figures["png"] = {k: p.name for k, p in pngs.items()}
    (out / "styloglossus.json").write_text(json.dumps(figures, indent=2))
    (out / "styloglossus.md").write_text(table(figures))
    print(table(figures))
    return figures


def table(figures: dict) -> str:
    lines = [
        "| run | tension (N) | peak von Mises near attachment (kPa) | attachment moved (mm) "
        "| min det F | min weight | ms/step |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in figures["table"]:
        lines.append(
            f"| {row['config']} | {row['tension_N']:.2f} | "
            f"{row['peak_von_mises_near_attachment_kPa']:.2f} | "
            f"{row['attachment_displacement_mm']:.2f} | {row['min_det_F']:.2f} | "
            f"{row['min_weight']:.3f} | {row['ms_per_step']:.1f} |"
        )
    errors = [r for r in figures["table"] if "error_vs_full" in r]
    if errors:
        lines += [
            "",
            "| reduced run | mean node error (mm) | max node error (mm) | "
            "attachment error (mm) | speed-up |",
            "|---|---|---|---|---|",
        ]
        for r in errors:
            e = r["error_vs_full"]
            lines.append(
                f"| {r['config']} | {e['mean_node_mm']:.2f} | {e['max_node_mm']:.2f} | "
                f"{e['attachment_mm']:.2f} | {e['speedup']:.0f}x |"
            )
    return "\n".join(lines) + "\n"


def render_panels(png, rows, *, vmax: float | None = None):
    """Panels (rows x columns of (title, run)) of the deformed tongue coloured by von Mises on
    one scale [0, vmax] (default: the largest peak near an attachment), looking at the left
    attachment from posterior-lateral-superior; its support nodes as spheres sized by |w_j|,
    the muscle as a red line."""
    import pyvista as pv
    from artifem.render import body_grid

    pv.OFF_SCREEN = True
    runs = [r for row in rows for _, r in row]
    vmax = vmax or max(max(r["peak_von_mises_near_attachment_Pa"].values()) for r in runs)
    ncol = max(len(row) for row in rows)
    plotter = pv.Plotter(
        off_screen=True, shape=(len(rows), ncol), window_size=[560 * ncol, 520 * len(rows)]
    )
    plotter.set_background("white")
    for i, row in enumerate(rows):
        for j, (title, r) in enumerate(row):
            plotter.subplot(i, j)
            body = r["_body"]
            grid, _ = body_grid(body.mesh, body.u)
            grid.cell_data["von Mises (kPa)"] = 1e-3 * r["_vm"].x.array[: grid.n_cells]
            plotter.add_mesh(
                grid,
                scalars="von Mises (kPa)",
                cmap="inferno",
                clim=(0.0, 1e-3 * vmax),
                show_edges=True,
                edge_color="gray",
                show_scalar_bar=(i, j) == (0, 0),
                scalar_bar_args={
                    "title": "von Mises (kPa)",
                    "color": "black",
                    "fmt": "%.0f",
                    "vertical": True,
                    "position_x": 0.85,
                    "position_y": 0.1,
                    "height": 0.7,
                    "width": 0.08,
                },
            )
            x = body.V.tabulate_dof_coordinates() + body.u.x.array.reshape(-1, 3)
            side = "left" if "left" in r["attachment_points"] else "right"
            dofs, w = r["_support_dofs"][side], np.abs(r["weights"][side])
            a = np.array(r["attachment_points"][side])
            moved = a + np.array(r["attachment_displacement_m"][side])
            plotter.add_mesh(pv.Line(STYLOID[side], moved), color="red", line_width=4)
            cloud = pv.PolyData(x[dofs])
            cloud["w"] = w
            plotter.add_mesh(
                cloud.glyph(
                    scale="w", orient=False, factor=0.004 / w.max(), geom=pv.Sphere(radius=0.5)
                ),
                color="cyan",
            )
            plotter.add_text(
                f"{title}: T = {r['tension_N'][side]:.2f} N", font_size=10, color="black"
            )
            look = np.array([0.05, 0.09 if side == "left" else -0.09, 0.04])
            plotter.camera_position = [tuple(a + 1.2 * look), tuple(a), (0.0, 0.0, 1.0)]
            plotter.camera.view_angle = 30.0
    Path(png).parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(png))
    plotter.close()
    return png


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--duration", type=positive_float, default=DURATION)
    parser.add_argument(
        "--tension",
        type=nonnegative_float,
        default=TENSION,
        help="equal-tension runs: prescribed tension per side (N)",
    )
    parser.add_argument("--no-reduced", action="store_true", help="skip the reduced tongue")
    parser.add_argument("--r", type=positive_int, default=ReducedConfig.r, help="POD vectors")
    parser.add_argument(
        "--points",
        type=positive_int,
        default=ReducedConfig.points,
        help="trained integration points",
    )
    parser.add_argument(
        "--cache", type=Path, default=None, help="training cache (default OUT/cache)"
    )


def run(args: argparse.Namespace) -> int:
    report(args)
    return 0
