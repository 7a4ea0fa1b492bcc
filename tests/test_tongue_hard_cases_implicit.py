"""The tongue's hard cases with the implicit integrator, and their agreement with the
semi-implicit runs (tests/test_tongue_hard_cases.py has the semi-implicit ones and the
contract; a file of its own so that the two pytest workers share the work).

The implicit integrator runs the level-0 cases only: its level-1 run takes about
4 minutes (249 s in docs/tongue_hard_cases.md: 100 Newton steps of 6,699 nodes); run it
with ``python -m artifem.models.tongue.hard_cases --cases level_1 --integrators implicit``.
"""

import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from hard_case_checks import (
    LEVEL0,
    assert_same_landmarks,
    check_outcome,
    check_protrusion_variants,
    make_runs,
)


@pytest.fixture(scope="module")
def runs(request):
    return make_runs(request)


@pytest.mark.slow
@pytest.mark.parametrize("name", LEVEL0)
def test_hard_case_implicit(name, runs):
    tongue, result = runs(name, "implicit")
    assert tongue.config.integrator == "implicit"
    check_outcome(name, tongue, result)


@pytest.mark.slow
@pytest.mark.parametrize("name", LEVEL0)
def test_both_integrators_end_on_the_same_state(name, runs):
    semi, implicit = runs(name, "semi-implicit")[1], runs(name, "implicit")[1]
    for r in (semi, implicit):  # documented: every case finishes, no halving
        assert (r["outcome"], r["halvings"]) == ("finished", 0), (name, r.get("error"))
    assert_same_landmarks(semi, implicit, name)


@pytest.mark.slow
@pytest.mark.parametrize("integrator", ["implicit"])
def test_protrusion_variants_end_on_the_same_state(integrator, runs):
    check_protrusion_variants(runs, integrator)
