"""The quick train/test splits the suite re-derives (issue 32): the quick tongue study and
the quick reduced jaw-tongue study, each with two held-out random schedules (seed 1000),
as the commands below write them; their figures go to docs/benchmarks/quick_splits.json.

    OPENBLAS_NUM_THREADS=1 python scripts/quick_splits.py       # a few minutes

The suite runs the same commands (tests/conftest.py's ``quick_tongue_study``,
tests/test_jaw_tongue_reduced.py) and allows each error at most ``MARGIN`` times the
figure written here: a change that breaks how the reduced models generalize (their
training, basis, points or reduced dynamics) fails a test. The full-size splits the docs
quote (docs/tongue_study.md, docs/reduction.md) take minutes to hours and stay out of the
suite.
"""

import json
import pathlib
import platform
import tempfile

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.cli import main

OUT = pathlib.Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "quick_splits.json"

#: the errors a test allows, relative to this file's (the trained points' greedy choice
#: may turn on round-off on another machine)
MARGIN = 1.25

COMMANDS = {
    "tongue": ["study", "tongue", "--quick", "--held-out", "2"],
    "jaw-tongue": ["study", "jaw-tongue", "--quick", "--duration", "0.15", "--held-out", "2"],
}


def split_figures(split: dict) -> dict:
    """Per set of a generalization.json, each run's largest and mean error (mm) and its
    estimate over its error."""
    return {
        name: {
            r["name"]: {
                "max_error_mm": r["max_error_mm"],
                "mean_error_mm": r["mean_error_mm"],
                "estimate_ratio": r["estimate_ratio"],
            }
            for r in runs
        }
        for name, runs in split["sets"].items()
    }


def tongue_figures(out: pathlib.Path) -> dict:
    """The quick study's largest error of each run (mm), by run id."""
    study = json.loads((out / "study.json").read_text())
    return {r["id"]: r["max_error_mm"] for r in study["runs"]}


def jaw_tongue_figures(out: pathlib.Path) -> dict:
    """The quick comparison's errors, by motion."""
    figures = json.loads((out / "jaw_tongue_reduced.json").read_text())
    keys = ("max_mean_error_mm", "max_angle_difference_deg")
    return {m: {k: r[k] for k in keys} for m, r in figures["motions"].items()}


def main_() -> None:
    doc = {
        "what": "the quick train/test splits the suite re-derives, each command's figures",
        "command": "OPENBLAS_NUM_THREADS=1 python scripts/quick_splits.py",
        "machine": platform.processor() or platform.machine(),
        "margin": MARGIN,
        "splits": {},
    }
    figures = {"tongue": tongue_figures, "jaw-tongue": jaw_tongue_figures}
    for name, argv in COMMANDS.items():
        with tempfile.TemporaryDirectory() as d:
            out = pathlib.Path(d)
            print(f"quick_splits: artifem {' '.join(argv)} --out {out}", flush=True)
            if main([*argv, "--out", str(out)]) != 0:
                raise SystemExit(f"quick_splits: `artifem {' '.join(argv)}` failed")
            split = json.loads((out / "generalization.json").read_text())
            doc["splits"][name] = {
                "argv": argv,
                "specification": split["specification"],
                "training_duration": split["training_duration"],
                "reduced": {k: split["reduced"][k] for k in ("runs", "basis", "points")},
                "runs": figures[name](out),
                "sets": split_figures(split),
            }
    OUT.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"quick_splits: {OUT}")


if __name__ == "__main__":
    main_()
