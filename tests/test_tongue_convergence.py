"""Tongue levels 0 and 1 agree on protrusion within the measured discretization error.

models/tongue/convergence.py runs the three speech motions on both levels
(docs/tongue_convergence.md). For protrusion it measured, at t = 1.0 s
(semi-implicit, dt = 0.01 s; the hold phase has settled to equilibrium):

    tip, level 0: (-1.40, 0.00, 6.64) mm   |d0| = 6.78 mm
    tip, level 1: (-1.22, 0.00, 7.69) mm   |d1| = 7.79 mm
    |d0 - d1| = 1.07 mm, 14 % of |d1|

Here each level is solved for its static equilibrium under the protrusion's held
excitations (``Scene.solve_static``, which ramps the activation): the same tips to the
digits above, at about a fifth of the cost of the level-1 run (9 and 18 Newton
iterations). Each tip is held to its measured value (:data:`STATIC_TIP_MM`) to 1e-4 mm:
the solve stops at 1e-10 of the loads, and the default CG + AMG and MUMPS give tips
within 1e-8 mm of each other. What it guards against: level 1 drifting away from level 0
through the refinement (fiber directions, bundles or fixed nodes carried over wrongly,
landmarks mapped to other nodes), and either level's equilibrium moving (material,
fibers, activation, the static solve). The two tips' difference is then the measured
discretization error above, checked as documentation.

The level-1 dynamic run (the hard case ``level_1``, about 3 minutes on two busy cores)
is in ``python -m artifem.models.tongue.hard_cases --cases level_1``, not in the suite.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.models.tongue.model import MOTIONS, PENALTY, Tongue, TongueConfig

#: The static protrusion tip of each level (mm), measured (the same with CG + AMG and MUMPS
#: to 1e-8 mm).
STATIC_TIP_MM = {
    0: [-1.40004366, 2.14284e-5, 6.63548424],
    1: [-1.22457035, 1.72537e-5, 7.69111810],
}


def protrusion_tip_mm(level: int) -> np.ndarray:
    """The tip's displacement (mm) at the static equilibrium of the held protrusion."""
    tongue = Tongue(TongueConfig(level=level, incompressibility=PENALTY))
    tongue.set_excitations(MOTIONS["protrusion"])
    tongue.scene.solve_static()
    return tongue.body.displacement_at([tongue.data.landmarks["tip"]])[0] * 1e3


@pytest.mark.slow
def test_protrusion_tip_level0_agrees_with_level1():
    d0, d1 = protrusion_tip_mm(0), protrusion_tip_mm(1)
    np.testing.assert_allclose(d0, STATIC_TIP_MM[0], rtol=0, atol=1e-4)
    np.testing.assert_allclose(d1, STATIC_TIP_MM[1], rtol=0, atol=1e-4)
    # the discretization error of the module docstring: 1.07 mm, 14 % of |d1|
    diff = np.linalg.norm(d0 - d1)
    assert round(diff, 2) == 1.07 and round(diff / np.linalg.norm(d1), 2) == 0.14
