"""Every demo script runs to the end and writes what it says it writes."""

import subprocess
import sys
from pathlib import Path

import pytest

DEMOS = Path(__file__).resolve().parents[1] / "demos"


@pytest.mark.parametrize("script, outputs", [
    ("material_prototyping.py", ["yeoh.png", "tongue_mooney_rivlin.png"]),
    ("tongue_gravity.py", ["tongue_gravity.png", "tongue.bp"]),
])
def test_demo_runs(script, outputs, tmp_path):
    run = subprocess.run([sys.executable, str(DEMOS / script), str(tmp_path)],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    for name in outputs:
        assert (tmp_path / name).exists(), f"{script} did not write {name}"
