"""
A thick rubber sphere inflated by an internal pressure, against its closed-form curve
=====================================================================================

One octant of the shell ``A <= |X| <= B`` (hexahedra mapped from the three faces of a
cube corner onto the sphere) with symmetry planes: u_k = 0 on X_k = 0, one
component only. The internal pressure p is a follower load: it acts on the
deformed inner face, t da = -p J F^-T N dA (Nanson), with its tangent from UFL.
Its faces and the symmetry planes enclose the cavity, so the pressure is
declared ``closed``: its potential -p V(u) joins the body's energy and the
static Newton keeps its energy line search. The material is the uncoupled
neo-Hookean W = mu/2 (I1bar - 3) with a soft bulk term and ArtiSynth's
element-wise incompressibility (kappa_inc = 1000 mu).

Each pressure level is set by ``load.set(p)`` and solved statically from the last
equilibrium. The incompressible closed form is

    p(la) = 2 mu (1/lb - 1/la) + mu/2 (lb^-4 - la^-4),   lb^3 = 1 + (la^3 - 1) (A/B)^3,

la and lb the inner and outer hoop stretches; p has a maximum (the limit point
of a thick neo-Hookean sphere), so the levels stay below it.

    python demos/inflated_sphere.py [OUT_DIR]      (ARTIFEM_QUICK=1: a coarse mesh, 2 levels)
"""

import json
import os
import sys
from pathlib import Path

import numpy as np

import artifem as af  # first: orders MPI ahead of dolfinx
import matplotlib
from scipy.optimize import brentq, minimize_scalar


matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/inflated_sphere")
quick = bool(os.environ.get("ARTIFEM_QUICK"))
A, B, MU = 1.0, 2.0, 1.0  # radii (m) and shear modulus (Pa): the curve scales
n = 3 if quick else 6  # hexahedra per patch side and through the wall


def pressure_of(la):
    lb = (1.0 + (la**3 - 1.0) * (A / B) ** 3) ** (1.0 / 3.0)
    return 2 * MU * (1 / lb - 1 / la) + 0.5 * MU * (lb**-4 - la**-4)


sphere = af.FemBody(
    af.spherical_shell_octant(A, B, n, n),
    af.MooneyRivlin(C10=MU / 2, kappa=MU),
    1000.0,
    incompressibility=1e3 * MU,
    name="sphere",
)
for k in range(3):  # symmetry planes: only the normal component is fixed
    sphere.fix_nodes(sphere.find_nodes(lambda x, k=k: np.abs(x[k]) < 1e-9), components=(k,))
load = sphere.add_pressure(0.0, where=lambda x: np.linalg.norm(x, axis=0) < A + 1e-9, closed=True)
scene = af.Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
scene.add(sphere)

limit = minimize_scalar(lambda la: -pressure_of(la), bounds=(1.0, 3.0), method="bounded")
p_max = pressure_of(limit.x)
X = sphere.V.tabulate_dof_coordinates()
inner = np.isclose(np.linalg.norm(X, axis=1), A)
levels = np.linspace(0.0, 0.85 * p_max, 3 if quick else 9)[1:]
rows = []
for p in levels:
    load.set(p)
    iterations = scene.solve_static()  # from the last equilibrium (load_steps ramp from 0)
    x = X + sphere.u.x.array.reshape(-1, 3)
    la = float(np.linalg.norm(x[inner], axis=1).mean() / A)
    exact = brentq(lambda s: pressure_of(s) - p, 1.0, limit.x)
    rows.append(
        {
            "p_over_mu": p / MU,
            "la_fem": la,
            "la_exact": exact,
            "error_la_minus_1": (la - exact) / (exact - 1.0),
            "newton": iterations,
        }
    )
    print(f"p = {p:.3f} mu: la = {la:.4f} (closed form {exact:.4f}), Newton {iterations}")

out.mkdir(parents=True, exist_ok=True)
(out / "inflated_sphere.json").write_text(
    json.dumps(
        {
            "A": A,
            "B": B,
            "mu": MU,
            "kappa_inc": 1e3 * MU,
            "cells_per_patch_side": n,
            "p_max_over_mu": p_max / MU,
            "la_at_p_max": limit.x,
            "levels": rows,
        },
        indent=1,
    )
)
la = np.linspace(1.0, 2.5, 200)
fig, ax = plt.subplots(figsize=(5.5, 4))
ax.plot(la, pressure_of(la) / MU, "k-", label="incompressible closed form")
ax.plot([r["la_fem"] for r in rows], [r["p_over_mu"] for r in rows], "o", label="FEM octant")
ax.set_xlabel("inner hoop stretch a / A")
ax.set_ylabel("p / mu")
ax.set_title(f"thick sphere B/A = {B / A:g}: internal pressure")
ax.legend()
fig.tight_layout()
fig.savefig(out / "pressure_stretch.png", dpi=120)
# seen from the cavity's side: the symmetry planes show the wall, the inner face moves most
af.render_bodies(
    out / "inflated_sphere.png",
    [(sphere.mesh, sphere.u)],
    scalars="displacement",
    scalar_name="displacement (m)",
    show_rest=True,
    camera=[(-4.0, -5.0, -3.0), (0.8, 0.8, 0.8), (0.0, 0.0, 1.0)],
)
print(
    f"largest error of la - 1: {max(abs(r['error_la_minus_1']) for r in rows):.2%} "
    f"({n}^3 hexahedra per patch); wrote {out}/"
)
