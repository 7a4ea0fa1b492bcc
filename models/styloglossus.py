"""The styloglossus as two external point-to-point muscles on the tongue (Lloyd et al. 2019,
section 3.1, Figs. 9-10): 4 versus 24 support nodes and the resulting stress fields.

Scene. The level-0 ArtiSynth hex tongue (models.tongue: Mooney-Rivlin C10 = 1037 Pa,
C20 = 486 Pa, kappa = 10370 Pa, element-wise incompressibility penalty 100 C10, Rayleigh
40 M + 0.03 K, jaw and hyoid attachment nodes fixed; its internal muscle bundles are left
unexcited) in a :class:`~artifem.multibody.coupled.CoupledSystem` without gravity, and two
:class:`~artifem.multibody.coupled.PointPath` muscles (left, right) from fixed styloid points
to points on the tongue.

Styloid points: ArtiSynth's HexTongueDemo values (0.14984, +-0.035891, 0.125) m. The tongue
mesh is in metres in the same frame: its bounding box is x in [0.0569, 0.1310] (tip at
x = 0.0576, base at x = 0.1274), y in [-0.0325, 0.0325], z in [0.0546, 0.1140] (top at
z = 0.1137), so the styloid points lie 19 mm behind, 3.3 mm lateral to and 11 mm above the
tongue's bounding box: posterior-superior-lateral, where the styloid processes are.

Attachment points: we did not find ArtiSynth's choice, so each is the centroid of the
boundary facet (hexahedron face on the surface) nearest to its styloid point, not on a fixed
(jaw/hyoid) node: on the lateral-posterior surface of the tongue. The point is attached with
``support_weights`` on ``nearest_nodes(point, k)`` for k = 4 and k = 24 (minimum-norm
weights that sum to one and reproduce the point; section 3.1).

Muscle: a Thelen 2003 Hill muscle (artifem.multibody.muscles.ThelenMuscle, rigid tendon,
activation dynamics), F0 = 3 N per side (ArtiSynth's MuscleMaxForce.txt gives 24 N for the
internal STY bundles together; 3 N keeps this very soft tongue (C10 ~ 1 kPa) from inverting
elements at a single attachment), optimal fiber length 0.8 L and tendon slack length
0.2 L with L the initial styloid-attachment distance (so it starts at the optimum).
Excitation: linear ramp 0 -> 1 over [0, 0.5] s, held to 1 s; h = 0.01 s.

Stress: Cauchy sigma = (1/J) P F^T with P = d psi/dF (ufl.diff) of the tongue's passive
energy (Mooney-Rivlin plus the incompressibility penalty), evaluated at cell centres into
DG0, von Mises; "near the attachment" = cells with a node within ``radius`` (default 12 mm)
of the attachment point's rest position.

Measured (1 s, h = 0.01 s, serial): peak von Mises near the attachment 12.5 kPa with 4
support nodes (tension 1.51 N, attachment moved 18.7 mm, min det F 0.41) and 20.0 kPa with
24 (2.25 N, 12.4 mm, min det F 0.72); about 106 / 112 ms per step. The paper's result (24
nodes spread the stress) is NOT reproduced: at equal excitation the 4-node point sinks
further, the Thelen force drops with the shorter fiber, and the 24-node minimum-norm weights
are partly negative (down to -0.08). Open: compare at equal tension (a force-controlled
point load or a linear muscle), and positive (e.g. least-squares with w >= 0) 24-node
weights.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
import numpy as np
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.models.tongue.model import Tongue, TongueConfig, load_tongue_data
from artifem.multibody.coupled import CoupledSystem, FemPoint, PointPath
from artifem.multibody.muscles import ThelenMuscle, ThelenParameters
from artifem.multibody.point_attachments import nearest_nodes, support_weights

STYLOID = {"left": np.array([0.14984, 0.035891, 0.125]),
           "right": np.array([0.14984, -0.035891, 0.125])}
MAX_FORCE = 3.0
RAMP, DURATION, DT = 0.5, 1.0, 0.01


def boundary_facet_centroids(body, exclude_dofs=()):
    """(centroids (m, 3), facet node dofs (m, 4)) of the exterior facets of the body's mesh."""
    msh = body.mesh
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, 0)
    msh.topology.create_connectivity(tdim - 1, tdim)
    facets = dmesh.exterior_facet_indices(msh.topology)
    f2v = msh.topology.connectivity(tdim - 1, 0)
    # P1 on the mesh geometry: vertex -> dof through the geometry (same ordering in dolfinx
    # for degree-1 meshes only through locate); use dof coordinates to match.
    X = body.V.tabulate_dof_coordinates()
    vx = msh.geometry.x
    msh.topology.create_connectivity(0, tdim)
    # map vertices to geometry nodes to dofs by coordinates (serial, exact copies)
    from scipy.spatial import cKDTree
    tree = cKDTree(X)
    vert_nodes = dmesh.entities_to_geometry(msh, 0, np.arange(
        msh.topology.index_map(0).size_local, dtype=np.int32)).ravel()
    vert_dof = tree.query(vx[vert_nodes])[1]
    cents, dofs = [], []
    excluded = set(int(d) for d in exclude_dofs)
    for f in facets:
        d = vert_dof[f2v.links(f)]
        if excluded.intersection(d.tolist()):
            continue
        cents.append(X[d].mean(axis=0))
        dofs.append(d)
    return np.array(cents), np.array(dofs)


