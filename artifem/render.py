"""Off-screen PNG rendering of deformed DOLFINx meshes with pyvista (no X server needed).

Each body is a dolfinx Mesh or a (Mesh, displacement Function or None) pair.
Meshes are converted with dolfinx.plot.vtk_mesh (on the displacement's function
space when there is one, so nodal displacements warp the grid points). In parallel
(render_bodies is then collective) the ranks' cells are gathered on rank 0, which alone
draws the picture and writes the file.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import dolfinx.mesh
import dolfinx.plot
import numpy as np
import pyvista as pv
from dolfinx import fem

from artifem.errors import InputError

pv.OFF_SCREEN = True

Body = dolfinx.mesh.Mesh | tuple[dolfinx.mesh.Mesh, fem.Function | None]
#: A body's coloring: "displacement" (|u| at the nodes), a scalar Function
#: (DG0 -> per cell, otherwise interpolated to the nodes), an array with one
#: value per grid point or per cell, or None (plain surface).
Scalars = str | fem.Function | np.ndarray | None

_CAMERAS = {"iso", "xy", "yx", "xz", "zx", "yz", "zy"}
_BODY_COLORS = ["lightsteelblue", "salmon", "khaki", "palegreen", "plum", "lightgray"]


def body_grid(
    msh: dolfinx.mesh.Mesh, displacement: fem.Function | None = None
) -> tuple[pv.UnstructuredGrid, pv.UnstructuredGrid]:
    """(deformed grid, rest grid) of a mesh; the deformed grid carries "displacement"."""
    if displacement is None:
        # A Lagrange space of the geometry's degree gives linear VTK cells for
        # linear meshes (vtk_mesh(msh) gives Lagrange cells, drawn tessellated).
        nodes = fem.functionspace(msh, ("Lagrange", msh.geometry.cmaps[0].degree))
        rest = pv.UnstructuredGrid(*_vtk_mesh(nodes))
        return rest.copy(), rest
    space = displacement.function_space
    if space.element.basix_element.discontinuous:
        raise InputError("render: the displacement must be a continuous Lagrange Function")
    rest = pv.UnstructuredGrid(*_vtk_mesh(space))
    values = displacement.x.array.reshape(-1, space.dofmap.index_map_bs)[: rest.n_points]
    if values.shape[1] != 3:
        raise InputError(f"render: the displacement must have 3 components, not {values.shape[1]}")
    deformed = rest.copy()
    deformed.point_data["displacement"] = values
    deformed.points = rest.points + values
    return deformed, rest


def _vtk_mesh(space: fem.FunctionSpace):
    """dolfinx.plot.vtk_mesh, with first-order prisms (6-node wedges: the masseter's
    aponeuroses) as VTK wedges: dolfinx has no first-order VTK type for them (the node
    orders agree)."""
    msh = space.mesh
    if msh.topology.cell_type != dolfinx.mesh.CellType.prism or space.ufl_element().degree != 1:
        return dolfinx.plot.vtk_mesh(space)
    cells = space.dofmap.list[: msh.topology.index_map(msh.topology.dim).size_local]
    topology = np.column_stack([np.full(len(cells), cells.shape[1]), cells]).ravel()
    return topology, np.full(len(cells), pv.CellType.WEDGE), space.tabulate_dof_coordinates()


def _attach_scalars(
    grid: pv.UnstructuredGrid,
    msh: dolfinx.mesh.Mesh,
    displacement: fem.Function | None,
    scalars: Scalars,
    name: str,
) -> bool:
    """Store ``scalars`` on ``grid`` under ``name``; return False when there is nothing to color."""
    if scalars is None:
        return False
    if isinstance(scalars, str):
        if scalars != "displacement":
            raise InputError(
                f"render: unknown scalars {scalars!r}; use 'displacement', a Function or an array"
            )
        if displacement is None:
            raise InputError("render: scalars='displacement' needs a displacement Function")
        grid.point_data[name] = np.linalg.norm(grid.point_data["displacement"], axis=1)
        return True
    if isinstance(scalars, fem.Function):
        space = scalars.function_space
        if space.element.basix_element.discontinuous and space.element.basix_element.degree == 0:
            cells = space.dofmap.list[: grid.n_cells, 0]
            grid.cell_data[name] = scalars.x.array[cells]
            return True
        target_space = (
            displacement.function_space.sub(0).collapse()[0]
            if displacement is not None
            else fem.functionspace(msh, ("Lagrange", 1))
        )
        nodal = fem.Function(target_space)
        nodal.interpolate(scalars)
        grid.point_data[name] = nodal.x.array[: grid.n_points]
        return True
    values = np.asarray(scalars)
    if len(values) == grid.n_points:
        grid.point_data[name] = values
    elif len(values) == grid.n_cells:
        grid.cell_data[name] = values
    else:
        raise InputError(
            f"render: {len(values)} scalar values match neither the "
            f"{grid.n_points} points nor the {grid.n_cells} cells"
        )
    return True


def _set_camera(plotter: pv.Plotter, camera, bounds) -> None:
    """Apply a named view ("iso", "xy", "xz", "yz", ...) or a pyvista camera position,
    framing ``bounds`` (the same box in every panel, so panels compare at one scale)."""
    if isinstance(camera, str) and camera not in _CAMERAS:
        raise InputError(
            f"render: unknown camera {camera!r}; use one of "
            f"{sorted(_CAMERAS)} or a pyvista camera position"
        )
    plotter.camera_position = camera
    plotter.reset_camera(bounds=bounds)


def add_displacement(
    plotter: pv.Plotter,
    displacement: fem.Function,
    clim,
    *,
    scalar_bar: bool = True,
    fmt: str = "%.1f",
    rest_opacity: float = 0.3,
) -> None:
    """Draw a body deformed by ``displacement``, colored by |u| in mm over ``clim``, with its
    rest shape as a faint wireframe, in the plotter's current subplot (for custom scenes)."""
    grid, rest = body_grid(displacement.function_space.mesh, displacement)
    grid.point_data["|u| (mm)"] = 1e3 * np.linalg.norm(grid.point_data["displacement"], axis=1)
    plotter.add_mesh(
        grid,
        scalars="|u| (mm)",
        cmap="viridis",
        show_edges=True,
        clim=clim,
        show_scalar_bar=scalar_bar,
        scalar_bar_args={"title": "|u| (mm)", "color": "black", "fmt": fmt},
    )
    plotter.add_mesh(rest, style="wireframe", color="gray", opacity=rest_opacity)


