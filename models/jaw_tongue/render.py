"""The jaw-tongue picture: the tongue coloured by its displacement and the jaw at its
pose, one panel per frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def render(png: Path, s, frames) -> Path:
    """The tongue (coloured by |u|, shared scale) and the jaw surface at (title, u, p, R)."""
    import pyvista as pv
    from dolfinx import fem

    from artifem.render import add_displacement

    pv.OFF_SCREEN = True
    body = s.tongue.body
    plotter = pv.Plotter(
        off_screen=True, shape=(1, len(frames)), window_size=[560 * len(frames), 520]
    )
    u_fun = fem.Function(body.V)
    clim = (
        0.0,
        max(
            1e-6, 1e3 * max(np.linalg.norm(u.reshape(-1, 3), axis=1).max() for _, u, _, _ in frames)
        ),
    )
    verts, tris = s.jaw.surface
    faces = np.hstack([np.full((len(tris), 1), 3), tris]).ravel()
    try:
        plotter.set_background("white")
        for i, (title, u, p, R) in enumerate(frames):
            plotter.subplot(0, i)
            u_fun.x.array[:] = u
            add_displacement(plotter, u_fun, clim, scalar_bar=i == 0, rest_opacity=0.15)
            plotter.add_mesh(pv.PolyData(verts @ R.T + p, faces), color="wheat", opacity=0.55)
            plotter.add_mesh(pv.Sphere(radius=0.002, center=s.hinge), color="red")
            plotter.add_text(title, font_size=11, color="black")
            plotter.camera_position = [(0.105, -0.35, 0.08), (0.105, 0.0, 0.08), (0, 0, 1)]
            plotter.reset_camera()
            plotter.camera.zoom(1.3)
        png.parent.mkdir(parents=True, exist_ok=True)
        plotter.screenshot(str(png))
    finally:
        plotter.close()
    return png
