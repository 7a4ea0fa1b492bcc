"""The Galerkin-gap diagnosis (artifem.reduction.galerkin_gap) on the small muscle beam.

(1) The held instants of a ramp-and-hold schedule: from the end of the ramp plus the hold.
(2) A complete basis with every point: every reduced solution is the full state it is
    compared with (the best approximation, the energy projection, the static equilibrium
    against the full one, the oracle: at round-off); the static reduced equilibrium
    against the swinging run is the full run's own distance to equilibrium.
(3) A 3-vector POD basis under a weak excitation, at the full equilibrium: the static
    reduced equilibrium is the energy-norm projection, and the oracle Petrov-Galerkin
    solve the best approximation, up to second order in the error (asserted 5 %).
(4) The residual's parts: each is its terms' residual, the rest the external load.
(5) ``ReducedFemBody(leave_out=...)``: a penalty body with its penalty left out is the
    reduced body of the same body built without it; an unknown term is refused.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

from artifem.errors import InputError
from artifem.excitation import ExcitationSchedule
from artifem.reduction.cubature import IntegrationPoints
from artifem.reduction.galerkin_gap import (
    PARTS,
    _FullBody,
    galerkin_gap,
    held_instant,
    write_markdown,
)
from artifem.reduction.quadrature_points import quadrature_points
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from artifem.reduction.reductor import (
    Basis,
    Points,
    ReducedModel,
    ReducibleScene,
    Reductor,
    Training,
)
from artifem.reduction.schedules import random_schedules
from artifem.reduction.training import ArtifactCache
from artifem.scene import Scene
from reduced_beam import full_basis, make_body

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="reduced bodies are serial")

DT = 0.01


def beam() -> Scene:
    """The beam driven by its muscle alone (no gravity, no load)."""
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(make_body(excitation=0.0, loads=False))
    return scene


MODEL = ReducibleScene("beam", beam, "fem", {"model": "gap-beam"})


def test_held_instants_start_a_hold_after_the_ramp():
    schedule = ExcitationSchedule.ramp_and_hold({"top": 0.5}, 0.1)
    times = np.arange(31) * DT
    held = held_instant(schedule, times, hold=0.05)
    assert np.array_equal(np.flatnonzero(held), np.arange(15, 31))
    # held, then released at 0.3 s: held before the release whatever comes after it, not
    # while the release is inside the last 0.05 s, held again once it is older
    release = ExcitationSchedule(
        np.array([0.0, 0.1, 0.3, 0.31]), {"top": np.array([0.0, 0.5, 0.5, 0.0])}
    )
    held = held_instant(release, np.arange(41) * DT, hold=0.05)
    assert held[[16, 20, 29]].all() and not held[[32, 33, 34]].any() and held[[37, 40]].all()


def test_a_run_without_a_held_instant_is_a_row_of_empty_cells():
    header, rule, row = write_markdown([{"run": "pulses", "held": False}]).splitlines()[-3:]
    assert row.startswith("| pulses | no held instant |")
    assert row.count("|") == header.count("|") == rule.count("|")


def test_a_complete_basis_has_no_gap(tmp_path):
    body = beam().fem_bodies[0]
    complete = ReducedModel(MODEL, full_basis(body), [], all_points(body))
    schedule = ExcitationSchedule.ramp_and_hold({"top": 0.4}, 0.1)
    (row,) = galerkin_gap(
        complete, {"ramp": schedule}, 0.3, DT, ArtifactCache(tmp_path), progress=False
    )
    assert "learned_pg_mm" not in row  # no training states given
    assert row["held"] and row["time"] >= 0.2
    for key in (
        "reduced_mm",
        "best_mm",
        "energy_mm",
        "best_static_mm",
        "galerkin_static_mm",
        "energy_static_mm",
        "oracle_pg_mm",
    ):
        assert row[key] < 1e-6, key
    # the beam still swings under gravity at t: its static equilibrium is elsewhere
    assert row["full_lag_mm"] > 1.0
    assert row["static_mm"] == pytest.approx(row["full_lag_mm"], rel=1e-6)


def test_static_solve_is_the_energy_projection_and_the_oracle_the_best(tmp_path):
    training = Training(
        random_schedules(["top"], 2, seed=1, duration=0.2, active=(1, 1), excitation=(0.0, 0.1)),
        duration=0.2,
        dt=DT,
        snapshot_every=1,
    )
    reductor = Reductor(MODEL, training, tmp_path / "cache", progress=False)
    reduced = reductor.reduce(Basis("pod", 3), Points(sampling="all"))
    schedule = ExcitationSchedule.ramp_and_hold({"top": 0.05}, 0.1)
    (row,) = galerkin_gap(
        reduced,
        {"weak": schedule},
        0.3,
        DT,
        ArtifactCache(tmp_path / "cache"),
        training=reductor.snapshots()[0],
        learned_sizes=(4,),
        progress=False,
    )
    assert row["galerkin_static_mm"] == pytest.approx(row["energy_static_mm"], rel=0.05)
    assert row["oracle_pg_mm"] == pytest.approx(row["best_static_mm"], rel=0.05)
    # nearly linear: the oracle's test basis at the training states is the one here
    assert row["learned_pg_mm"]["4"] == pytest.approx(row["best_static_mm"], rel=0.05)
    assert row["best_static_mm"] < row["galerkin_static_mm"]
    share = row["residual_share"]
    assert set(share) == set(PARTS)
    assert share["other"] < 1e-12  # no load but dead ones, equal at q* and u*
    # measured at 0.952 / 0.003 / 0.047 (passive / active / volumetric): under a weak
    # excitation the passive material drives the gap; 0.01 absolute allows the solvers'
    # round-off through the training
    assert share["passive"] == pytest.approx(0.952, abs=0.01)
    assert share["volumetric"] == pytest.approx(0.047, abs=0.01)
    assert row["correction_mm"]["passive"] == pytest.approx(0.80, rel=0.05)  # measured 0.7995
    assert "| weak | " in write_markdown([row]) and "p = 4" in write_markdown([row])


def test_the_residual_parts_are_their_terms_and_the_rest_is_the_external_load():
    """The split of R(u) (galerkin_gap's residual shares): the volumetric part is the
    residual of the body with its penalty less that of the body without it, and "other"
    is minus the gravity load, assembled here on its own."""
    body = make_body(excitation=0.3, loads=False)
    without = make_body(excitation=0.3, loads=False, incompressibility=None)
    n = 3 * body.V.dofmap.index_map.size_local
    full, plain = _FullBody(body, n), _FullBody(without, n)
    u = np.random.default_rng(0).standard_normal(n) * 1e-3
    u[full.fixed] = 0.0
    parts = full.parts(u)
    scale = np.linalg.norm(full.residual(u))
    np.testing.assert_allclose(
        parts["volumetric"], full.residual(u) - plain.residual(u), rtol=0, atol=1e-12 * scale
    )
    v = ufl.TestFunction(body.V)
    g = fem_petsc.assemble_vector(fem.form(1000.0 * ufl.dot(body.gravity, v) * ufl.dx))
    g.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    load = g.array[:n].copy()
    load[full.fixed] = 0.0
    assert np.linalg.norm(load) > 0.1 * scale
    np.testing.assert_allclose(parts["other"], -load, rtol=0, atol=1e-12 * scale)


def test_leaving_out_the_penalty_is_the_body_without_it():
    with_penalty, without = (
        make_body(excitation=0.3),
        make_body(excitation=0.3, incompressibility=None),
    )
    U = full_basis(with_penalty)[:, ::7]
    table = quadrature_points(with_penalty)  # every point but the penalty's own
    kept = np.concatenate(
        [
            table.of_term(t)
            for t in with_penalty.energy_terms(merged=True)
            if t.name != "incompressibility"
        ]
    )
    points = IntegrationPoints(np.unique(kept), np.ones(np.unique(kept).size), "all")
    left_out = ReducedFemBody(with_penalty, U, points, leave_out=["incompressibility"])
    plain = ReducedFemBody(without, U, all_points(without))
    q = np.random.default_rng(0).standard_normal(U.shape[1]) * 1e-3
    for b in (left_out, plain):
        b.set_q(q)
    np.testing.assert_allclose(left_out.force(), plain.force(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(left_out.tangent(), plain.tangent(), rtol=1e-12, atol=1e-9)
    with pytest.raises(InputError, match="not energy terms"):
        ReducedFemBody(with_penalty, U, points, leave_out=["penalty"])
