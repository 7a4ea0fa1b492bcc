"""The masseter picture: one column per model, front and side views."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyvista as pv

from artifem.render import _set_camera, body_grid


def render(models: list, png: Path, titles=None) -> Path:
    """One column per model, front (xz) and side (yz) views: the primary deformed (faint,
    |u| in mm; the embedding model also shows its embedded muscle surface), the fascicles
    (dark red), the aponeuroses (orange: membranes or slab cells), the jaw and the arch
    (gray); off-screen with pyvista."""
    pv.OFF_SCREEN = True
    plotter = pv.Plotter(
        off_screen=True, shape=(2, len(models)), window_size=[380 * len(models), 1100]
    )
    plotter.set_background("white")
    umax = max(1e3 * np.abs(m.primary.u.x.array).max() for m in models) or 1.0
    for i, m in enumerate(models):
        grid, _ = body_grid(m.primary.mesh, m.primary.u)
        grid.point_data["|u| (mm)"] = 1e3 * np.linalg.norm(grid.point_data["displacement"], axis=1)
        for row, view in enumerate(("xz", "yz")):
            plotter.subplot(row, i)
            plotter.add_mesh(
                grid.copy(),
                scalars="|u| (mm)",
                cmap="viridis",
                clim=(0.0, umax),
                opacity=0.3,
                show_edges=True,
                edge_color="gray",
                show_scalar_bar=(i == 0 and row == 0),
                scalar_bar_args={"title": "|u| (mm)", "color": "black", "fmt": "%.2f"},
            )
            if getattr(m.primary, "surface", None) is not None:
                plotter.add_mesh(m.primary.surface.to_pyvista(), color="white", opacity=0.25)
            if m.aponeuroses == "slabs":
                plotter.add_mesh(
                    grid.extract_cells(m.primary.muscles["aponeuroses"].cells), color="orange"
                )
            for membrane in m.membranes:
                plotter.add_mesh(_wedge_grid(membrane), color="orange")
            plotter.add_mesh(m.fascicles.to_pyvista(), color="darkred", line_width=2)
            for body in (m.jaw, m.arch):
                V, T = body.surface
                poly = pv.PolyData(
                    V @ body.rotation.T + body.position, np.c_[np.full(len(T), 3), T].ravel()
                )
                plotter.add_mesh(poly, color="lightgray", opacity=0.5)
            if row == 0:
                plotter.add_text(titles[i] if titles else m.label, font_size=10, color="black")
            _set_camera(plotter, view, grid.bounds)
    Path(png).parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(png))
    plotter.close()
    return Path(png)


def _wedge_grid(body):
    """A prism FemBody at its current positions as VTK wedges (dolfinx.plot has no prisms)."""
    cells = body.mesh.geometry.dofmaps[0]
    conn = np.hstack([np.full((len(cells), 1), 6), cells]).ravel()
    return pv.UnstructuredGrid(conn, np.full(len(cells), pv.CellType.WEDGE), body.nodal_positions())
