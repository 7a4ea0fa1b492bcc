"""The tongue's hard cases with the implicit integrator, and their agreement with the
semi-implicit runs (tests/test_tongue_hard_cases.py has the semi-implicit ones and the
contract; a file of its own so that the two pytest workers share the work).

The implicit integrator runs the level-0 cases that differ most from the semi-implicit
step's: the full excitation stepped at t = 0 (``step``: an indefinite tangent on the
first steps), the stiffest penalty (``kappa_1000C10``) and the large time step
(``dt_0.05``), each against its run in docs/tongue_hard_cases.json
(``hard_case_checks.check_outcome``). The others (``all_exciters``, ``kappa_100C10``:
40-60 s each with the implicit step on two busy cores) and level 1 (about 4 minutes) are
in the hard-case study, ``python -m artifem.models.tongue.hard_cases --integrators
implicit`` (its table in docs/tongue_hard_cases.md), to keep ``make test`` near 12 minutes.
"""

import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.models.tongue.model import DURATION
from hard_case_checks import (
    AGREE_HALF_MM,
    AGREE_MM,
    COMMITTED,
    assert_same_landmarks,
    check_outcome,
    check_protrusion_variants,
    committed_at,
    duration,
    make_runs,
)


#: the level-0 cases run with the implicit integrator (module docstring)
IMPLICIT = ["step", "kappa_1000C10", "dt_0.05"]


@pytest.fixture(scope="module")
def runs():
    return make_runs()


@pytest.mark.slow
@pytest.mark.parametrize("name", IMPLICIT)
def test_hard_case_implicit(name, runs):
    tongue, result = runs(name, "implicit")
    assert tongue.config.integrator == "implicit"
    check_outcome(name, tongue, result)


@pytest.mark.slow
@pytest.mark.parametrize("name", IMPLICIT)
def test_both_integrators_end_on_the_same_state(name, runs):
    """The implicit run ends where the semi-implicit one was at that time (AGREE_MM at
    t = 1 s, AGREE_HALF_MM at t = 0.5 s). The semi-implicit run is the committed one:
    tests/test_tongue_hard_cases.py re-runs it and holds it to that run's landmarks, rounded
    to 1e-4 mm, so running it here again adds nothing."""
    t = duration(name)
    semi = committed_at(COMMITTED[name, "semi-implicit"], t)
    implicit = runs(name, "implicit")[1]
    for r in (semi, implicit):  # documented: every case finishes, no halving
        assert (r["outcome"], r["halvings"]) == ("finished", 0), (name, r.get("error"))
    assert_same_landmarks(semi, implicit, name, AGREE_MM if t == DURATION else AGREE_HALF_MM)


@pytest.mark.slow
@pytest.mark.parametrize("integrator", ["implicit"])
def test_protrusion_variants_end_on_the_same_state(integrator, runs):
    check_protrusion_variants(runs, integrator)
