"""
A reduced FEM body in a jointed scene: a cantilever of 12 modes swings a pendulum
=================================================================================

The beam's deformation is x = X + U q with U its 12 lowest vibration modes (SLEPc)
and every quadrature point kept; a rigid pendulum hinged to the world hangs from the
beam's tip by a spring whose end is a point on the reduced body (G = sum_j w_j U_j).
The scene's step is a few small dense matrices: no PETSc, no loop over the nodes.

    python demos/reduced_body_in_joints.py [OUT_DIR]    (ARTIFEM_QUICK=1: a few steps)
"""

import os
import sys
from pathlib import Path

import numpy as np

import artifem as af  # first: orders MPI ahead of dolfinx
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.reduction import all_points, linear_modes

out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/reduced_body_in_joints")
duration = 0.05 if os.environ.get("ARTIFEM_QUICK") else 1.0

box = dmesh.create_box(
    MPI.COMM_SELF, [np.zeros(3), np.array([1.0, 0.1, 0.1])], [20, 2, 2], dmesh.CellType.hexahedron
)
beam = af.FemBody(
    box, af.NeoHookean.from_young_poisson(5e5, 0.3), 1000.0, rayleigh=(0.5, 0.002), name="beam"
)
beam.fix_nodes(beam.find_nodes(lambda x: x[0] < 1e-12))
U, eigenvalues = linear_modes(beam, 12)
reduced = af.ReducedFemBody(beam, U, all_points(beam), name="beam_modes")

pendulum = af.RigidBody("pendulum", 0.5, 1e-3 * np.eye(3), position=(1.3, 0.05, -0.2))
hinge = af.SphericalJoint.at_world(pendulum, None, (1.3, 0.05, 0.05), name="pivot")
tip = af.FemPoint(reduced, af.shape_function_weights(beam, (1.0, 0.05, 0.05)))
spring = af.PointPath(
    af.AxialSpring(200.0, rest_length=0.25, damping=0.5),
    [tip, af.Frame.at_world(pendulum, (1.3, 0.05, -0.2))],
    name="spring",
)

scene = af.Scene(gravity=(0.0, 0.0, -9.81))
scene.add(reduced, pendulum, hinge, spring)
run = af.simulate(
    scene,
    duration,
    0.005,
    vtx=out,
    progress=False,
    record={
        "tip_z_mm": lambda s: 1e3 * (tip.position()[2] - 0.05),
        "spring_N": lambda s: spring.tension(),
    },
)

reduced.to_full()
af.render_bodies(
    out / "reduced_beam.png",
    [(box, beam.u)],
    scalars="displacement",
    scalar_name="displacement (m)",
    camera="xz",
    show_rest=True,
)
print(
    f"first frequency {np.sqrt(eigenvalues[0]) / (2 * np.pi):.2f} Hz; tip "
    f"{run.records['tip_z_mm'][-1]:.1f} mm, spring {run.records['spring_N'][-1]:.2f} N; "
    f"{run.ms_per_step:.2f} ms/step ({scene.master_count()} coordinates), "
    f"{run.halvings} halvings; wrote {out}/"
)
