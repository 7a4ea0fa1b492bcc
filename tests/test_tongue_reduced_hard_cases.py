"""The tongue's hard cases on a *reduced* tongue: finish cleanly or stop with a clear
inversion error, never NaN.

Each case of models/tongue/hard_cases.py is built with ``build_case`` (its tongue,
schedule and dt), and a ReducedFemBody of the case's own tongue body runs it in a
Scene (no gravity, as the tongue's own scene) with the case's schedule controller
(``tongue.bundle_schedule(schedule).controller(tongue.body)``), semi-implicit, for
the case's full duration (1.0 s: a reduced step costs about 1 ms, so nothing is
shortened). A run passes when every completed step leaves finite q, q' and either

- it finishes with min det F > 0 at the integration points over all steps; or
- it raises ElementInversionError and leaves a finite, uninverted state (the start
  of the failed step).

Measured: every configuration finishes without halving; the smallest min det F is
0.027 (all_exciters, trained points). det F is checked, as the reduced body does,
only at its m integration points: with random points, all_exciters and level_1 end
with inverted elements in the full mesh at u = U q (det F -0.96 and -1.83), some of
them integration cells inverted at a Gauss point that is not sampled.

Reduced models:

- level 0 (all_exciters, step, dt_0.05, kappa_100C10, kappa_1000C10): a mass-weighted
  POD basis (r = 10) of training snapshots of the level-0 tongue, each of its eleven
  exciters alone ramped to 0.6 over 0.1 s (the study's training, shortened: 0.2 s at
  dt = 0.02 s, a snapshot every 2 steps; about 18 s, cached once per module in a tmp
  directory through ArtifactCache), with 200 integration points either trained (ECSW
  fitted to the case body's *own* forces at the training states, so the kappa cases
  are fitted with their own bulk modulus) or random (uniform per quadrature rule).
  The kappa cases reuse the penalty tongue's snapshots: same mesh, fixed nodes and
  muscles; only the bulk modulus differs.
- level_1: training snapshots would need full level-1 steps (about 0.7 s each), too
  slow here; it runs the study's other basis instead, extended linear modes (6 modes x
  9 maps = 54 vectors, no full run needed), with 200 random points.

Serial. About a minute on this machine (mostly the training runs).
"""

from dataclasses import asdict

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.excitation import ExcitationSchedule
from artifem.errors import ElementInversionError
from artifem.models.tongue.hard_cases import CASES, PENALTY_CONFIG, build_case
from artifem.models.tongue.model import DURATION, Tongue, TongueConfig
from artifem.reduction.bases import body_mass, extended_modes, linear_modes, pod_basis
from artifem.reduction.cubature import random_points, trained_points
from artifem.reduction.quadrature_points import quadrature_points
from artifem.reduction.reduced_body import ReducedFemBody
from artifem.reduction.training import (
    ArtifactCache,
    Snapshots,
    force_training_matrix,
    project,
    record_snapshots,
)
from artifem.scene import Scene

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="ReducedFemBody is serial")

TRAINING = {"excitation": 0.6, "ramp": 0.1, "duration": 0.2, "dt": 0.02, "every": 2}
POD_R = 10
LINEAR_MODES = 6
POINTS = 200

#: The cases with the element penalty (the ``incompressible_*`` cases need a reduced
#: pressure space trained on hard runs: tests/test_reduced_incompressibility.py).
PENALTY_CASES = [name for name in CASES if not name.startswith("incompressible_")]
LEVEL_0 = [name for name in PENALTY_CASES if CASES[name].config.get("level", 0) == 0]
CONFIGS = [(name, "pod", sampling) for name in LEVEL_0 for sampling in ("trained", "random")] + [
    ("level_1", "extended-modal", "random")
]


def test_every_hard_case_is_covered():
    assert set(LEVEL_0) | {"level_1"} == set(PENALTY_CASES)
    assert {name for name, _, _ in CONFIGS} == set(PENALTY_CASES)


