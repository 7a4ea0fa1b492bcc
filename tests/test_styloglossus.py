"""The styloglossus as external point-to-point muscles on the level-0 tongue (models/styloglossus).

Short runs (0.3 s of the 0.5 s ramp): the Thelen muscles at equal excitation on 4 and on 24
support nodes, and a prescribed tension (1.5 N e(t): 0.9 N at 0.3 s) on 4 nodes, 24 nodes
with minimum-norm (signed) weights and 24 nodes with non-negative weights; a reduced tongue
trained on short full runs.

Measured (0.3 s; the 1 s figures are in the module docstring and docs/styloglossus.md):
peak von Mises near the attachment at equal tension 0.9 N: 5.42 kPa (4 nodes), 4.15 kPa (24,
min-norm), 8.04 kPa (24, w >= 0). At equal excitation: 4.14 kPa at 0.73 N (4 nodes) and
4.71 kPa at 1.03 N (24): not a comparison at equal load. The runs are deterministic (the
same to the last digit in either order, and with OpenBLAS's Haswell and Sandybridge
kernels since a muscle at rest no longer takes the slope of its curves' kinks from the
round-off's sign: artifem.multibody.muscles.REST_VELOCITY): MEASURED holds their figures,
compared to 1e-6.

The paper's claim (24 nodes lower the peak) holds at equal tension with the signed min-norm
weights (passing test) and fails with non-negative weights (strict xfail): the attachment
point is the centroid of a surface facet, on the boundary of the convex hull of its nearest
nodes, and the only non-negative weights that reproduce a point on a face of the hull sit on
that face: 97% of the weight is on the facet's own 4 nodes, so the force is not spread.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.models.tongue.model import load_tongue_data
from artifem.errors import InputError
from artifem.models.styloglossus.model import (
    RAMP,
    STYLOID,
    SUPPORTS,
    TENSION,
    ReducedConfig,
    attachment_points,
    boundary_facet_centroids,
    reducible,
)
from artifem.models.styloglossus.study import reduce_tongue, simulate

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial scene")

DURATION = 0.3
RUNS = ["excitation 4", "excitation 24", "tension 4", "tension 24", "tension 24+"]
#: Each run's figures at 0.3 s, measured (module docstring): min det F, the Thelen
#: tension at equal excitation (the prescribed one is 1.5 N e(t) = 0.9 N), the peak von
#: Mises stress near each attachment and the attachment's displacement (m: posterior +x,
#: toward its own side in y, superior +z).
MEASURED = {
    "excitation 4": {
        "min_det_F": 0.60117096898,
        "tension_N": {"left": 0.73365657994, "right": 0.73365202911},
        "peak_Pa": {"left": 4141.0948071, "right": 4141.1745416},
        "displacement_m": {
            "left": [0.0090695548744, 0.0025529781469, 0.0046462712652],
            "right": [0.0090696598516, -0.0025529412343, 0.0046463323307],
        },
    },
    "excitation 24": {
        "min_det_F": 0.83141148117,
        "tension_N": {"left": 1.0302446798, "right": 1.0302487994},
        "peak_Pa": {"left": 4715.2012033, "right": 4715.2942646},
        "displacement_m": {
            "left": [0.0063747747198, 0.0011029522648, 0.0021246904313],
            "right": [0.006374829823, -0.0011028817729, 0.0021246576835],
        },
    },
    "tension 4": {
        "min_det_F": 0.54126683409,
        "peak_Pa": {"left": 5419.9134583, "right": 5420.0517772},
        "displacement_m": {
            "left": [0.010525127859, 0.0032716243593, 0.0055669506303],
            "right": [0.010525292129, -0.0032716195379, 0.0055670406804],
        },
    },
    "tension 24": {
        "min_det_F": 0.84429938258,
        "peak_Pa": {"left": 4146.9362013, "right": 4146.990977},
        "displacement_m": {
            "left": [0.005860188373, 0.00096322185542, 0.0019073773201],
            "right": [0.0058602285121, -0.00096314336911, 0.0019073411342],
        },
    },
    "tension 24+": {
        "min_det_F": 0.74657861841,
        "peak_Pa": {"left": 8040.0280468, "right": 8040.3174694},
        "displacement_m": {
            "left": [0.0072137022394, 0.0018998798074, 0.0029946740384],
            "right": [0.0072136896059, -0.0018997969903, 0.0029946599611],
        },
    },
}


@pytest.fixture(scope="module")
def data():
    return load_tongue_data(0)


@pytest.fixture(scope="module")
def results(data):
    runs = {f"excitation {k}": simulate(k, duration=DURATION, data=data) for k in (4, 24)}
    for name, (k, nonneg) in SUPPORTS.items():
        runs[f"tension {name}"] = simulate(
            k, nonnegative=nonneg, load="tension", duration=DURATION, data=data
        )
    return runs


def peak(r):
    return max(r["peak_von_mises_near_attachment_Pa"].values())


@pytest.mark.parametrize("run", RUNS)
def test_runs_and_moves_toward_the_styloid_points(results, run):
    """Each attachment moves toward its styloid point (within 60 degrees of the line to it),
    by MEASURED's displacement (to 1e-6 of its length), with MEASURED's min det F and
    tension (the prescribed 0.9 N to round-off)."""
    r, measured = results[run], MEASURED[run]
    assert r["min_det_F"] == pytest.approx(measured["min_det_F"], rel=1e-6)
    for side, styloid in STYLOID.items():
        d = np.array(r["attachment_displacement_m"][side])
        p = np.array(r["attachment_points"][side])
        expected = measured["displacement_m"][side]  # posterior and superior
        np.testing.assert_allclose(d, expected, rtol=0, atol=1e-6 * np.linalg.norm(expected))
        assert np.sign(d[1]) == np.sign(styloid[1])  # toward its own side
        assert d @ (styloid - p) > 0.5 * np.linalg.norm(d) * np.linalg.norm(styloid - p)
        if run.startswith("tension"):  # T = 1.5 N e(t), the ramp e(t) = t / 0.5 s
            assert r["tension_N"][side] == pytest.approx(TENSION * DURATION / RAMP, rel=1e-12)
        else:
            assert r["tension_N"][side] == pytest.approx(measured["tension_N"][side], rel=1e-6)
    # left/right symmetric
    assert abs(r["tension_N"]["left"] - r["tension_N"]["right"]) < 1e-2 * r["tension_N"]["left"]


@pytest.mark.parametrize("run", RUNS)
def test_the_peak_stress_near_each_attachment_is_the_measured_one(results, run):
    """The peak von Mises stress within 12 mm of each attachment (module docstring), to 1e-6."""
    for side, peak_Pa in MEASURED[run]["peak_Pa"].items():
        assert results[run]["peak_von_mises_near_attachment_Pa"][side] == pytest.approx(
            peak_Pa, rel=1e-6
        ), side


def test_equal_excitation_is_not_equal_tension(results):
    """The 4-node point sinks further, the Thelen fiber shortens and its force drops."""
    t4, t24 = (results[f"excitation {k}"]["tension_N"]["left"] for k in (4, 24))
    assert t4 < 0.8 * t24


def test_equal_tension_24_min_norm_nodes_lower_the_peak_stress(results):
    r4, r24 = results["tension 4"], results["tension 24"]
    assert r4["tension_N"]["left"] == pytest.approx(r24["tension_N"]["left"], rel=1e-12)
    assert peak(r24) < 0.95 * peak(r4)
    assert r24["min_det_F"] > r4["min_det_F"] + 0.2
    d4, d24 = (np.linalg.norm(r["attachment_displacement_m"]["left"]) for r in (r4, r24))
    assert d24 < 0.6 * d4


def test_nonnegative_weights_of_a_surface_point_stay_on_its_facet(results):
    r = results["tension 24+"]
    body = r["_body"]
    cents, facet_dofs = boundary_facet_centroids(body, body.fixed_dofs)
    for side, p in attachment_points(body).items():
        w = np.array(r["weights"][side])
        assert w.min() >= 0.0 and min(results["tension 24"]["weights"][side]) < -0.05
        facet = facet_dofs[np.argmin(np.linalg.norm(cents - p, axis=1))]
        assert w[np.isin(r["_support_dofs"][side], facet)].sum() > 0.9


@pytest.mark.xfail(
    strict=True,
    reason="24 non-negative weights of a surface point sit on its "
    "facet: the peak doubles (module docstring)",
)
def test_equal_tension_24_nonnegative_nodes_lower_the_peak_stress(results):
    assert peak(results["tension 24+"]) < peak(results["tension 4"])


def test_reduced_tongue_follows_the_full_attachment(data, results, tmp_path_factory):
    """A small reduced tongue (the reductor: POD of short one-sided training runs, the path
    excitations its load inputs; ECSW points) pulled on 24 min-norm nodes by both sides at
    once: the paths went onto the reduced body, the attachment displacement is close to the
    full one, the stress is reconstructed."""
    rc = ReducedConfig(r=10, points=80, force_snapshots=30, snapshot_every=3)
    model = reduce_tongue(
        "24", tmp_path_factory.mktemp("styloglossus_cache"), rc, data=data, duration=DURATION
    )
    assert model.training["runs"] == 2 and model.r == 10
    red = simulate(24, load="tension", reduced=model, duration=DURATION, data=data)
    full = results["tension 24"]
    assert red["tension_N"]["left"] == pytest.approx(full["tension_N"]["left"], rel=1e-12)
    d_full = np.array(full["attachment_displacement_m"]["left"])
    d_red = np.array(red["attachment_displacement_m"]["left"])
    # measured: the attachment 7.1 % of its 6.2 mm displacement off, the peak stress 4.3 %
    # above the full model's; 1.5 times each allowed (the trained points may differ on
    # another machine's round-off)
    assert np.linalg.norm(d_red - d_full) < 1.5 * 0.071 * np.linalg.norm(d_full)
    assert peak(red) == pytest.approx(peak(full), rel=1.5 * 0.043)


def test_an_unknown_support_is_refused():
    with pytest.raises(InputError, match="unknown support '12'"):
        reducible("12")


def test_simulate_styloglossus_is_the_studys_run(tmp_path):
    """``artifem simulate styloglossus`` (the runner) at the prescribed tension runs the
    study's scene: the same tension, attachment motion and peak stress near it."""
    import json

    from artifem.cli import main

    args = ["--load", "tension", "--duration", "0.05", "--no-progress", "--no-vtx"]
    assert (
        main(["simulate", "styloglossus", "--case", "24-nodes", "--out", str(tmp_path), *args]) == 0
    )
    f = json.loads((tmp_path / "24-nodes" / "simulate.json").read_text())
    r = simulate(24, load="tension", duration=0.05)
    assert f["steps"] == r["steps"] == 5
    for side in STYLOID:
        assert f["tension_N"][side] == pytest.approx(r["tension_N"][side], rel=1e-9)
        moved = 1e3 * np.array(r["attachment_displacement_m"][side])
        assert f["attachment_displacement_mm"][side] == pytest.approx(moved, rel=1e-9)
        near = r["peak_von_mises_near_attachment_Pa"][side]
        assert f["peak_von_mises_near_attachment_Pa"][side] == pytest.approx(near, rel=1e-9)
    assert f["tension_N"]["left"] == pytest.approx(1.5 * 0.05 / 0.5)  # T = 1.5 N e(t)
