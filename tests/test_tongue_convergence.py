"""Tongue levels 0 and 1 agree on protrusion within the measured discretization error.

models/tongue/convergence.py runs the three speech motions on both levels
(docs/tongue_convergence.md). For protrusion it measured, at t = 1.0 s
(semi-implicit, dt = 0.01 s; the hold phase has settled to equilibrium):

    tip, level 0: (-1.40, 0.00, 6.64) mm   |d0| = 6.78 mm
    tip, level 1: (-1.22, 0.00, 7.69) mm   |d1| = 7.79 mm
    |d0 - d1| = 1.07 mm, 14 % of |d1|

The runs are deterministic to about 1e-4 mm (the integrators and dt = 0.05 s
reproduce the same equilibrium to that precision, docs/tongue_hard_cases.md),
so the tolerance is the measured difference with a 50 % margin: |d0 - d1| <
1.6 mm and < 21 % of |d1|. What it guards against: level 1 drifting away from
level 0 through the refinement (fiber directions, bundles or fixed nodes
carried over wrongly, landmarks mapped to other nodes), which moves the tip by
several millimetres; and a motion so small that agreement means nothing
(|d1| > 5 mm, same direction within 15 degrees). One motion only, to keep it
cheap: the test takes about 100 s here (level 1 about 90 s).

The level-1 run is the ``level_1`` hard case (checked here too: the level-1
tongue, semi-implicit, protrusion, dt = 0.01 s, 1.0 s): both read the session fixture
``level1_protrusion`` (tests/conftest.py), which checks that it is the run
``run_motions(1, ("protrusion",))`` would make, so it is computed once per run.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.models.tongue.convergence import landmark_mm, run_motions
from hard_case_checks import check_outcome

#: Measured |d0 - d1| of the protrusion tip at t = 1 s (mm) and relative to |d1|.
MEASURED_MM, MEASURED_REL = 1.07, 0.14
TOLERANCE_MM, TOLERANCE_REL = 1.5 * MEASURED_MM, 1.5 * MEASURED_REL


@pytest.mark.slow
def test_protrusion_tip_level0_agrees_with_level1(level1_protrusion):
    d0 = landmark_mm(run_motions(0, ("protrusion",))["protrusion"], "tip", 1.0)
    _, level1 = level1_protrusion  # run_motions(1, ("protrusion",))["protrusion"]
    assert level1["outcome"] == "finished", (  # run_motions raises SolverError otherwise
        f"tongue protrusion at level 1 did not finish: "
        f"{level1.get('error') or level1.get('inversion')}"
    )
    d1 = landmark_mm(level1, "tip", 1.0)
    assert np.all(np.isfinite(d0)) and np.all(np.isfinite(d1))
    n1 = np.linalg.norm(d1)
    assert n1 > 5.0, f"level 1 tip moved only {d1} mm"
    cos = float(d0 @ d1 / (np.linalg.norm(d0) * n1))
    assert cos > np.cos(np.radians(15)), f"tip directions differ: {d0} vs {d1} mm"
    diff = float(np.linalg.norm(d0 - d1))
    assert diff < TOLERANCE_MM, f"|d0 - d1| = {diff:.2f} mm (level 0 {d0}, level 1 {d1})"
    assert diff / n1 < TOLERANCE_REL, f"|d0 - d1| / |d1| = {diff / n1:.3f}"


@pytest.mark.slow
def test_the_level1_protrusion_is_a_sound_hard_case(level1_protrusion):
    """The hard case ``level_1`` is this run (models/tongue/hard_cases.py): it finishes, or
    stops with the inversion error naming time, elements and det F, never NaN
    (tests/hard_case_checks.py). Here rather than in test_tongue_hard_cases.py so that the
    run is made once, on the worker that holds this file."""
    tongue, result = level1_protrusion
    check_outcome("level_1", tongue, result)