@pytest.fixture(scope="module")
def training(tmp_path_factory) -> Snapshots:
    """Snapshots of the level-0 tongue of the cases (the element penalty), one cached run
    per exciter."""
    cache = ArtifactCache(tmp_path_factory.mktemp("tongue_training"))
    tongue = Tongue(TongueConfig(**PENALTY_CONFIG))
    body = tongue.body
    parts, keys = [], []
    for exciter in tongue.exciters:
        key = cache.key("snapshots", model=asdict(tongue.config), exciter=exciter, **TRAINING)

        def run(exciter=exciter):
            tongue.reset()
            tongue.drive(
                ExcitationSchedule.ramp_and_hold(
                    {exciter: TRAINING["excitation"]}, TRAINING["ramp"]
                )
            )
            return record_snapshots(
                tongue.scene,
                body,
                duration=TRAINING["duration"],
                dt=TRAINING["dt"],
                every=TRAINING["every"],
                progress=False,
            ).as_arrays()

        data = cache.get(key, run)
        parts.append(Snapshots(data["displacements"], data["excitations"]))
        keys.append(key)
    # Cached: a second pass loads every run without stepping the tongue again.
    again = [cache.get(k, lambda: pytest.fail("training recomputed")) for k in keys]
    for part, data in zip(parts, again):
        np.testing.assert_array_equal(part.displacements, data["displacements"])
    snapshots = Snapshots.concatenate(parts)
    steps = round(TRAINING["duration"] / TRAINING["dt"])
    assert snapshots.displacements.shape == (
        len(tongue.exciters) * steps // TRAINING["every"],
        3 * body.V.dofmap.index_map.size_local,
    )
    assert np.all(np.isfinite(snapshots.displacements))
    assert np.abs(snapshots.displacements).max() > 5e-3  # the exciters move it (m)
    return snapshots


def reduced_tongue(tongue, basis: str, sampling: str, snapshots: Snapshots | None):
    body = tongue.body
    body.compile()
    mass = body_mass(body)
    if basis == "pod":
        U, _ = pod_basis(snapshots.displacements, mass, r=POD_R)
    else:
        modes, _ = linear_modes(body, LINEAR_MODES)
        U = extended_modes(modes, mass, fixed_dofs=body.fixed_dofs)
    table = quadrature_points(body)
    if sampling == "trained":
        q = project(U, mass, snapshots.displacements)
        G, b = force_training_matrix(body, U, q, snapshots.excitations, progress=False)
        points = trained_points(G, b, tol=1e-6, max_points=POINTS)
        assert points.m == POINTS and points.residual < 0.05  # measured: 2e-3 to 7e-3
    else:
        points = random_points(table.volume, POINTS, rng=0, groups=table.degree)
    tongue.reset()
    return ReducedFemBody(body, U, points, name=f"tongue_{basis}_{sampling}")


@pytest.mark.parametrize(
    "name, basis, sampling", CONFIGS, ids=[f"{n}-{b}-{s}" for n, b, s in CONFIGS]
)
def test_reduced_hard_case_finishes_or_stops_with_an_inversion_error(
    name, basis, sampling, request
):
    snapshots = request.getfixturevalue("training") if basis == "pod" else None
    tongue, schedule, dt = build_case(name, "semi-implicit")
    reduced = reduced_tongue(tongue, basis, sampling, snapshots)
    body = tongue.body
    scene = Scene(gravity=(0.0, 0.0, 0.0), integrator=tongue.config.integrator)
    scene.add(reduced)
    scene.add_controller(tongue.bundle_schedule(schedule).controller(body))

    steps = int(round(DURATION / dt))
    error, largest = None, 0.0
    for _ in range(steps):
        try:
            scene.step(dt)
        except ElementInversionError as exc:
            error = exc
            break
        q, qdot = reduced.state()
        assert np.all(np.isfinite(q)) and np.all(np.isfinite(qdot)), (
            f"non-finite state at t = {scene.t:.3f} s"
        )
        largest = max(largest, float(np.abs(reduced.nodal_displacement()).max()))

    # Whatever happened, the state left behind is finite and uninverted.
    q, qdot = reduced.state()
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(qdot))
    assert np.all(np.isfinite(reduced.nodal_displacement()))
    bad, det_now = reduced.inverted_elements()
    assert bad.size == 0 and det_now > 0, f"inverted elements left: {bad[:20]}"
    if error is None:
        assert scene.t == pytest.approx(DURATION)
        assert 0 < scene.min_det_F < np.inf
        assert scene.min_det_F <= det_now
        # The controller drove the reduced body (measured: largest |u| 1.2 mm for
        # kappa_1000C10 with trained points, else 3.9 to 23 mm).
        assert largest > 5e-4
        expected = tongue.bundle_schedule(schedule).at(scene.t)
        for bundle, value in expected.items():
            assert float(body.muscles[bundle].excitation.value) == pytest.approx(value)
    else:
        assert error.min_det <= 0 or error.elements.size >= 1, str(error)
        assert "element inversion at t =" in str(error)
        assert scene.t < DURATION and error.time > scene.t
