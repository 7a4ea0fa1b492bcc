"""The main job (``make demo``): the reduced tongue study, then the full-model scenes.

1. ``artifem study tongue`` on the level-0 tongue: training, bases, integration
   points, the full model and twelve reduced configurations through the three
   speech motions, the train/test split on five held-out random schedules, and the
   report (about 5 minutes on 2 cores the first time; training is cached in the output
   directory, so a second run skips it);
2. the muscle-driven cantilever (``artifem simulate beam``) and the tongue's
   protrusion, retroflexion and retraction (``artifem simulate tongue --case all``).

``--quick``: the same job, small (a minute on 2 cores): ``study tongue --quick``,
the beam on 8 x 2 x 2 cells for 0.2 s and each tongue motion for 0.1 s; results
to look at the pipeline by, not figures to quote.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from artifem.models import muscle_beam
from artifem.models.tongue import model as tongue, study


#: ``--quick``: extra arguments of each part.
QUICK_STUDY = ["--quick"]
QUICK_BEAM = ["--level", "0", "--duration", "0.2", "--dt", "0.02"]
QUICK_TONGUE = ["--duration", "0.1"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("results/demo"), help="output directory")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a small run of the same job (study tongue --quick, the beam on "
        f"its level {QUICK_BEAM[1]} for {QUICK_BEAM[3]} s, each "
        f"tongue motion for {QUICK_TONGUE[1]} s)",
    )


def _parse(module, argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    return parser.parse_args(argv)


def run(args: argparse.Namespace) -> int:
    quick = args.quick
    status = study.run(
        _parse(study, ["--out", str(args.out / "study")] + (QUICK_STUDY if quick else []))
    )
    status = status or muscle_beam.run(
        _parse(
            muscle_beam, ["--out", str(args.out / "muscle_beam")] + (QUICK_BEAM if quick else [])
        )
    )
    status = status or tongue.run(
        _parse(
            tongue,
            ["--case", "all", "--out", str(args.out / "tongue")] + (QUICK_TONGUE if quick else []),
        )
    )
    print(
        f"demo: reduced-model study report {args.out}/study/report.md (speed versus error, "
        f"Table 2 analog, plots and renders beside it); beam pictures "
        f"{args.out}/muscle_beam/curl/beam.png; tongue motions {args.out}/tongue/cases.png; "
        f"ParaView series in */*.bp"
    )
    return status
