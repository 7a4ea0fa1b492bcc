"""The beam-ellipsoid picture: the beam coloured by its displacement and the ellipsoid at
its pose, one panel per frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyvista as pv
from dolfinx import fem

from artifem.render import add_displacement


def render(png: Path, config, beam, frames) -> Path:
    """The beam (colored by |u|) and the ellipsoid at the given (title, u, p, R) frames."""
    pv.OFF_SCREEN = True
    plotter = pv.Plotter(
        off_screen=True, shape=(1, len(frames)), window_size=[520 * len(frames), 420]
    )
    u_fun = fem.Function(beam.V)
    clim = (0.0, 1e3 * max(np.abs(u).max() for _, u, _, _ in frames))
    try:
        plotter.set_background("white")
        for i, (title, u, p, R) in enumerate(frames):
            plotter.subplot(0, i)
            u_fun.x.array[:] = u
            add_displacement(plotter, u_fun, clim, scalar_bar=i == 0, fmt="%.0f")
            shell = pv.ParametricEllipsoid(*config.semi_axes)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R, p
            plotter.add_mesh(shell.transform(T, inplace=False), color="salmon", opacity=0.9)
            plotter.add_text(title, font_size=11, color="black")
            plotter.camera_position = "xz"
            plotter.reset_camera()
        png.parent.mkdir(parents=True, exist_ok=True)
        plotter.screenshot(str(png))
    finally:
        plotter.close()
    return png
