"""Every demo script (demos/*.py, found by glob) runs to the end in its quick mode
(ARTIFEM_QUICK=1: a few steps) and writes what it says it writes."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

DEMOS = Path(__file__).resolve().parents[1] / "demos"

#: files a demo must write (besides anything else it writes)
OUTPUTS = {
    "material_prototyping.py": ["yeoh.png", "tongue_mooney_rivlin.png"],
    "tongue_gravity.py": ["tongue_gravity.png", "tongue.bp"],
    "bone_hinge_muscle.py": ["bone_hinge_muscle.png", "tissue.bp"],
    "reduced_body_in_joints.py": ["reduced_beam.png", "beam_modes.bp"],
    "skin_pressure.py": ["skin_pressure.png", "block.bp"],
    "static_pressure.py": ["static_pressure.png"],
    "inflated_sphere.py": ["pressure_stretch.png", "inflated_sphere.png", "inflated_sphere.json"],
    "contact_pad_on_bone.py": [
        "contact_pad_on_bone.png",
        "contact_pressure.png",
        "pad.bp",
        "pad_contact_pressure.bp",
    ],
}


def test_every_demo_is_listed():
    assert sorted(p.name for p in DEMOS.glob("*.py")) == sorted(OUTPUTS)


@pytest.mark.parametrize("script", sorted(p.name for p in DEMOS.glob("*.py")))
def test_demo_runs(script, tmp_path):
    env = {**os.environ, "ARTIFEM_QUICK": "1"}
    run = subprocess.run(
        [sys.executable, str(DEMOS / script), str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    for name in OUTPUTS[script]:
        assert (tmp_path / name).exists(), f"{script} did not write {name}"
