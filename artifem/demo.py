"""The main job (``make demo``): the reduced tongue study, then the full-model scenes.

1. ``artifem study tongue`` on the level-0 tongue: training, bases, integration
   points, the full model and twelve reduced configurations through the three
   speech motions, and the report (about 5 minutes on 2 cores the first time;
   training is cached in the output directory, so a second run skips it);
2. the muscle-driven cantilever (``artifem simulate beam``) and the tongue's
   protrusion, retroflexion and retraction (``artifem simulate tongue --motion all``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from artifem.models import muscle_beam
from artifem.models.tongue import simulate as tongue, study


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("results/demo"), help="output directory")


def _parse(module, argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    return parser.parse_args(argv)


def run(args: argparse.Namespace) -> int:
    status = study.run(_parse(study, ["--out", str(args.out / "study")]))
    status = status or muscle_beam.run(_parse(muscle_beam, ["--out", str(args.out / "muscle_beam")]))
    status = status or tongue.run(_parse(tongue, ["--motion", "all",
                                                  "--out", str(args.out / "tongue")]))
    print(f"demo: reduced-model study report {args.out}/study/report.md (speed versus error, "
          f"Table 2 analog, plots and renders beside it); beam pictures "
          f"{args.out}/muscle_beam/beam.png; tongue motions {args.out}/tongue/motions.png; "
          f"ParaView series in */*.bp")
    return status
