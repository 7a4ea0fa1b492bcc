"""The styloglossus as external point-to-point muscles on the level-0 tongue (models.styloglossus).

Short runs (0.3 s of the 0.5 s ramp) with 4 and with 24 support nodes: the scene runs, the
attachment points move toward their styloid points (posterior: +x, superior: +z, and
laterally toward their side) and the muscles pull.

The paper's claim that 24 support nodes lower the peak stress near the attachment is NOT
reproduced by this scene (measured, full 1 s run: 12.5 kPa with 4 nodes at 1.51 N tension,
20.0 kPa with 24 nodes at 2.25 N; 0.3 s: 4.17 vs 5.61 kPa): the 4-node attachment lets the
point sink further into the soft tissue, the muscle shortens more and its Thelen force drops,
and the min-norm 24-node weights are partly negative. Kept as a strict xfail until resolved.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.models.tongue.model import load_tongue_data
from artifem.models.styloglossus import STYLOID, simulate

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial scene")


@pytest.fixture(scope="module")
def results():
    data = load_tongue_data(0)
    return {k: simulate(k, duration=0.3, data=data) for k in (4, 24)}


@pytest.mark.parametrize("k", [4, 24])
def test_runs_and_moves_toward_the_styloid_points(results, k):
    r = results[k]
    assert r["min_det_F"] > 0.2
    for side, styloid in STYLOID.items():
        d = np.array(r["attachment_displacement_m"][side])
        p = np.array(r["attachment_points"][side])
        assert d[0] > 1e-3 and d[2] > 1e-3                 # posterior and superior
        assert np.sign(d[1]) == np.sign(styloid[1])        # toward its own side
        assert d @ (styloid - p) > 0.5 * np.linalg.norm(d) * np.linalg.norm(styloid - p)
        assert r["tension_N"][side] > 0.3
    # left/right symmetric
    assert abs(r["tension_N"]["left"] - r["tension_N"]["right"]) < 1e-2 * r["tension_N"]["left"]


@pytest.mark.xfail(strict=True, reason="not reproduced yet: see the module docstring")
def test_24_support_nodes_lower_the_peak_stress(results):
    p4 = max(results[4]["peak_von_mises_near_attachment_Pa"].values())
    p24 = max(results[24]["peak_von_mises_near_attachment_Pa"].values())
    assert p24 < p4
