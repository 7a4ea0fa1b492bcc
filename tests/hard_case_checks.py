"""What the tongue hard-case tests check (tests/test_tongue_hard_cases*.py): the outcome
contract and the landmark agreement."""

import re

import numpy as np
import pytest

from artifem.models.tongue.hard_cases import CASES, build_case, run_built

#: The cases with the element penalty (the tongue's default).
PENALTY = [name for name in CASES if not name.startswith("incompressible_")]
#: Landmark agreement at t = 1 s (mm). With the Rayleigh damping D = 40 M + 0.03 K_0 (the
#: stiffness at rest, FemBody.rest_stiffness) the protrusion's softest mode still creeps
#: toward the static equilibrium at t = 1 s (about 3 s^-1: the step case's tip moves 0.02 mm
#: between t = 1 and 2 s). Two integrators at one dt differ there by O(h) (measured at most
#: 2.2e-3 mm), dt = 0.01 and 0.05 s by the creep's phase (measured 0.063 mm).
AGREE_MM, AGREE_DT_MM = 5e-3, 0.1


def make_runs():
    """runs(name, integrator) -> (tongue, run_built result), each run at most once per
    module."""
    done = {}

    def get(name, integrator):
        if (name, integrator) not in done:
            tongue, _, dt = build_case(name, integrator)
            done[name, integrator] = tongue, run_built(tongue, dt)
        return done[name, integrator]

    return get


def check_outcome(name, tongue, result):
    """A result or ElementInversionError naming time, elements and det F; never NaN."""
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
            f"{result.get('error')}"
        )
        inv = result["inversion"]
        message = inv["message"]
        assert re.search(r"t = [-+0-9.e]+ s", message), message
        assert re.search(r"det F = [-+0-9.e]+ <= 0", message), message
        assert re.search(r"\d+ element\(s\) \[\d+", message), message
        assert inv["elements"] >= 1 and inv["min_det_F"] <= 0
        assert inv["time"] > result["t_reached"] - 1e-12


def assert_same_landmarks(a, b, what, atol=AGREE_MM):
    for landmark in a["landmarks_mm"]:
        np.testing.assert_allclose(
            a["landmarks_mm"][landmark],
            b["landmarks_mm"][landmark],
            rtol=0,
            atol=atol,
            err_msg=f"{what}: {landmark}",
        )


def check_protrusion_variants(runs, integrator: str) -> None:
    """``step`` (no ramp) and ``dt_0.05`` (five times the step) end on the same landmarks, near
    the protrusion's static equilibrium (tip (-1.40, 6.64) mm in x, z: where the runs arrive
    at t = 2 s, to 2e-3 mm)."""
    step, coarse = runs("step", integrator)[1], runs("dt_0.05", integrator)[1]
    assert step["outcome"] == coarse["outcome"] == "finished"
    assert (step["dt"], coarse["dt"]) == (0.01, 0.05)
    assert coarse["steps"] == 20 and step["steps"] == 100
    assert_same_landmarks(step, coarse, f"step vs dt_0.05 ({integrator})", AGREE_DT_MM)
    assert step["landmarks_mm"]["tip"][0] == pytest.approx(-1.40, abs=0.05)
    assert step["landmarks_mm"]["tip"][2] == pytest.approx(6.64, abs=0.05)
