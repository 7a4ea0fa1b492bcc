"""Pictures of the foot: the bones with their ligaments and muscles, the tissue coloured by
its von Mises stress (cut through the second ray), and the plantar pressure on the floor.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyvista as pv

from artifem.render import body_grid
from artifem.stress import von_mises

pv.OFF_SCREEN = True


def _bone_meshes(foot) -> list[pv.PolyData]:
    out = []
    for body in foot.bones.values():
        v, f = body.surface
        out.append(pv.PolyData(body.to_world(v), np.column_stack([np.full(len(f), 3), f]).ravel()))
    return out


def _lines(paths) -> pv.PolyData | None:
    points, cells = [], []
    for path in paths:
        x = path.positions()
        cells.append(np.r_[len(x), np.arange(len(x)) + sum(len(p) for p in points)])
        points.append(x)
    if not points:
        return None
    return pv.PolyData(np.vstack(points), lines=np.concatenate(cells))


def render_foot(png: Path, foot, title: str) -> Path:
    """Two views side by side: the bones with the ligaments (orange) and muscles (red)
    seen from the medial side; the tissue, cut at the middle of the second ray, coloured by
    its von Mises stress (kPa, the range to the 98th percentile of the cells), with the
    bones."""
    grid, _ = body_grid(foot.tissue.mesh, foot.tissue.u)
    vm = von_mises(foot.tissue).x.array
    grid.cell_data["von Mises (kPa)"] = 1e-3 * vm[: grid.n_cells]
    bones = _bone_meshes(foot)
    z_cut = (
        float(np.mean(foot.bones["metatarsals2_5"].position[2]))
        if foot.bones
        else float(np.mean(grid.bounds[4:]))
    )
    cut = grid.clip(normal=(0.0, 0.0, 1.0), origin=(0.0, 0.0, z_cut), invert=True)
    plotter = pv.Plotter(off_screen=True, shape=(1, 2), window_size=[1800, 700])
    try:
        plotter.set_background("white")
        plotter.subplot(0, 0)
        for mesh in bones:
            plotter.add_mesh(mesh, color="ivory", show_edges=False, smooth_shading=True)
        ligaments = _lines(foot.ligaments)
        if ligaments is not None:
            plotter.add_mesh(ligaments, color="orange", line_width=3)
        muscles = _lines([p for paths in foot.muscles.values() for p in paths])
        if muscles is not None:
            plotter.add_mesh(muscles, color="red", line_width=5)
        plotter.add_text(f"{title}: bones, ligaments, muscles", font_size=11, color="black")
        plotter.view_vector((0.0, 0.0, -1.0), viewup=(0.0, 1.0, 0.0))
        plotter.subplot(0, 1)
        # the colour range ends at the 98th percentile: a few cells under the heel's bone
        # would otherwise leave the rest of the tissue black
        top = float(np.percentile(grid.cell_data["von Mises (kPa)"], 98)) or 1.0
        plotter.add_mesh(
            cut,
            scalars="von Mises (kPa)",
            cmap="inferno",
            show_edges=False,
            clim=(0.0, top),
            scalar_bar_args={
                "title": "von Mises (kPa), to the 98th percentile",
                "color": "black",
                "fmt": "%.3g",
            },
        )
        for mesh in bones:
            plotter.add_mesh(mesh, color="ivory", opacity=0.6)
        plotter.add_text(f"{title}: tissue von Mises stress, cut", font_size=11, color="black")
        plotter.view_vector((0.0, 0.0, 1.0), viewup=(0.0, 1.0, 0.0))
        plotter.screenshot(str(png))
    finally:
        plotter.close()
    return png


def plot_reduced_comparison(png: Path, reduced: dict, dt: float, title: str) -> Path:
    """The reduced feet against the full one over the held-out run
    (:func:`~artifem.models.foot.reduced.compare`'s figures, name -> figures): the mean
    node error of each (mm; the issue's 1 mm target dashed) and the ms of every step of
    each and of the full foot (log scale: the slow steps show)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (err, cost) = plt.subplots(1, 2, figsize=(11, 4.2))
    full = None
    for name, r in reduced.items():
        if "failure" in r:
            continue
        label = f"{name}: {r['pod_vectors']} POD, {r['points']} {r['config']['sampling']} points"
        t = dt * np.arange(1, len(r["mean_node_error_mm"]) + 1)
        err.plot(t, r["mean_node_error_mm"], label=label)
        cost.semilogy(t, r["reduced_ms"], label=label)
        full = r["full_ms"]
    if full is not None:
        cost.semilogy(dt * np.arange(1, len(full) + 1), full, "k", label="full foot")
    err.axhline(1.0, color="gray", ls="--", lw=1, label="target 1 mm")
    err.set_xlabel("t (s)")
    err.set_ylabel("mean node error of the tissue (mm)")
    cost.set_xlabel("t (s)")
    cost.set_ylabel("wall ms of the step")
    for ax in (err, cost):
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png


def plot_plantar_pressure(
    png: Path,
    points: np.ndarray,
    pressure: np.ndarray,
    centre: np.ndarray,
    title: str,
    reference: str,
) -> Path:
    """The floor's pressure at the sole's nodes (kPa) seen from below (x forward, z
    lateral), the centre of pressure marked, a published figure quoted beside it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.tri import Triangulation

    fig, ax = plt.subplots(figsize=(5.5, 7.5))
    x, z, p = 1e3 * points[:, 0], 1e3 * points[:, 2], 1e-3 * pressure
    if len(p) >= 3:
        tri = Triangulation(z, x)
        shade = ax.tripcolor(tri, p, shading="gouraud", cmap="jet", vmin=0.0)
        fig.colorbar(shade, ax=ax, label="plantar pressure (kPa)")
    ax.plot(
        1e3 * centre[2], 1e3 * centre[0], "k+", markersize=14, mew=2, label="centre of pressure"
    )
    ax.set_xlabel("z: lateral (mm)")
    ax.set_ylabel("x: forward (mm)")
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title, fontsize=10)
    fig.text(0.02, 0.01, reference, fontsize=7, wrap=True)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return png
