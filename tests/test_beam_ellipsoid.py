"""models/beam_ellipsoid.py end to end: static solve, reference, a short swing, PNG and JSON.

The physics checks of the scene (static deflection against the stiff-block
reference, the swing's energy) are in tests/test_multibody_coupled.py; this
runs the script as a user would and checks what it writes.
"""

import argparse
import json

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.models.beam_ellipsoid import BeamEllipsoidConfig, build_reference, run

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")


def test_run_writes_the_picture_and_the_figures(tmp_path):
    assert run(argparse.Namespace(out=tmp_path, dt=2e-3, duration=0.02)) == 0
    figures = json.loads((tmp_path / "beam_ellipsoid.json").read_text())
    static = figures["static"]
    assert static["rigid_end_face"]["tip_deflection_mm"] == pytest.approx(19.7354732, rel=1e-7)
    assert static["end_frame"]["tip_deflection_mm"] == pytest.approx(19.7344, rel=1e-4)
    assert static["frame_vs_reference"] < 3e-4
    assert np.isfinite(figures["swing"]["energy_J"]["final"])
    png = tmp_path / "beam_ellipsoid.png"
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_reference_block_must_be_whole_cells():
    with pytest.raises(ValueError, match="whole number of beam cells"):
        build_reference(BeamEllipsoidConfig(semi_axes=(0.047, 0.035, 0.035)))
