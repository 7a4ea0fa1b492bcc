"""The tongue's hard cases on a *reduced* tongue: finish cleanly or stop with a clear
inversion error, never NaN.

Each case of models/tongue/hard_cases.py is built with ``build_case`` (its tongue,
schedule and dt), and a ReducedFemBody of the case's own tongue body runs it in a
Scene (no gravity, as the tongue's own scene) with the case's schedule controller
(``tongue.bundle_schedule(schedule).controller(tongue.body)``), semi-implicit, for
the case's full duration (1.0 s: a reduced step costs about 1 ms, so nothing is
shortened). A run passes when either

- it finishes (the scene's health check holds det F > 0 at the integration points and
  a finite q, q' at every step) with its landmarks at t = 1 s no further from the full
  tongue's, the case's semi-implicit run in docs/tongue_hard_cases.json, than 1.25 times
  the measured distance (MEASURED_ERROR_MM); or
- it raises ElementInversionError and leaves a finite, uninverted state (the start
  of the failed step).

Measured: every configuration finishes without halving; the smallest min det F is
0.029 (all_exciters, trained points). These small bases are far from the full tongue:
its landmarks move 5.4 to 24.8 mm, and the reduced ones end 3.0 to 14.5 mm from them (a
basis of each exciter alone at 0.6 for 0.2 s does not span 1 s of the hard cases); the
test keeps that from getting worse. det F is checked, as the reduced body does, only at
its m integration points: with random points, all_exciters and level_1 end with inverted
elements in the full mesh at u = U q (det F -0.96 and -1.83), some of them integration
cells inverted at a Gauss point that is not sampled.

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
from hard_case_checks import committed_run

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="ReducedFemBody is serial")

TRAINING = {"excitation": 0.6, "ramp": 0.1, "duration": 0.2, "dt": 0.02, "every": 2}
POD_R = 10
LINEAR_MODES = 6
POINTS = 200
#: The trained points' relative residual (``trained_points``) per tongue body, measured
#: (25 % above it allowed, ERROR_MARGIN): the kappa cases fit their own bulk modulus.
MEASURED_RESIDUAL = {"kappa_100C10": 5.178e-3, "kappa_1000C10": 2.356e-3}
DEFAULT_RESIDUAL = 1.0705e-2  # the other level-0 cases: the tongue's own kappa
#: max over the landmarks of |u_reduced - u_full| (mm) at t = 1 s, u_full the case's
#: semi-implicit run in docs/tongue_hard_cases.json, measured (two runs: the same to 1e-9
#: mm). As tests/test_tongue_study.py, 25 % above it is allowed: the trained points'
#: greedy choice may turn on round-off on another machine.
MEASURED_ERROR_MM = {
    ("all_exciters", "trained"): 14.451,
    ("all_exciters", "random"): 6.977,
    ("step", "trained"): 7.853,
    ("step", "random"): 4.701,
    ("dt_0.05", "trained"): 7.783,
    ("dt_0.05", "random"): 4.640,
    ("kappa_100C10", "trained"): 5.873,
    ("kappa_100C10", "random"): 4.518,
    ("kappa_1000C10", "trained"): 3.018,
    ("kappa_1000C10", "random"): 3.018,
    ("level_1", "random"): 13.072,
}
ERROR_MARGIN = 1.25

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
    assert set(MEASURED_ERROR_MM) == {(name, sampling) for name, _, sampling in CONFIGS}


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


def reduced_tongue(name: str, tongue, basis: str, sampling: str, snapshots: Snapshots | None):
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
        measured = MEASURED_RESIDUAL.get(name, DEFAULT_RESIDUAL)
        assert points.m == POINTS and points.residual <= ERROR_MARGIN * measured, points.residual
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
    reduced = reduced_tongue(name, tongue, basis, sampling, snapshots)
    body = tongue.body
    scene = Scene(gravity=(0.0, 0.0, 0.0), integrator=tongue.config.integrator)
    scene.add(reduced)
    scene.add_controller(tongue.bundle_schedule(schedule).controller(body))

    steps = int(round(DURATION / dt))
    error = None
    for _ in range(steps):
        try:
            scene.step(dt)
        except ElementInversionError as exc:
            error = exc
            break

    if error is None:
        assert scene.t == pytest.approx(DURATION)
        expected = tongue.bundle_schedule(schedule).at(scene.t)
        for bundle, value in expected.items():
            assert float(body.muscles[bundle].excitation.value) == pytest.approx(value)
        # The controller drove the reduced body as the full one: its landmarks against the
        # full tongue's run of the case.
        full = committed_run(name, tongue, dt)["landmarks_mm"]
        reduced.to_full()
        mine = 1e3 * body.displacement_at(list(tongue.data.landmarks.values()))
        error_mm = max(
            np.linalg.norm(mine[k] - full[landmark])
            for k, landmark in enumerate(tongue.data.landmarks)
        )
        assert error_mm <= ERROR_MARGIN * MEASURED_ERROR_MM[name, sampling], error_mm
    else:
        # The state left behind is the start of the failed step: finite and uninverted.
        q, qdot = reduced.state()
        assert np.all(np.isfinite(q)) and np.all(np.isfinite(qdot))
        bad, det_now = reduced.inverted_elements()
        assert bad.size == 0 and det_now > 0, f"inverted elements left: {bad[:20]}"
        assert error.min_det <= 0 or error.elements.size >= 1, str(error)
        assert "element inversion at t =" in str(error)
        assert scene.t < DURATION and error.time > scene.t
