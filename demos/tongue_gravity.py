"""
The ArtiSynth tongue hanging from its jaw and hyoid attachments under gravity
=============================================================================

Reads the ANSYS mesh shipped in models/data, fixes the jaw and hyoid
attachment nodes (as ArtiSynth's stand-alone HexTongueDemo does), and lets the
tissue (Mooney-Rivlin, C10 = 1037 Pa, C20 = 486 Pa, kappa = 10370 Pa) settle
for 0.3 s with the semi-implicit integrator. Writes a VTX series and a PNG.

    python demos/tongue_gravity.py [OUT_DIR]      (ARTIFEM_QUICK=1: 0.05 s)
"""

import os
import sys
from importlib.resources import files
from pathlib import Path

import numpy as np

import artifem as af  # first: orders MPI ahead of dolfinx

DATA = Path(str(files("artifem.models.data") / "artisynth-tongue"))  # shipped in the wheel
out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/tongue_gravity")
duration = 0.05 if os.environ.get("ARTIFEM_QUICK") else 0.3

# The mesh; FemBody takes file-order node rows. The attachment files hold
# ArtiSynth's 0-based node numbers (ANSYS id - 1), i.e. rows already.
mesh_data = af.read_mesh(DATA / "tongue.node")
domain, _ = af.to_dolfinx(mesh_data)
attached = np.concatenate(
    [
        np.loadtxt(DATA / f, dtype=int).ravel()
        for f in ("jawAttachments.txt", "hyoidAttachments.txt")
    ]
)

body = af.FemBody(
    domain,
    af.MooneyRivlin.tongue(),
    density=1040.0,
    rayleigh=(40.0, 0.03),
    gravity=(0.0, 0.0, -9.81),
    name="tongue",
)
body.fix_nodes(attached)

scene = af.Scene(gravity=(0.0, 0.0, -9.81))
scene.add(body)
tip = int(mesh_data.node_rows([920])[0])  # ArtiSynth's "tip" landmark
run = af.simulate(
    scene,
    duration,
    0.01,
    record={"tip": lambda s: body.displacement_at([tip])[0]},
    keep=(duration,),
    vtx=out,
)

af.render_bodies(
    out / "tongue_gravity.png",
    [(domain, run.snapshots[duration]["tongue"])],
    scalars="displacement",
    scalar_name="displacement (m)",
    camera="xz",
    show_rest=True,
)
print(
    f"{run.ms_per_step:.1f} ms/step, tip moved {1e3 * run.records['tip'][-1]} mm, "
    f"min det F {run.min_det_F:.3f}; wrote {out}/"
)
