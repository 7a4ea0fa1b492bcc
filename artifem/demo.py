"""The main job (``make demo``): the muscle-driven beam and the tongue's three motions.

Until the reduced-model study exists, the demo runs the muscle-driven
cantilever (``artifem simulate beam``) and the ArtiSynth tongue's protrusion,
retroflexion and retraction (``artifem simulate tongue --motion all``), and
says where their pictures and figures are. About 30 s on 2 cores once compiled.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from artifem.models import muscle_beam
from artifem.models.tongue import simulate as tongue


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("results/demo"), help="output directory")


def run(args: argparse.Namespace) -> int:
    beam_parser, tongue_parser = argparse.ArgumentParser(), argparse.ArgumentParser()
    muscle_beam.add_arguments(beam_parser)
    tongue.add_arguments(tongue_parser)
    status = muscle_beam.run(beam_parser.parse_args(["--out", str(args.out / "muscle_beam")]))
    status = status or tongue.run(tongue_parser.parse_args(
        ["--motion", "all", "--out", str(args.out / "tongue")]))
    print(f"demo: beam pictures {args.out}/muscle_beam/beam.png and tip.png; tongue motions "
          f"side by side {args.out}/tongue/motions.png; figures in */simulate.json; "
          f"ParaView series in */*.bp")
    return status