def _gathered(comm, grid: pv.UnstructuredGrid) -> pv.UnstructuredGrid | None:
    """The ranks' parts of one body's grid merged on rank 0 (None on the others); the
    points shared by two ranks appear twice, which draws the same picture."""
    parts = comm.gather(grid, root=0)
    if comm.rank != 0:
        return None
    parts = [p for p in parts if p.n_cells] or parts[:1]
    return parts[0] if len(parts) == 1 else pv.merge(parts, merge_points=False)


def render_bodies(
    png: str | Path,
    bodies: Body | Sequence[Body],
    scalars: Scalars | Sequence[Scalars] = None,
    titles: Sequence[str] | None = None,
    camera="iso",
    window_size: tuple[int, int] = (1200, 800),
    overlay: bool = False,
    show_rest: bool = False,
    scalar_name: str = "value",
    cmap: str = "viridis",
    surfaces: Sequence = (),
) -> Path:
    """Render bodies to ``png``: side by side (one subplot each) or ``overlay``-ed in one view.

    ``scalars`` is one coloring for all bodies, which then share one color
    range, or a list with one per body, each with its own range (see Scalars).
    Edges are drawn; ``show_rest`` adds the undeformed shape as a faint
    wireframe.  ``camera`` is "iso", "xy", "xz", "yz" (and reversed) or a
    pyvista camera position.  ``surfaces``: triangle surfaces (vertices (n, 3), triangles
    (m, 3)) drawn in every view in light gray, e.g. a rigid body's at its pose,
    ``(body.to_world(body.surface[0]), body.surface[1])``.  Returns the PNG path.
    """
    if isinstance(bodies, dolfinx.mesh.Mesh) or (
        isinstance(bodies, tuple)
        and len(bodies) == 2
        and isinstance(bodies[0], dolfinx.mesh.Mesh)
        and (bodies[1] is None or isinstance(bodies[1], fem.Function))
    ):
        bodies = [bodies]
    bodies = [(b, None) if isinstance(b, dolfinx.mesh.Mesh) else tuple(b) for b in bodies]
    if not bodies:
        raise InputError("render: no bodies to draw")
    per_body = list(scalars) if isinstance(scalars, (list, tuple)) else [scalars] * len(bodies)
    if len(per_body) != len(bodies):
        raise InputError(f"render: {len(per_body)} scalars for {len(bodies)} bodies")
    if titles is not None and len(titles) != len(bodies):
        raise InputError(f"render: {len(titles)} titles for {len(bodies)} bodies")

    grids, colored = [], []
    for (msh, u), s in zip(bodies, per_body):
        deformed, rest = body_grid(msh, u)
        colored.append(_attach_scalars(deformed, msh, u, s, scalar_name))
        grids.append((deformed, rest))
    comm = bodies[0][0].comm
    if comm.size > 1:  # each rank holds its own cells: rank 0 draws them all, alone
        grids = [tuple(_gathered(comm, g) for g in pair) for pair in grids]
        if comm.rank != 0:
            return Path(png)
    shared = not isinstance(scalars, (list, tuple))
    ranges = [g.get_data_range(scalar_name) for (g, _), c in zip(grids, colored) if c]
    shared_clim = (min(r[0] for r in ranges), max(r[1] for r in ranges)) if ranges else None

    solids = []
    for vertices, triangles in surfaces:
        triangles = np.asarray(triangles, dtype=np.int64)
        faces = np.column_stack([np.full(len(triangles), 3), triangles]).ravel()
        solids.append(pv.PolyData(np.asarray(vertices, dtype=float), faces))
    boxes = np.array(
        [g.bounds for pair in grids for g in pair] + [m.bounds for m in solids]
    ).reshape(-1, 3, 2)
    bounds = np.column_stack([boxes[:, :, 0].min(axis=0), boxes[:, :, 1].max(axis=0)]).ravel()

    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    shape = (1, 1) if overlay else (1, len(bodies))
    plotter = pv.Plotter(off_screen=True, shape=shape, window_size=list(window_size))
    try:
        plotter.set_background("white")
        for i, ((deformed, rest), has_scalars) in enumerate(zip(grids, colored)):
            plotter.subplot(0, 0 if overlay else i)
            if has_scalars:
                # One color bar for a shared coloring, else one per body (bars are keyed by title).
                bar = scalar_name if shared else (titles[i] if titles else f"{scalar_name} {i + 1}")
                clim = shared_clim if shared else deformed.get_data_range(scalar_name)
                plotter.add_mesh(
                    deformed,
                    scalars=scalar_name,
                    cmap=cmap,
                    clim=clim,
                    show_edges=True,
                    edge_color="black",
                    scalar_bar_args={
                        "title": bar,
                        "color": "black",
                        "fmt": "%.3g",
                        "position_x": 0.2,
                        "width": 0.6,
                    },
                )
            else:
                label = titles[i] if overlay and titles is not None else None
                plotter.add_mesh(
                    deformed,
                    color=_BODY_COLORS[i % len(_BODY_COLORS)],
                    show_edges=True,
                    edge_color="black",
                    label=label,
                )
            if show_rest:
                plotter.add_mesh(rest, style="wireframe", color="gray", opacity=0.3)
            for solid in solids:
                plotter.add_mesh(solid, color="gainsboro", show_edges=True, edge_color="gray")
            if titles is not None and not overlay:
                plotter.add_text(titles[i], font_size=12, color="black")
            _set_camera(plotter, camera, bounds)
        if overlay and titles is not None and not all(colored):
            plotter.add_legend(bcolor="white", face="rectangle")
        plotter.screenshot(str(png))
    finally:
        plotter.close()
    return png
