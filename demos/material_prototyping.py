"""
Prototype a material at the form level: write its energy in UFL, check it, use it
=================================================================================

A Yeoh material, W = sum_i c_i (I1bar - 3)^i + kappa/2 (J - 1)^2, written here in
a few lines, is checked the way one checks any new energy before a full
model: stress-free and with zero energy at rest, the small-strain shear
modulus 2 c_1, and its curves beside the tongue's Mooney-Rivlin.

    python demos/material_prototyping.py [OUT_DIR]
"""

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import artifem as af  # first: orders MPI ahead of dolfinx
from artifem.forms import MooneyRivlin, isochoric_invariants, jacobian

out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/material_prototyping")
out.mkdir(parents=True, exist_ok=True)


@dataclass(frozen=True)
class Yeoh:
    c1: float
    c2: float
    c3: float
    kappa: float

    def strain_energy(self, F):
        I1bar, _ = isochoric_invariants(F)
        return (
            self.c1 * (I1bar - 3)
            + self.c2 * (I1bar - 3) ** 2
            + self.c3 * (I1bar - 3) ** 3
            + self.kappa / 2 * (jacobian(F) - 1) ** 2
        )


yeoh = Yeoh(c1=1037.0, c2=486.0, c3=50.0, kappa=10370.0)

psi, P, A = af.point_response(yeoh, np.eye(3))
print(f"at rest: psi = {psi:.2e}, |P| = {np.abs(P).max():.2e}")
gamma = 1e-4
_, P, _ = af.point_response(yeoh, np.eye(3) + gamma * np.outer([1, 0, 0], [0, 1, 0]))
print(f"small-strain shear modulus {P[0, 1] / gamma:.1f} Pa (theory 2 c1 = {2 * yeoh.c1:.1f} Pa)")

stretches = np.linspace(0.7, 1.5, 33)
af.plot_stress_stretch(af.stress_stretch_curves(yeoh, stretches), out / "yeoh.png", title="Yeoh")
af.plot_stress_stretch(
    af.stress_stretch_curves(MooneyRivlin.tongue(), stretches),
    out / "tongue_mooney_rivlin.png",
    title="tongue Mooney-Rivlin",
)
print(f"curves in {out}/yeoh.png and {out}/tongue_mooney_rivlin.png")
