"""
A pressure-loaded FEM body solved statically: follower against dead load
========================================================================

A soft cantilever carries a skin on its top face with a uniform pressure. The
pressure follows the skin as the beam bends (a follower load: it turns with the
faces), so it has no potential; the static solve ramps it over load steps and
its consistent tangent G^T (df/dx) G enters Newton. The same pressure frozen at
the rest configuration (a dead load) bends the beam differently.

    python demos/static_pressure.py [OUT_DIR]
"""

import sys
from pathlib import Path

import numpy as np

import artifem as af  # first: orders MPI ahead of dolfinx
from dolfinx import mesh as dmesh
from mpi4py import MPI


out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/static_pressure")
PRESSURE = -150.0  # Pa, against the top face's outward normal


def cantilever(name):
    box = dmesh.create_box(
        MPI.COMM_SELF,
        [np.zeros(3), np.array([1.0, 0.2, 0.2])],
        [10, 2, 2],
        dmesh.CellType.hexahedron,
    )
    beam = af.FemBody(box, af.NeoHookean.from_young_poisson(1e5, 0.3), 1000.0, name=name)
    beam.fix_nodes(beam.find_nodes(lambda x: x[0] < 1e-12))
    return beam


# The skin: the top face, 2 x 10 quads split into triangles, on the beam (its only master).
grid = np.array([[x, y, 0.2] for y in np.linspace(0, 0.2, 3) for x in np.linspace(0, 1, 11)])
quads = [
    (j * 11 + i, j * 11 + i + 1, j * 11 + i + 12, j * 11 + i + 11)
    for j in range(2)
    for i in range(10)
]
triangles = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])

follower = cantilever("follower")
scene = af.Scene(gravity=(0.0, 0.0, 0.0))
load = af.SkinPressure(af.SkinMesh(grid, triangles, [follower]), PRESSURE)
scene.add(follower, load)
iterations = scene.solve_static(load_steps=6)

# the same forces, computed once at rest, as dead nodal loads
dead = cantilever("dead")
skin_rest = af.SkinMesh(grid, triangles, [dead])
(f_nodes,) = skin_rest.master_forces(skin_rest.pressure_forces(PRESSURE))
nodes = {d: n for n, d in dead._input_node_to_dof().items()}
dead.add_nodal_load(np.array([nodes[d] for d in range(f_nodes.size // 3)]), f_nodes.reshape(-1, 3))
reference = af.Scene(gravity=(0.0, 0.0, 0.0))
reference.add(dead)
reference.solve_static(load_steps=6)

tip = [np.abs(b.u.x.array.reshape(-1, 3)).max(axis=0) * 1e3 for b in (follower, dead)]
af.render_bodies(
    out / "static_pressure.png",
    [(follower.mesh, follower.u), (dead.mesh, dead.u)],
    scalars="displacement",
    scalar_name="displacement (m)",
    camera="xz",
    titles=["follower pressure", "dead load"],
    show_rest=True,
)
print(
    f"Newton iterations per load step {iterations}; max |u| (x, y, z) mm: follower "
    f"{np.round(tip[0], 1)}, dead {np.round(tip[1], 1)}; wrote {out}/"
)
