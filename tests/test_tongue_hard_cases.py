"""The tongue on hard cases, semi-implicit: finish cleanly or stop with a clear error, never NaN.

One test per case of models/tongue/hard_cases.py (all eleven exciters at 1.0,
excitations stepped without a ramp, dt = 0.05 s, kappa = 100 C10 and 1000 C10), 1.0 s
each. A case passes when the run either (tests/hard_case_checks.py)

- finishes: every landmark finite, min det F > 0 over all steps and no
  element inverted at the end; or
- raises ElementInversionError whose message names the time, the elements and
  det F, with the body left finite and uninverted at the start of the failed step.

Any other exception (or a NaN) fails. The step and dt_0.05 protrusion variants end on the
same landmarks (docs/tongue_hard_cases.md). The implicit integrator's runs and the
agreement of the two integrators are in tests/test_tongue_hard_cases_implicit.py (files
apart so that the two pytest workers share the work). The ``level_1`` case (about 3
minutes) is not in the suite: ``python -m artifem.models.tongue.hard_cases --cases
level_1`` runs it; tests/test_tongue_convergence.py compares the levels' static
equilibria.

Durations on this machine (serial), see that page: the level-0 cases 2-10 s each (4-30 s
with other jobs on the machine).
"""

import re

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.models.tongue.hard_cases import build_case, run_built
from hard_case_checks import PENALTY, check_outcome, check_protrusion_variants, make_runs


@pytest.fixture(scope="module")
def runs():
    return make_runs()


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in PENALTY if n != "level_1"])
def test_hard_case_semi_implicit(name, runs):
    tongue, result = runs(name, "semi-implicit")
    assert tongue.config.integrator == "semi-implicit"
    check_outcome(name, tongue, result)


@pytest.mark.slow
@pytest.mark.parametrize("integrator", ["semi-implicit"])
def test_protrusion_variants_end_on_the_same_state(integrator, runs):
    check_protrusion_variants(runs, integrator)


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [
        "incompressible_dt_0.05",
        "incompressible_step",
        "incompressible_all_exciters",
        "incompressible_coactivation",
        "incompressible_all_step",
    ],
)
def test_hard_incompressibility_on_a_hard_case(name, runs):
    """The tongue's default (hard incompressibility, semi-implicit with the implicit
    fallback) finishes the hard cases, 1 s each: the protrusion targets switched on at
    t = 0 (``step``), every exciter at 1.0 ramped (``all_exciters``) or switched on at
    t = 0 (``all_step``), antagonists together at 1.0 from t = 0 (``coactivation``), with
    min det F > 0 and the volume held to the element tolerance 1e-4 (the penalty lets it
    change by about 3 %). A step that leaves volumes off by more than 1 % is projected back
    (``integrators._project_volumes``); where the semi-implicit step inverts elements (the
    co-activation and every exciter switched on at once) the implicit Newton step takes
    over (``fallbacks``); the dt = 0.05 s protrusion finishes too."""
    tongue, result = runs(name, "semi-implicit")
    assert tongue.config.integrator == "semi-implicit"
    check_outcome(name, tongue, result)
    assert result["outcome"] == "finished", result.get("error")
    assert abs(result["volume_change"]) <= 1e-4
    if name in ("incompressible_coactivation", "incompressible_all_step"):
        assert result["fallbacks"] > 0  # the semi-implicit step inverts elements there


@pytest.mark.slow
def test_fast_pulses_finish():
    """Every exciter pulsed at 0.8, two groups in antiphase switched every 0.05 s (within
    1 ms) from t = 0: five switches finish with default settings, the volume held to
    2e-4 (measured 1.1e-4: the semi-implicit steps between switches hold the constraint
    linearized, and what they leave, up to ``Incompressible.step_tol`` per element, the
    next step corrects)."""
    tongue, _, dt = build_case("incompressible_pulses", "semi-implicit")
    result = run_built(tongue, dt, duration=0.25)
    assert result["outcome"] == "finished", result.get("error")
    assert result["steps_done"] == 25 and result["min_det_F"] > 0
    assert abs(result["volume_change"]) <= 2e-4 and result["fallbacks"] > 0


@pytest.mark.slow
def test_the_semi_implicit_step_alone_stops_with_a_clear_error():
    """Without the fallback (``Scene(fallback=None)``) every exciter switched on at once
    stops within the first step after the halvings: the semi-implicit step inverts elements
    there (its volumes projected back or not), and the error names the body, the time, the
    elements and det F, the body left finite and uninverted: the fallback is what makes it
    finish."""
    tongue, _, dt = build_case("incompressible_all_step", "semi-implicit")
    tongue.scene.fallback = None
    result = run_built(tongue, dt, duration=0.05)
    body = tongue.body
    assert np.all(np.isfinite(body.u.x.array)) and body.inverted_elements()[0].size == 0
    assert result["outcome"] == "inversion error", result
    assert result["fallbacks"] == 0 and result["t_reached"] < dt  # within the first step
    assert re.match(
        r"element inversion at t = [\d.e-]+ s: det F = -?[\d.e-]+ <= 0 in \d+ "
        r"element\(s\) of body 'tongue' \[\d+",
        result["inversion"]["message"],
    ), result["inversion"]["message"]
