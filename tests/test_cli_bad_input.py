"""Every command answers its typical bad inputs with one line on stderr and a non-zero
exit status, before any model is built (no traceback, nothing written)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from artifem.cli import main


def schedule(tmp_path, text):
    path = tmp_path / "schedule.json"
    path.write_text(text)
    return str(path)


CASES = [  # (argv, fragment of the one line); "{tmp}" is the test's own directory
    (["mesh", "info", "{tmp}/nope.node"], "ANSYS node file not found"),
    (
        ["material", "curves", "tongue", "--out", "{tmp}/c.png", "--max-stretch", "0.5"],
        "--max-stretch must be > 1",
    ),
    (["material", "curves", "jelly", "--out", "{tmp}/c.png"], "invalid choice: 'jelly'"),
    (["simulate", "beam", "--out", "{tmp}/o", "--dt", "-1"], "argument --dt: must be > 0"),
    (
        ["simulate", "beam", "--out", "{tmp}/o", "--excitation", "2"],
        "argument --excitation: must be in [0, 1]",
    ),
    (
        ["simulate", "beam", "--out", "{tmp}/o", "--level", "3"],
        "argument --level: invalid choice: 3",
    ),
    (
        ["simulate", "tongue", "--out", "{tmp}/o", "--duration", "0"],
        "argument --duration: must be > 0",
    ),
    (
        ["simulate", "tongue", "--out", "{tmp}/o", "--schedule", "{tmp}/missing.json"],
        "excitation schedule file not found",
    ),
    (
        [
            "simulate",
            "tongue",
            "--out",
            "{tmp}/o",
            "--schedule",
            "schedule:" + json.dumps({"times": [0, 0.5], "excitations": {"GGP": [0, 2.0]}}),
        ],
        "values of 'GGP' must be in [0, 1]",
    ),
    (
        [
            "simulate",
            "tongue",
            "--out",
            "{tmp}/o",
            "--schedule",
            "schedule:" + json.dumps({"times": [0, 0.5], "excitations": {"XX": [0, 0.5]}}),
        ],
        "unknown muscle 'XX'",
    ),
    (
        ["simulate", "tongue", "--out", "{tmp}/o", "--schedule", "schedule:{\"GGP\": 1}"],
        "not an excitation schedule",
    ),
    (["simulate", "tongue", "--out", "{tmp}/o", "--case", "yawn"], "invalid choice: 'yawn'"),
    (["simulate", "beam-ellipsoid", "--out", "{tmp}/o", "--dt", "0"], "argument --dt: must be > 0"),
    (["simulate", "jaw-tongue", "--out", "{tmp}/o", "--dt", "-0.01"], "argument --dt: must be > 0"),
    (
        ["study", "styloglossus", "--out", "{tmp}/o", "--tension", "-1"],
        "argument --tension: must be >= 0",
    ),
    (
        ["study", "airway", "--out", "{tmp}/o", "--pressure", "nan"],
        "argument --pressure: must be finite",
    ),
    (["study", "airway", "--out", "{tmp}/o", "--motions", "flap"], "invalid choice: 'flap'"),
    (["simulate", "airway", "--out", "{tmp}/o", "--pressure", "-1"], "must be >= 0"),
    (["simulate", "airway", "--out", "{tmp}/o", "--tongue", "half"], "invalid choice: 'half'"),
    (
        ["simulate", "masseter", "--out", "{tmp}/o", "--excitation", "1.5"],
        "argument --excitation: must be in [0, 1]",
    ),
    (["bench", "fom", "--out", "{tmp}/b.json", "--sizes", "7q"], "'7q' is neither one of"),
    (["bench", "tongue", "--out", "{tmp}/b.json", "--ranks", "0"], "expected positive integers"),
    (["bench", "scenes", "--out", "{tmp}/b.json", "--scenes", "moon"], "unknown scenes ['moon']"),
    (
        ["study", "tongue", "--out", "{tmp}/o", "--points", "-3"],
        "argument --points: must be a positive integer",
    ),
    (
        ["study", "jaw-tongue", "--out", "{tmp}/o", "--r", "0"],
        "argument --r: must be a positive integer",
    ),
    (["simulate", "beam", "--dt", "0.1"], "the following arguments are required: --out"),
    (["simulate", "pendulum"], "invalid choice: 'pendulum'"),
    # every subcommand: a missing file, a value out of range, an unknown name (where it
    # takes one), the quick modes included
    (["mesh", "info", "{tmp}/mesh.xyz"], "unknown mesh file extension '.xyz'"),
    (["simulate", "tongue", "--out", "{tmp}/o", "--level", "2"], "invalid choice: 2"),
    (["simulate", "tongue", "--out", "{tmp}/o", "--integrator", "rk4"], "invalid choice: 'rk4'"),
    (
        ["simulate", "tongue", "--out", "{tmp}/o", "--incompressibility", "rigid"],
        "invalid choice: 'rigid'",
    ),
    (
        ["simulate", "beam-ellipsoid", "--out", "{tmp}/o", "--duration", "inf"],
        "argument --duration: must be finite",
    ),
    (
        ["simulate", "jaw-tongue", "--out", "{tmp}/o", "--schedule", "{tmp}/missing.json"],
        "excitation schedule file not found",
    ),
    (
        [
            "simulate",
            "jaw-tongue",
            "--out",
            "{tmp}/o",
            "--schedule",
            "schedule:" + json.dumps({"times": [0, 0.5], "excitations": {"XX": [0, 0.5]}}),
        ],
        "unknown muscles ['XX']",
    ),
    (["simulate", "jaw-tongue", "--out", "{tmp}/o", "--case", "yawn"], "invalid choice: 'yawn'"),
    (
        ["study", "styloglossus", "--out", "{tmp}/o", "--r", "0"],
        "argument --r: must be a positive integer",
    ),
    (
        ["study", "styloglossus", "--out", "{tmp}/o", "--duration", "-0.3"],
        "argument --duration: must be > 0",
    ),
    (
        ["study", "styloglossus", "--out", "{tmp}/o", "--duration", "0.02", "--r", "4"],
        "r = 4 POD vectors need as many training snapshots",
    ),
    (
        ["study", "scene", "artifem.models.styloglossus.model", "--out", "{tmp}/o"],
        "give the model as MODULE:FUNCTION",
    ),
    (
        [
            "study",
            "scene",
            "artifem.models.styloglossus.model:reducible",
            "--out",
            "{tmp}/o",
            "--each-alone",
            "1.5",
        ],
        "argument --each-alone: must be in [0, 1]",
    ),
    (["simulate", "airway", "--out", "{tmp}/o", "--dt", "0"], "argument --dt: must be > 0"),
    (
        ["study", "masseter", "--out", "{tmp}/o", "--coarse", "--steps", "0"],
        "argument --steps: must be a positive integer",
    ),
    (
        ["bench", "fom", "--out", "{tmp}/b.json", "--ranks", "x"],
        "--ranks: expected comma-separated integers",
    ),
    (["bench", "fom", "--out", "{tmp}/b.json", "--solver", "lu"], "--solver: unknown ['lu']"),
    (
        ["bench", "tongue", "--out", "{tmp}/b.json", "--levels", "2"],
        "--levels: expected comma-separated levels among 0, 1",
    ),
    (
        ["bench", "tongue", "--out", "{tmp}/b.json", "--motion", "swallow"],
        "--motion: unknown 'swallow'",
    ),
    (
        ["bench", "scenes", "--out", "{tmp}/b.json", "--quick", "--steps", "-1"],
        "argument --steps: must be a positive integer",
    ),
    (
        ["bench", "reduced", "--out", "{tmp}/b.json", "--incompressibility", "lu"],
        "--incompressibility: choose from penalty, hard; got 'lu'",
    ),
    (
        ["bench", "reduced", "--out", "{tmp}/b.json", "--incompressibility", ","],
        "--incompressibility: choose from penalty, hard; got ','",
    ),
    (["study", "tongue", "--out", "{tmp}/o", "--level", "2"], "invalid choice: 2"),
    (["study", "tongue", "--out", "{tmp}/o", "--quick", "--bases", "pca"], "invalid choice: 'pca'"),
    (["study", "jaw-tongue", "--out", "{tmp}/o", "--motions", "yawn"], "invalid choice: 'yawn'"),
    (
        ["study", "jaw-tongue", "--out", "{tmp}/o", "--quick", "--duration", "-1"],
        "argument --duration: must be > 0",
    ),
    (
        ["study", "robustness", "tongue-level2", "--out", "{tmp}/o"],
        "unknown model 'tongue-level2'; choose one of ['jaw-tongue', 'tongue'",
    ),
    (
        ["study", "robustness", "tongue", "--out", "{tmp}/o", "--schedules", "0"],
        "argument --schedules: must be a positive integer",
    ),
    (["demo", "--quick", "--out", "{tmp}/o", "--steps", "3"], "unrecognized arguments: --steps 3"),
    (["demo", "--quick", "--out", "file:{tmp}/taken"], "Not a directory"),
]


def _argv(tmp_path, argv):
    """ "schedule:TEXT": a schedule file holding TEXT; "file:PATH": an existing (empty) file."""
    out = []
    for a in argv:
        if a.startswith("schedule:"):
            a = schedule(tmp_path, a[len("schedule:") :])
        elif a.startswith("file:"):
            a = a[len("file:") :].replace("{tmp}", str(tmp_path))
            Path(a).write_text("")
        out.append(a.replace("{tmp}", str(tmp_path)))
    return out


@pytest.mark.parametrize(
    "argv, fragment", CASES, ids=[" ".join(c[0][:2]) + f" #{i}" for i, c in enumerate(CASES)]
)
def test_bad_input_is_one_line_and_a_nonzero_exit(tmp_path, capsys, argv, fragment):
    try:
        status = main(_argv(tmp_path, argv))
    except SystemExit as exc:  # argparse's own usage errors
        status = exc.code
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert status != 0
    assert len(lines) == 1, captured.err
    assert fragment in lines[0] and "error" in lines[0]
    assert "Traceback" not in captured.err + captured.out
    assert not (tmp_path / "o").exists() and not (tmp_path / "b.json").exists()


def test_console_script_bad_schedule_has_no_traceback(tmp_path):
    """The installed command as a user runs it: one line, exit status 2."""
    exe = Path(sys.executable).parent / "artifem"
    if not exe.exists():
        pytest.skip("artifem console script not installed in this environment")
    path = schedule(tmp_path, json.dumps({"times": [0, 0.5], "excitations": {"GGP": [0, 2]}}))
    out = subprocess.run(
        [str(exe), "simulate", "tongue", "--schedule", path, "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        "artifem: error: excitation schedule: values of 'GGP' must be in [0, 1]"
    ]
