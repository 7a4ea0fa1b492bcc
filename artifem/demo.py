"""The main job (``make demo``): the muscle-driven beam, rendered and measured.

Until the tongue study exists, the demo runs the muscle-driven cantilever of
``artifem.models.muscle_beam`` and says where its pictures and figures are.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from artifem.models import muscle_beam


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("results/demo"), help="output directory")


def run(args: argparse.Namespace) -> int:
    beam_args = argparse.Namespace(out=args.out / "muscle_beam", integrator="semi-implicit",
                                   cells=[24, 6, 6], excitation=1.0, dt=0.01, no_progress=False)
    status = muscle_beam.run(beam_args)
    print(f"demo: pictures {args.out}/muscle_beam/beam.png and tip.png, figures "
          f"{args.out}/muscle_beam/simulate.json, ParaView series "
          f"{args.out}/muscle_beam/displacement.bp")
    return status
