"""
A skin over two masters, inflated by a pressure that acts back on them
======================================================================

A soft block hangs from a fixed bone by its end nodes. A closed triangulated skin
wraps the block; each vertex follows the block (shape functions of the element
that holds it) and, near the bone, the bone, with weights that blend from one to
the other (Lloyd et al. 2019, section 4). A pressure inside the skin, ramped by its
schedule p(t), pushes each face along its normal; the vertex
forces reach the masters through G^T (virtual work) and the block swells.

    python demos/skin_pressure.py [OUT_DIR]      (ARTIFEM_QUICK=1: a few steps)
"""

import os
import sys
from pathlib import Path

import numpy as np
import pyvista as pv

import artifem as af  # first: orders MPI ahead of dolfinx
from dolfinx import mesh as dmesh
from mpi4py import MPI


out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/skin_pressure")
duration = 0.02 if os.environ.get("ARTIFEM_QUICK") else 0.4

box = dmesh.create_box(
    MPI.COMM_SELF, [np.zeros(3), np.array([0.4, 0.1, 0.1])], [8, 2, 2], dmesh.CellType.hexahedron
)
block = af.FemBody(
    box, af.NeoHookean.from_young_poisson(3e4, 0.3), 1000.0, rayleigh=(5.0, 0.01), name="block"
)
bone = af.RigidBody("bone", 1.0, 1e-3 * np.eye(3), position=(0.0, 0.05, 0.05), motion="fixed")
carried = af.NodeAttachment(block, block.find_nodes(lambda x: x[0] < 1e-12), bone)

# The skin: the block's surface (outward triangles), on the block and, within 0.1 m of
# the bone, on the bone too.
surface = pv.Box(bounds=(0.0, 0.4, 0.0, 0.1, 0.0, 0.1), level=3).triangulate()
vertices = np.asarray(surface.points, dtype=float)
faces = surface.faces.reshape(-1, 4)[:, 1:]
w_bone = np.clip(1.0 - vertices[:, 0] / 0.1, 0.0, 1.0)
skin = af.SkinMesh(vertices, faces, [block, bone], weights=np.column_stack([1 - w_bone, w_bone]))


def volume(x):
    """The enclosed volume of the (closed, outward) skin: sum x0 . (x1 x x2) / 6."""
    a, b, c = (x[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


pressure = af.SkinPressure(skin, lambda t: 2000.0 * min(t / 0.2, 1.0))
scene = af.Scene(gravity=(0.0, 0.0, -9.81))
scene.add(block, bone, carried, pressure)
run = af.simulate(
    scene,
    duration,
    0.005,
    vtx=out,
    progress=False,
    record={"volume_cm3": lambda s: 1e6 * volume(skin.positions())},
)

af.render_bodies(
    out / "skin_pressure.png",
    [(box, block.u)],
    scalars="displacement",
    scalar_name="displacement (m)",
    camera="iso",
    show_rest=True,
)
v = run.records["volume_cm3"]
print(
    f"enclosed volume {v[0]:.0f} -> {v[-1]:.0f} cm^3 under {pressure.pressure_at(scene.t):.0f} "
    f"Pa; {run.ms_per_step:.1f} ms/step, {run.halvings} halvings; wrote {out}/"
)
