"""``artifem material curves``: stress-stretch curves of a named material to PNG.

Form-level prototyping from the shell: tabulates the uniaxial (traction-free
lateral faces), equibiaxial and simple-shear responses of the UFL energy and
plots them (see ``artifem.material_response.stress_stretch_curves``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from artifem import forms
from artifem.errors import InputError
from artifem.material_response import plot_stress_stretch, stress_stretch_curves

#: Materials reachable by name; parameters in Pa.
MATERIALS = {
    "tongue": lambda: forms.MooneyRivlin.tongue(),
    "tongue-log": lambda: forms.MooneyRivlin.tongue(bulk="log"),
    "neo-hookean": lambda: forms.NeoHookean.from_young_poisson(3000.0, 0.45),
    "svk": lambda: forms.StVenantKirchhoff.from_young_poisson(3000.0, 0.45),
    "linear": lambda: forms.LinearElastic.from_young_poisson(3000.0, 0.45),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("material", choices=sorted(MATERIALS))
    parser.add_argument("--out", required=True, type=Path, help="PNG path")
    parser.add_argument("--max-stretch", type=float, default=1.5)
    parser.add_argument("--json", action="store_true", help="also write the curves as JSON")


def run(args: argparse.Namespace) -> int:
    if args.max_stretch <= 1.0:
        raise InputError(f"--max-stretch must be > 1, got {args.max_stretch}")
    material = MATERIALS[args.material]()
    stretches = np.linspace(1.0 / args.max_stretch, args.max_stretch, 41)
    curves = stress_stretch_curves(material, stretches)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    plot_stress_stretch(curves, args.out, title=f"{args.material}: {material}")
    if args.json:  # null where a curve has ended (no traction-free state)
        data = {
            mode: {
                k: [None if np.isnan(x) else x for x in np.asarray(v).tolist()]
                for k, v in c.items()
            }
            for mode, c in curves.items()
        }
        args.out.with_suffix(".json").write_text(json.dumps(data, indent=1))
    for mode, c in curves.items():
        ended = np.isnan(np.asarray(c.get("P11", []), dtype=float))
        if ended.any():
            gone = c["stretch"][ended]
            print(
                f"{args.material}: no traction-free {mode} state at {ended.sum()} of the "
                f"{ended.size} stretches ({gone.min():.4g} to {gone.max():.4g}): the curve "
                "ends there"
            )
    print(f"wrote {args.out}")
    return 0
