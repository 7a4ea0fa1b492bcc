"""
Soft tissue meets bone: a pad of soft tissue dropped on a bony condyle
======================================================================

Contact is one more constraint of the Scene: at every step the closed surfaces of the
pad (the FEM body's exterior facets) and of the condyle (a rigid body's triangle
surface) give pairs, each vertex within the margin over a triangle of the other, and
each pair one row phi = e . (x_v - c) >= 0 with an impulse lambda >= 0 (and two friction
rows bounded by mu lambda) in the same solve as joints and attachments. The contact is
hard: no vertex sinks into the bone beyond the tolerance, and no energy is gained. The
pad drapes over the condyle, its weight carried by the contact pressure p_i = f_i / A_i
on its nodes.

    python demos/contact_pad_on_bone.py [OUT_DIR]      (ARTIFEM_QUICK=1: a few steps)
"""

import os
import sys
from pathlib import Path

import numpy as np
import pyvista as pv

import artifem as af  # first: orders MPI ahead of dolfinx
from dolfinx import mesh as dmesh
from mpi4py import MPI


out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/contact_pad_on_bone")
duration = 0.03 if os.environ.get("ARTIFEM_QUICK") else 0.6

# The condyle: a fixed rigid ball of radius 3 cm (pyvista's triangulated sphere).
ball = pv.Sphere(radius=0.03, theta_resolution=32, phi_resolution=32).triangulate()
condyle = af.RigidBody.from_surface(
    "condyle", ball.points, ball.faces.reshape(-1, 4)[:, 1:], 1900.0, motion="fixed"
)

# The pad: a 10 x 10 x 1.5 cm block of soft tissue, 2 mm above the top of the condyle.
box = dmesh.create_box(
    MPI.COMM_SELF,
    [np.array([-0.05, -0.05, 0.032]), np.array([0.05, 0.05, 0.047])],
    [10, 10, 2],
    dmesh.CellType.hexahedron,
)
pad = af.FemBody(
    box, af.NeoHookean.from_young_poisson(2e4, 0.45), 1050.0, rayleigh=(5.0, 0.002), name="pad"
)

# Contact with friction; the margin covers the approach within a step.
contact = af.MeshContact(pad, condyle, mu=0.4, tolerance=1e-5, margin=0.01, name="pad on condyle")

scene = af.Scene(gravity=(0.0, 0.0, -9.81))
scene.add(pad, condyle, contact)
run = af.simulate(
    scene,
    duration,
    0.005,
    vtx=out,
    progress=False,
    record={"lift_N": lambda s: s.contact_forces(contact).resultant[2]},
)

# Pictures: the pad on the condyle from the side, and its contact pressure from below.
pressure = scene.contact_pressure(contact)["pad"]
af.render_bodies(
    out / "contact_pad_on_bone.png",
    [(box, pad.u)],
    scalars="displacement",
    scalar_name="displacement (m)",
    camera="xz",
    surfaces=[(condyle.to_world(condyle.surface[0]), condyle.surface[1])],
)
af.render_bodies(
    out / "contact_pressure.png",
    [(box, pad.u)],
    scalars=pressure.nodal,
    scalar_name="contact pressure (Pa)",
    camera="yx",
)
weight = pad.total_mass() * 9.81
print(
    f"contact lift {run.records['lift_N'][-1]:.3f} N for a weight of {weight:.3f} N, "
    f"peak pressure {pressure.pressure.max():.0f} Pa on {np.count_nonzero(pressure.pressure)} "
    f"nodes, {run.ms_per_step:.1f} ms/step, {run.halvings} halvings; wrote {out}/"
)
