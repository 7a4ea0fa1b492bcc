"""The default linear solver (CG + smoothed-aggregation AMG, lagged) on the physics,
against MUMPS, within the tolerance LinearSolver states (rtol 1e-7 on the residual keeps
the tongue's displacement within 3e-8 relative after 30 semi-implicit steps).

Users get the iterative default; the physics tests mostly force MUMPS for round-off
agreement. Here the same runs are made with both: an FEM body on its own (the
tongue, with both integrators) and FEM bodies carried by a hinged bone through the
distributed (Schur) island (tests/test_scene_schur.py: 7e-9 relative with CG + AMG).
Reduced and rigid bodies solve densely: they have no solver choice. Measured on the
level-0 tongue (protrusion): 7e-10 relative after 30 semi-implicit steps, 3e-11 after
10 implicit ones.
"""

import numpy as np
import pytest

import artifem as af  # noqa: F401  (must precede dolfinx / petsc4py)

from artifem.linear_solver import DEFAULT_METHOD
from artifem.models.tongue.model import Tongue, TongueConfig


@pytest.fixture(scope="module")
def tongue_data():
    from artifem.models.tongue.model import load_tongue_data
    return load_tongue_data(0)


@pytest.mark.parametrize("integrator, steps", [("semi-implicit", 30), ("implicit", 10)])
def test_tongue_default_solver_agrees_with_mumps(tongue_data, integrator, steps):
    runs = {}
    for solver in (DEFAULT_METHOD, "mumps"):
        tongue = Tongue(TongueConfig(level=0, integrator=integrator, linear_solver=solver),
                        data=tongue_data)
        tongue.drive(Tongue.motion("protrusion"))
        for _ in range(steps):
            tongue.scene.step(0.01)
        runs[solver] = tongue.body.u.x.array.copy()
    u = runs["mumps"]
    assert np.abs(u).max() > 1e-4                       # the tongue moved
    assert np.abs(runs[DEFAULT_METHOD] - u).max() < 3e-7 * np.abs(u).max()
