"""The tongue on hard cases: finish cleanly or stop with a clear inversion error, never NaN.

One test per case of models/tongue/hard_cases.py (all eleven exciters at 1.0,
excitations stepped without a ramp, dt = 0.05 s, kappa = 100 C10 and
1000 C10, level 1), 1.0 s each with the default semi-implicit integrator.
A case passes when the run either

- finishes: every landmark finite, min det F > 0 over all steps and no
  element inverted at the end; or
- raises ElementInversionError whose message names the time, the elements and
  det F, with the body left finite and uninverted at the start of the failed
  step.

Any other exception (or a NaN) fails. Both integrators and the figures are in
docs/tongue_hard_cases.md. Durations on this machine (serial): see that page;
measured: level 1 89 s (100 steps of 6,699 nodes), the level-0 cases 2-9 s each
(plus about 35 s of form compilation per kappa value on a cold cache).

The level_1 run is the level-1 protrusion of test_tongue_convergence (same tongue,
schedule, dt and duration): both read the session fixture ``level1_protrusion``
(tests/conftest.py), so it is computed once per run.
"""

import re

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.models.tongue.hard_cases import CASES, build_case, run_built


@pytest.mark.slow
@pytest.mark.parametrize("name", list(CASES))
def test_hard_case_semi_implicit(name, request):
    if name == "level_1":                    # shared with test_tongue_convergence
        tongue, result = request.getfixturevalue("level1_protrusion")
    else:
        tongue, _, dt = build_case(name, "semi-implicit")
        result = run_built(tongue, dt)
    body = tongue.body
    # Never a silent NaN: whatever happened, the state left behind is finite.
    assert np.all(np.isfinite(body.u.x.array)), "non-finite displacement left in the body"
    assert np.all(np.isfinite(body.v.x.array)), "non-finite velocity left in the body"
    landmarks = np.array(list(result["landmarks_mm"].values()))
    assert np.all(np.isfinite(landmarks))
    bad, det_now = body.inverted_elements()
    assert bad.size == 0 and det_now > 0, f"inverted elements left in the body: {bad[:20]}"

    if result["outcome"] == "finished":
        assert result["steps_done"] == result["steps"]
        assert result["t_reached"] == pytest.approx(1.0)
        assert 0 < result["min_det_F"] < np.inf
        assert np.abs(landmarks).max() > 0.1, "the muscles did not move the tongue"
    else:
        assert result["outcome"] == "inversion error", (
            f"{name}: stopped with something other than ElementInversionError: "
            f"{result.get('error')}")
        inv = result["inversion"]
        message = inv["message"]
        assert re.search(r"t = [-+0-9.e]+ s", message), message
        assert re.search(r"det F = [-+0-9.e]+ <= 0", message), message
        assert re.search(r"\d+ element\(s\) \[\d+", message), message
        assert inv["elements"] >= 1 and inv["min_det_F"] <= 0
        assert inv["time"] > result["t_reached"] - 1e-12
