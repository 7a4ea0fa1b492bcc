"""``artifem study beam-ellipsoid`` (models/beam_ellipsoid/study.py) end to end: static
solve, reference, a short swing, PNG (decoded, not blank) and JSON.

The physics checks of the scene (static deflection against the stiff-block
reference, the swing's energy) are in tests/test_multibody_coupled.py; this
runs the script as a user would and checks what it writes against references
that do not come from an earlier run of the same code:

- the stiff-block FEM reference the script solves itself (the beam extended by
  a block 1e4 times stiffer, same weight and moment: no coupling involved) for
  both couplings of the ellipsoid;
- Euler-Bernoulli theory and the ellipsoid's mass, computed here from the
  configuration;
- free fall for the first 20 ms of the swing, and no energy gain.
"""

import argparse
import json

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.models.beam_ellipsoid.model import BeamEllipsoidConfig, build_reference
from artifem.models.beam_ellipsoid.study import run
from outputs import assert_picture

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")

G = 9.81


def euler_bernoulli_mm(config: BeamEllipsoidConfig, mass: float) -> float:
    """Tip deflection (mm) of the clamped cantilever, small deflection, no shear: its own
    weight q (q L^4 / 8 EI) and the ellipsoid's weight W hung a beyond the end (a force W
    and a moment W a at x = L: W L^3 / 3 EI + W a L^2 / 2 EI)."""
    L, b, h = config.length, config.width, config.height
    EI = config.young * b * h**3 / 12.0
    q, W, a = config.density * b * h * G, mass * G, config.semi_axes[0]
    return 1e3 * (q * L**4 / (8 * EI) + W * L**3 / (3 * EI) + W * a * L**2 / (2 * EI))


def test_run_writes_the_picture_and_the_figures(tmp_path):
    """Tolerances:

    - rigid end face against the stiff-block reference: 1e-6. Both have the same beam
      mesh, resultant and moment about the end face; they differ only by the block's
      compliance, O(1 / stiffness ratio) of the block's small share (measured
      1.2e-4 / ratio: 1.2e-6 at 100x, 1.2e-7 at 1000x, 1.2e-8 at the script's 1e4x).
    - end frame against the reference: 3e-4. The frame leaves the end face deformable
      (the load spread over it); measured 5e-5 less.
    - Euler-Bernoulli: 0.93 < FEM / EB < 1.03. Above: the continuum adds shear
      deflection (Timoshenko, 3 E h^2 / (12 k G L^2) ~ 2 % of the end-load part) and a
      displacement FEM is stiffer than the continuum (its compliance is a lower bound);
      below: the 24 x 4 x 4 Q1 mesh's shear locking and the clamped face's Poisson
      constraint (measured 0.967). Dropping the moment W a (-11 %) or the beam's weight
      (-47 %) falls out of it.
    - swing, t = 20 ms (10 steps of 2 ms): the released tip first falls freely,
      g t^2 / 2 = 1.96 mm, less the restoring force's (omega t)^2 / 12 < 2 %
      (omega^2 = g / static deflection), plus the semi-implicit Euler's (n + 1) / n = 1.1
      on n = 10 steps: 0.9 to 1.25 of g t^2 / 2 (measured 1.13); no energy gain.
    """
    dt, duration = 2e-3, 0.02
    assert run(argparse.Namespace(out=tmp_path, dt=dt, duration=duration)) == 0
    figures = json.loads((tmp_path / "beam_ellipsoid.json").read_text())
    config = BeamEllipsoidConfig()
    a, b, c = config.semi_axes
    mass = config.ellipsoid_density * 4.0 / 3.0 * np.pi * a * b * c
    assert figures["ellipsoid_mass_kg"] == pytest.approx(mass, rel=1e-12)
    static = figures["static"]
    face = static["rigid_end_face"]["tip_deflection_mm"]
    frame = static["end_frame"]["tip_deflection_mm"]
    reference = static["reference_mm"]
    assert abs(face - reference) < 1e-6 * reference
    assert abs(frame - reference) < 3e-4 * reference
    assert static["frame_vs_reference"] == pytest.approx(
        abs(frame - reference) / reference, rel=1e-9
    )
    theory = euler_bernoulli_mm(config, mass)
    assert static["euler_bernoulli_mm"] == pytest.approx(theory, rel=1e-12)
    for tip in (face, frame, reference):
        assert 0.93 < tip / theory < 1.03, (tip, theory)
    swing = figures["swing"]
    free_fall_mm = 1e3 * 0.5 * G * duration**2
    assert 0.9 < swing["max_tip_mm"] / free_fall_mm < 1.25, swing["max_tip_mm"]
    energy = swing["energy_J"]
    assert np.isfinite(energy["final"])
    assert energy["max"] <= energy["initial"] + 1e-9 * abs(energy["initial"])
    assert_picture(tmp_path / "beam_ellipsoid.png")


def test_reference_block_must_be_whole_cells():
    with pytest.raises(ValueError, match="whole number of beam cells"):
        build_reference(BeamEllipsoidConfig(semi_axes=(0.047, 0.035, 0.035)))


def test_simulate_beam_ellipsoid_is_the_studys_swing(tmp_path):
    """``artifem simulate beam-ellipsoid`` (the runner, its frame case at the smallest level,
    12 x 2 x 2 hexahedra) releases the same scene as the study's swing on that mesh: the
    same tip deflection at every step, and the released tip first falls freely (the
    study's test above)."""
    from artifem.cli import main
    from artifem.models.beam_ellipsoid.model import LEVELS
    from artifem.models.beam_ellipsoid.study import swing

    dt, duration = 2e-3, 0.02
    common = ["--dt", str(dt), "--duration", str(duration), "--no-progress", "--no-vtx"]
    argv = ["simulate", "beam-ellipsoid", "--level", "0", "--out", str(tmp_path), *common]
    assert main(argv) == 0
    figures = json.loads((tmp_path / "frame" / "simulate.json").read_text())
    config = BeamEllipsoidConfig(cells=LEVELS[0])
    *_, rec, _ = swing(config, duration, dt, attach="frame")
    assert figures["nodes"] == 13 * 3 * 3
    assert figures["steps"] == 10 and figures["max_tip_mm"] == pytest.approx(
        1e3 * rec["tip"].max(), rel=1e-10
    )
    assert figures["energy_J"]["max"] == pytest.approx(rec["energy"].max(), rel=1e-10)
    assert figures["energy_J"]["max"] <= figures["energy_J"]["initial"] + 1e-9 * abs(
        figures["energy_J"]["initial"]
    )
    a, b, c = config.semi_axes
    mass = config.ellipsoid_density * 4.0 / 3.0 * np.pi * a * b * c
    assert figures["ellipsoid_mass_kg"] == pytest.approx(mass, rel=1e-12)
    theory = euler_bernoulli_mm(config, mass)
    assert figures["euler_bernoulli_static_tip_mm"] == pytest.approx(theory, rel=1e-12)
    free_fall_mm = 1e3 * 0.5 * G * duration**2
    assert 0.9 < figures["max_tip_mm"] / free_fall_mm < 1.25
    assert_picture(tmp_path / "frame" / "beam-ellipsoid.png")