def attachment_points(body) -> dict[str, np.ndarray]:
    cents, _ = boundary_facet_centroids(body, body.fixed_dofs)
    return {side: cents[np.argmin(np.linalg.norm(cents - s, axis=1))]
            for side, s in STYLOID.items()}


def excitation(t: float) -> float:
    return float(min(1.0, max(0.0, t / RAMP)))


def von_mises_dg0(body, config: TongueConfig) -> fem.Function:
    """DG0 von Mises stress of sigma = (1/J) P F^T, P = d psi/dF of the passive energy."""
    F = ufl.variable(ufl.Identity(3) + ufl.grad(body.u))
    psi = body.material.strain_energy(F)
    if config.incompressibility is not None:
        psi = psi + 0.5 * config.incompressibility * (ufl.det(F) - 1) ** 2
    P = ufl.diff(psi, F)
    J = ufl.det(F)
    s = P * F.T / J
    dev = s - ufl.tr(s) / 3 * ufl.Identity(3)
    vm = ufl.sqrt(1.5 * ufl.inner(dev, dev))
    Q = fem.functionspace(body.mesh, ("DG", 0))
    out = fem.Function(Q, name="von_mises")
    out.interpolate(fem.Expression(vm, Q.element.interpolation_points))
    return out


def cells_near(body, point, radius) -> np.ndarray:
    msh = body.mesh
    x = msh.geometry.x
    dm = msh.geometry.dofmaps[0]
    d = np.linalg.norm(x[dm] - point, axis=2).min(axis=1)
    return np.flatnonzero(d <= radius)


def simulate(support: int, *, duration: float = DURATION, dt: float = DT, radius: float = 0.012,
        data=None, config: TongueConfig = TongueConfig(level=0)) -> dict:
    """Simulate with the given support size; returns the results and the objects."""
    tongue = Tongue(config, comm=MPI.COMM_SELF, data=data)
    body = tongue.body
    scene = CoupledSystem(gravity=(0.0, 0.0, 0.0))
    scene.add(body)
    points = attachment_points(body)
    paths, fem_points = {}, {}
    for side, styloid in STYLOID.items():
        p = points[side]
        w = support_weights(body, p, nearest_nodes(body, p, support))
        fem_points[side] = FemPoint(body, w, name=f"STY_{side}")
        L = float(np.linalg.norm(styloid - p))
        muscle = ThelenMuscle(ThelenParameters(MAX_FORCE, 0.8 * L, 0.2 * L), name=f"STY_{side}")
        paths[side] = PointPath(muscle, [styloid, fem_points[side]], excitation=excitation,
                                name=f"STY_{side}")
        scene.add(paths[side])
    start = {s: fp.position().copy() for s, fp in fem_points.items()}
    n = int(round(duration / dt))
    t0 = time.perf_counter()
    for _ in range(n):
        scene.step(dt)
    ms = 1e3 * (time.perf_counter() - t0) / n
    vm = von_mises_dg0(body, config)
    peaks, near = {}, {}
    for side, p in points.items():
        cells = cells_near(body, p, radius)
        near[side] = cells
        peaks[side] = float(vm.x.array[cells].max())
    moved = {s: (fem_points[s].position() - start[s]).tolist() for s in STYLOID}
    return {"support_nodes": support, "attachment_points": {s: p.tolist() for s, p in
                                                             points.items()},
            "weights": {s: fem_points[s].weights.weights.tolist() for s in STYLOID},
            "peak_von_mises_near_attachment_Pa": peaks,
            "peak_von_mises_Pa": float(vm.x.array.max()),
            "attachment_displacement_m": moved,
            "tension_N": {s: paths[s].tension() for s in STYLOID},
            "ms_per_step": ms, "steps": n, "dt": dt, "radius_m": radius,
            "min_det_F": float(np.nanmin(body.det_F())),
            "_body": body, "_vm": vm}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--duration", type=float, default=DURATION)


