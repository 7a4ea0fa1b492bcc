"""The airway pictures: the scene from the side with its mid-sagittal section, and the
section areas along the airway."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyvista as pv


def polydata(vertices, triangles) -> pv.PolyData:
    """A pyvista triangle surface."""
    return pv.PolyData(
        np.asarray(vertices, dtype=float),
        np.hstack([np.full((len(triangles), 1), 3), triangles]).ravel(),
    )


def render(png: Path, a, panels) -> Path:
    """Per panel (title, u, p, R, x): a side view of the tongue (|u|), jaw, palate and airway
    skin, and below it their mid-sagittal section (y = 0) with the rest airway in gray."""
    from dolfinx import fem

    from artifem.render import add_displacement, body_grid

    pv.OFF_SCREEN = True
    body = a.jt.tongue.body
    plotter = pv.Plotter(
        off_screen=True, shape=(2, len(panels)), window_size=[520 * len(panels), 1040]
    )
    u_fun = fem.Function(body.V)
    clim = (
        0.0,
        max(1e-6, 1e3 * max(np.linalg.norm(u.reshape(-1, 3), axis=1).max() for _, u, *_ in panels)),
    )
    jaw_v, jaw_t = a.jt.jaw.surface
    pal_v, pal_t = a.palate.surface
    palate = polydata(pal_v + a.palate.position, pal_t)
    rest_skin = polydata(a.skin.rest, a.skin.faces).slice(normal="y", origin=(0, 0, 0))
    side = [(0.10, -0.40, 0.06), (0.10, 0.0, 0.06), (0, 0, 1)]
    try:
        plotter.set_background("white")
        for i, (title, u, p, R, x) in enumerate(panels):
            u_fun.x.array[:] = u
            jaw = polydata(jaw_v @ R.T + p, jaw_t)
            skin = polydata(x, a.skin.faces)
            plotter.subplot(0, i)
            add_displacement(plotter, u_fun, clim, scalar_bar=i == 0, rest_opacity=0.1)
            plotter.add_mesh(jaw, color="wheat", opacity=0.35)
            plotter.add_mesh(palate, color="lightpink", opacity=0.5)
            plotter.add_mesh(
                skin,
                color="deepskyblue",
                opacity=0.45,
                show_edges=True,
                edge_color="steelblue",
                line_width=0.5,
            )
            plotter.add_text(title, font_size=10, color="black")
            plotter.camera_position = side
            plotter.reset_camera()
            plotter.camera.zoom(1.35)
            plotter.subplot(1, i)
            grid, _ = body_grid(body.mesh, u_fun)
            plotter.add_mesh(
                grid.slice(normal="y", origin=(0, 0, 0)), color="indianred", opacity=0.8
            )
            plotter.add_mesh(rest_skin, color="gray", line_width=2)
            for mesh, color in ((jaw, "tan"), (palate, "hotpink"), (skin, "blue")):
                plotter.add_mesh(
                    mesh.slice(normal="y", origin=(0, 0, 0)), color=color, line_width=3
                )
            plotter.add_text(
                "mid-sagittal: airway (blue; rest gray), tongue, palate, jaw",
                font_size=8,
                color="black",
            )
            plotter.camera_position = side
            plotter.reset_camera()
            plotter.camera.zoom(1.35)
        png.parent.mkdir(parents=True, exist_ok=True)
        plotter.screenshot(str(png))
    finally:
        plotter.close()
    return png


def plot_sections(png: Path, curves: dict) -> Path:
    """Area along the airway (larynx -> lips): curves name -> (length m, area m^2, style)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.2))
    for name, (s, area, style) in curves.items():
        ax.plot(1e3 * s, 1e6 * area, style, label=name, lw=1.4)
    ax.set_xlabel("distance from the larynx along the airway (mm)")
    ax.set_ylabel("cross-section area (mm$^2$)")
    ax.legend(fontsize=8, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return png