def run(args: argparse.Namespace) -> int:
    report(args)
    return 0


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    return report(parser.parse_args(argv))


def report(args: argparse.Namespace) -> dict:
    """Both supports, the shared-scale stress render and the JSON summary."""
    args.out.mkdir(parents=True, exist_ok=True)
    data = load_tongue_data(0)
    results = {k: simulate(k, duration=args.duration, data=data) for k in (4, 24)}
    vmax = max(r["peak_von_mises_Pa"] for r in results.values())
    bodies = [(r["_body"].mesh, r["_body"].u) for r in results.values()]
    png = args.out / "styloglossus_stress.png"
    # one colour scale for both panels
    scal = [r["_vm"] for r in results.values()]
    render_shared(png, bodies, scal, [f"{k} support nodes" for k in results], vmax)
    summary = {str(k): {kk: v for kk, v in r.items() if not kk.startswith("_")}
               for k, r in results.items()}
    summary["png"] = str(png)
    summary["styloid_points_m"] = {s: p.tolist() for s, p in STYLOID.items()}
    summary["max_isometric_force_N"] = MAX_FORCE
    (args.out / "styloglossus.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps({k: (v["peak_von_mises_near_attachment_Pa"], v["ms_per_step"])
                      for k, v in summary.items() if isinstance(v, dict) and "ms_per_step" in v}))
    return summary


def render_shared(png, bodies, scalars, titles, vmax):
    """Side by side with one colour range [0, vmax] (pyvista, as artifem.render)."""
    import pyvista as pv
    from artifem.render import _set_camera, body_grid
    pv.OFF_SCREEN = True
    plotter = pv.Plotter(off_screen=True, shape=(1, len(bodies)), window_size=[1600, 700])
    plotter.set_background("white")
    grids = []
    for (msh, u), s in zip(bodies, scalars):
        g, rest = body_grid(msh, u)
        g.cell_data["von Mises (Pa)"] = s.x.array[:g.n_cells]
        grids.append((g, rest))
    boxes = np.array([g.bounds for pair in grids for g in pair]).reshape(-1, 3, 2)
    bounds = np.column_stack([boxes[:, :, 0].min(axis=0), boxes[:, :, 1].max(axis=0)]).ravel()
    for i, ((g, rest), title) in enumerate(zip(grids, titles)):
        plotter.subplot(0, i)
        plotter.add_mesh(g, scalars="von Mises (Pa)", cmap="inferno", clim=(0.0, vmax),
                         show_edges=True, edge_color="black",
                         scalar_bar_args={"title": "von Mises (Pa)", "color": "black",
                                          "fmt": "%.3g"})
        for s in STYLOID.values():
            plotter.add_mesh(pv.Sphere(radius=0.002, center=s), color="cyan")
        plotter.add_text(title, font_size=12, color="black")
        _set_camera(plotter, "iso", bounds)
    plotter.link_views()
    Path(png).parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(png))
    plotter.close()
    return png


if __name__ == "__main__":
    main()
