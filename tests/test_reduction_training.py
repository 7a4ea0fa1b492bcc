"""The training pipeline of reduced models (artifem.reduction.training), end to end on a beam.

(a) ArtifactCache: keys are stable for equal inputs (dict order, numpy arrays)
    and differ for different ones; save/load round trip; get() computes once and
    then loads; a compute (or a save) that fails leaves no artifact and no
    temporary file, and the next get() computes again (resume semantics).
(b) Training forces on a muscle-driven hex beam (snapshots recorded in a Scene
    driven by an ExcitationSchedule ramp, plus tip-load and gravity runs; mass-
    weighted POD): b of force_training_matrix is U^T R_int at every training
    state -- checked against the all-points ReducedFemBody and, at training
    states, against the full body's assembled residual with the loads off;
    trained_points(G, b, tol=1e-3) meets its tolerance with fewer points, and a
    ReducedFemBody on those points reproduces the stacked training forces to it.
(c) An exactly representable physical case: a basis moving one free corner node
    touches only the 9 integration points of its one element, so b = G w* with
    w* = 1 on those points; the greedy fit finds exactly them, weights 1.
(d) Accuracy against the full model (muscle ramp, semi-implicit, 30 steps): the
    max over time of the mean nodal error decreases strictly with the POD size r
    (all points) and, at r = 4, does not increase with the number of trained
    points m (see the test for the one justified slack).
(e) An undamped reduced model with trained weights never gains energy over 300
    semi-implicit steps, from an initial displacement or an initial velocity.

Serial (ReducedFemBody is serial). About 5 s.
"""

import pickle
import warnings

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.excitation import ExcitationSchedule
from artifem.fem_body import FemBody
from artifem.forms import BlemkerFiber, NeoHookean
from artifem.reduction.bases import body_mass, pod_basis
from artifem.reduction.cubature import trained_points, trained_points_path
from artifem.reduction.quadrature_points import quadrature_points
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from artifem.reduction.training import (
    ArtifactCache,
    Snapshots,
    force_training_matrix,
    project,
    record_snapshots,
)
from artifem.scene import Scene

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="ReducedFemBody is serial")


# ---- (a) ArtifactCache ----------------------------------------------------------------------


def test_cache_key_is_stable_for_equal_inputs_and_differs_for_different_ones():
    key = ArtifactCache.key
    a = key("snapshots", model={"E": 1e5, "nu": 0.3, "fixed": np.arange(4)}, dt=0.01, every=5)
    # Same inputs, keyword and dict order swapped, the array rebuilt, numpy scalars.
    b = key(
        "snapshots",
        every=np.int64(5),
        dt=np.float64(0.01),
        model={"fixed": np.array([0, 1, 2, 3]), "nu": 0.3, "E": 1e5},
    )
    assert a == b
    assert a == key(
        "snapshots", model={"E": 1e5, "nu": 0.3, "fixed": np.arange(4)}, dt=0.01, every=5
    )  # deterministic
    assert a.startswith("snapshots-") and "/" not in a and " " not in a
    different = [
        key("basis", model={"E": 1e5, "nu": 0.3, "fixed": np.arange(4)}, dt=0.01, every=5),
        key("snapshots", model={"E": 2e5, "nu": 0.3, "fixed": np.arange(4)}, dt=0.01, every=5),
        key(
            "snapshots",
            model={"E": 1e5, "nu": 0.3, "fixed": np.array([0, 1, 2, 4])},
            dt=0.01,
            every=5,
        ),
        key("snapshots", model={"E": 1e5, "nu": 0.3, "fixed": np.arange(4)}, dt=0.02, every=5),
        key("snapshots", model={"E": 1e5, "nu": 0.3, "fixed": np.arange(4)}, dt=0.01),
        key(
            "snapshots",
            model={"E": 1e5, "nu": 0.3, "fixed": np.arange(4).reshape(2, 2)},
            dt=0.01,
            every=5,
        ),
    ]
    assert len({a, *different}) == 1 + len(different)


def test_cache_key_accepts_numpy_bool_scalars():
    assert ArtifactCache.key("k", flag=np.bool_(True)) == ArtifactCache.key("k", flag=True)


def test_cache_save_load_round_trip(tmp_path):
    cache = ArtifactCache(tmp_path / "nested" / "cache")  # created on demand
    key = cache.key("basis", r=3)
    assert cache.load(key) is None
    arrays = {
        "U": np.random.default_rng(0).standard_normal((6, 3)),
        "index": np.arange(5, dtype=np.int64),
        "residual": np.array(1.5e-3),
    }
    cache.save(key, arrays)
    assert cache.path(key) == tmp_path / "nested" / "cache" / f"{key}.npz"
    loaded = cache.load(key)
    assert set(loaded) == set(arrays)
    for name, value in arrays.items():
        assert loaded[name].dtype == value.dtype and loaded[name].shape == value.shape
        np.testing.assert_array_equal(loaded[name], value)
    assert float(loaded["residual"]) == 1.5e-3
    # A second cache on the same directory sees it (what a resumed run does).
    np.testing.assert_array_equal(ArtifactCache(cache.root).load(key)["U"], arrays["U"])
    assert not list(cache.root.glob("*.tmp"))


def test_cache_get_computes_once_then_loads(tmp_path):
    cache = ArtifactCache(tmp_path)
    calls = []

    def compute():
        calls.append(1)
        return {"x": [1.0, 2.0, 3.0], "n": 7}  # lists and scalars become arrays

    key = cache.key("thing", a=1)
    first = cache.get(key, compute)
    second = cache.get(key, compute)
    third = ArtifactCache(tmp_path).get(key, compute)
    assert len(calls) == 1
    for found in (first, second, third):
        np.testing.assert_array_equal(found["x"], [1.0, 2.0, 3.0])
        assert int(found["n"]) == 7
    # Another key is another artifact.
    cache.get(cache.key("thing", a=2), compute)
    assert len(calls) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [f"{cache.key('thing', a=1)}.npz", f"{cache.key('thing', a=2)}.npz"]
    )


def test_cache_failed_compute_leaves_nothing_and_is_computed_again(tmp_path):
    cache = ArtifactCache(tmp_path)
    key = cache.key("snapshots", exciter="GGP")
    calls = []

    def interrupted():
        calls.append("interrupted")
        raise KeyboardInterrupt  # a killed run, mid-computation

    def failing():
        calls.append("failing")
        raise RuntimeError("solver diverged")

    with pytest.raises(KeyboardInterrupt):
        cache.get(key, interrupted)
    with pytest.raises(RuntimeError, match="diverged"):
        cache.get(key, failing)
    assert list(tmp_path.iterdir()) == []  # no artifact, no *.tmp
    assert cache.load(key) is None
    found = cache.get(key, lambda: calls.append("ok") or {"u": np.ones(3)})
    assert calls == ["interrupted", "failing", "ok"]
    np.testing.assert_array_equal(found["u"], np.ones(3))
    assert cache.get(key, lambda: pytest.fail("recomputed a cached artifact"))["u"].size == 3


#: what pickling a lambda raises (np.savez pickles an object array)
UNPICKLABLE = (pickle.PicklingError, AttributeError)


def test_cache_failed_save_leaves_no_temporary_file(tmp_path):
    cache = ArtifactCache(tmp_path)
    key = cache.key("points", m=3)
    with pytest.raises(UNPICKLABLE):
        cache.save(key, {"fine": np.ones(2), "unpicklable": lambda: None})
    assert list(tmp_path.iterdir()) == []
    # A get() whose result cannot be written: nothing on disk, computed again next time.
    calls = []

    def compute():
        calls.append(1)
        return {"bad": lambda: None}

    for _ in range(2):
        with pytest.raises(UNPICKLABLE):
            cache.get(key, compute)
    assert len(calls) == 2 and list(tmp_path.iterdir()) == []


# ---- the beam ---------------------------------------------------------------------------------

TIP_LOAD = (0.0, 2.0, 0.0)  # N per tip node
GRAVITY = (0.0, 0.0, -9.81)


def make_body(rayleigh=(2.0, 0.01)):
    """A 4x2x2 hex beam (1 x 0.3 x 0.2 m) clamped at x = 0, a muscle in its top half
    (BlemkerFiber, excitation 0), an incompressibility penalty and a tip load. The loads
    (tip load, gravity) act only with load_factor 1; tests set it and body.gravity."""
    msh = dmesh.create_box(
        MPI.COMM_WORLD,
        [np.zeros(3), np.array([1.0, 0.3, 0.2])],
        [4, 2, 2],
        dmesh.CellType.hexahedron,
    )
    body = FemBody(
        msh,
        NeoHookean.from_young_poisson(1.0e5, 0.3),
        1000.0,
        rayleigh=rayleigh,
        gravity=(0.0, 0.0, 0.0),
        incompressibility=2.0e5,
    )
    x = msh.geometry.x
    inputs = np.asarray(msh.geometry.input_global_indices, dtype=np.int64)
    body.fix_nodes(inputs[x[:, 0] < 1e-12])
    body.add_nodal_load(inputs[np.abs(x[:, 0] - 1.0) < 1e-12], TIP_LOAD)
    n = msh.topology.index_map(3).size_local
    centroids = x[msh.geometry.dofmaps[0][:n]].mean(axis=1)
    cells = np.asarray(msh.topology.original_cell_index[:n])[centroids[:, 2] > 0.1]
    rng = np.random.default_rng(1)
    directions = np.array([1.0, 0.0, 0.0]) + 0.3 * rng.standard_normal((cells.size, 3))
    body.add_muscle("top", cells, directions, BlemkerFiber(2.0e4), excitation=0.0)
    body.compile()
    return body


def ndofs(body):
    return 3 * body.V.dofmap.index_map.size_local


def reset(body, excitation=0.0, load_factor=0.0, gravity=(0.0, 0.0, 0.0)):
    body.u.x.array[:] = 0.0
    body.v.x.array[:] = 0.0
    body.set_excitation("top", excitation)
    body.load_factor.value = load_factor
    body.gravity.value[:] = gravity


#: Training runs: (muscle ramp target or None, load factor, gravity).
TRAINING = [
    (1.0, 0.0, (0.0, 0.0, 0.0)),  # the muscle alone, ramped to 1 over 0.2 s
    (None, 1.0, (0.0, 0.0, 0.0)),  # the tip load alone
    (None, 1.0, GRAVITY),  # tip load and gravity
    (0.5, 1.0, GRAVITY),
]  # all three


def record_training(body) -> Snapshots:
    parts = []
    for target, load_factor, gravity in TRAINING:
        reset(body, load_factor=load_factor, gravity=gravity)
        # The run's gravity: Scene.add sets the body's gravity to the scene's.
        scene = Scene(gravity=gravity, linear_solver="mumps")
        scene.add(body)
        if target is not None:
            scene.add_controller(
                ExcitationSchedule.ramp_and_hold({"top": target}, 0.2).controller(body)
            )
        parts.append(record_snapshots(scene, body, duration=0.4, dt=0.01, every=2, progress=False))
    reset(body)
    return Snapshots.concatenate(parts)


def training_forces(body, U, q, excitations):
    """force_training_matrix, insisting that no training state is left out."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return force_training_matrix(body, U, q, excitations, progress=False)


@pytest.fixture(scope="module")
def beam():
    body = make_body()
    snapshots = record_training(body)
    return body, snapshots, body_mass(body)


def test_training_snapshots_cover_the_variants(beam):
    body, snapshots, mass = beam
    u, a = snapshots.displacements, snapshots.excitations
    assert u.shape == (4 * 20, ndofs(body)) and a.shape == (80, 1)
    # The excitation of each snapshot is the schedule's at its time (ramp every 2 steps of 0.01 s).
    np.testing.assert_allclose(a[:20, 0], np.minimum(0.02 * np.arange(1, 21) / 0.2, 1.0))
    np.testing.assert_array_equal(a[20:60, 0], 0.0)
    np.testing.assert_allclose(a[60:, 0], np.minimum(0.05 * np.arange(1, 21), 0.5))
    assert np.all(np.isfinite(u))
    tip = u.reshape(80, -1, 3)
    assert np.abs(tip[:20, :, 2]).max() > 0.05  # the muscle bends the beam
    assert np.abs(tip[20:40, :, 1]).max() > 1e-3  # the tip load pushes it sideways
    assert tip[40:60, :, 2].min() < -1e-2  # gravity pulls it down
    assert np.all(u[:, (3 * body.fixed_dofs[:, None] + np.arange(3)).ravel()] == 0.0)


def full_internal_residual(body, u, excitation):
    """The full body's internal residual R_int(u): the assembled R with every load off."""
    saved_factor = float(body.load_factor.value)
    saved_excitation = float(body.muscles["top"].excitation.value)
    body.load_factor.value = 0.0
    body.set_excitation("top", excitation)
    n = ndofs(body)
    body.u.x.array[:n] = u
    body.u.x.scatter_forward()
    body.assemble(tangent=False)
    R = body.R.array[:n].copy()
    body.u.x.array[:] = 0.0
    body.load_factor.value = saved_factor
    body.set_excitation("top", saved_excitation)
    return R


def test_the_point_table_names_an_inverted_element():
    """An element whose corner node is pushed past its opposite corner (det J < 0 at the
    points near it, a few 1e-4 m^3: far from -1) is refused by quadrature_points, by its
    input index."""
    from artifem.errors import InputError

    body = make_body()
    x = body.mesh.geometry.x
    corner = np.flatnonzero(np.all(np.abs(x - [1.0, 0.3, 0.2]) < 1e-12, axis=1))
    (cell,) = np.flatnonzero(np.isin(body.mesh.geometry.dofmaps[0], corner).any(axis=1))
    x[corner] = [0.7, 0.1, 0.05]  # past the element's corner (0.75, 0.15, 0.1)
    (index,) = body.input_cell_index([cell])
    with pytest.raises(InputError, match=rf"det J <= 0 in input elements \[{index}\]$"):
        quadrature_points(body)


def test_training_forces_are_the_reduced_internal_forces_and_trained_points_fit_them(beam):
    body, snapshots, mass = beam
    reset(body)
    U, _ = pod_basis(snapshots.displacements, mass, r=6)
    q = project(U, mass, snapshots.displacements)
    S, r = q.shape
    assert r == 6
    body.set_excitation("top", 0.37)
    G, b = training_forces(body, U, q, snapshots.excitations)
    assert float(body.muscles["top"].excitation.value) == 0.37  # restored
    n_points = quadrature_points(body).size
    assert n_points == 9 * 16 and G.shape == (S * r, n_points) and b.shape == (S * r,)
    np.testing.assert_allclose(b, G.sum(axis=1), rtol=1e-14, atol=0)

    # b = the all-points reduced internal residual at (q_s, a_s), every training state.
    everything = ReducedFemBody(body, U, all_points(body))
    stacked = []
    for qs, a in zip(q, snapshots.excitations):
        body.set_excitation("top", a[0])
        everything.set_q(qs)
        stacked.append(everything.internal_residual())
    stacked = np.concatenate(stacked)
    scale = np.abs(b).max()
    assert scale > 0
    np.testing.assert_allclose(stacked, b, rtol=0, atol=1e-12 * scale)

    # ... = U^T R_int(U q_s) of the full body assembled with gravity and loads off, at
    # training states of every run (muscle ramp, tip load, gravity, all three).
    for s in (5, 19, 30, 59, 79):
        R = full_internal_residual(body, U @ q[s], snapshots.excitations[s, 0])
        ref = U.T @ R
        assert np.abs(ref).max() > 1e-3 * scale
        np.testing.assert_allclose(b[s * r : (s + 1) * r], ref, rtol=0, atol=1e-11 * scale)

    # Trained points: the fit meets tol with a fraction of the points ...
    tol = 1e-3
    points = trained_points(G, b, tol=tol)
    assert points.method == "trained" and points.residual <= tol
    assert 6 <= points.m < n_points // 2  # measured: 47 of 144
    fit = G[:, points.indices] @ points.weights
    assert np.linalg.norm(fit - b) <= tol * np.linalg.norm(b)
    assert np.linalg.norm(fit - b) / np.linalg.norm(b) == pytest.approx(points.residual, rel=1e-9)
    # ... and a reduced body on those points reproduces the stacked training forces.
    reduced = ReducedFemBody(body, U, points)
    forces = []
    for qs, a in zip(q, snapshots.excitations):
        body.set_excitation("top", a[0])
        reduced.set_q(qs)
        forces.append(reduced.internal_residual())
    forces = np.concatenate(forces)
    np.testing.assert_allclose(forces, fit, rtol=0, atol=1e-12 * scale)
    assert np.linalg.norm(forces - b) <= tol * np.linalg.norm(b) * (1 + 1e-9)
    reset(body)


def test_one_element_basis_is_recovered_exactly(beam):
    """U moves only the free corner node (1, 0.3, 0.2), which belongs to one element: only
    that element's 9 points (8 Gauss + the penalty's centre point) have nonzero columns,
    and b = G w* with w* = 1 on them. Nonlinear states make the 9 columns independent
    (measured condition number 1.8e3 on the 56 states kept), so the fit is unique: the
    greedy finds those 9 points with weights 1."""
    body, snapshots, mass = beam
    reset(body)
    n = ndofs(body)
    X = body.V.tabulate_dof_coordinates()[: n // 3]
    corner = int(np.argmin(np.linalg.norm(X - [1.0, 0.3, 0.2], axis=1)))
    assert np.allclose(X[corner], [1.0, 0.3, 0.2])
    U = np.zeros((n, 3))
    U[3 * corner + np.arange(3), np.arange(3)] = 1.0 / np.sqrt(mass[3 * corner + np.arange(3)])
    q = project(U, mass, snapshots.displacements)
    np.testing.assert_allclose(
        U @ q[7],
        np.where(np.repeat(np.arange(n // 3) == corner, 3), snapshots.displacements[7], 0.0),
    )
    # A whole-beam displacement at one node alone crushes its element: keep the states
    # whose projection inverts nothing (checked at every point).
    everything = ReducedFemBody(body, U, all_points(body))
    keep = []
    for s, qs in enumerate(q):
        everything.set_q(qs)
        if everything.det_F().min() > 0.2:
            keep.append(s)
    assert len(keep) >= 40
    q, a = q[keep], snapshots.excitations[keep]
    assert a.max() > 0.5  # muscle states among them
    G, b = training_forces(body, U, q, a)
    table = quadrature_points(body)
    element = np.flatnonzero(np.any(table.dofs == corner, axis=1))
    assert element.size == 9 and np.unique(table.cell[element]).size == 1
    assert np.array_equal(np.flatnonzero(np.linalg.norm(G, axis=0)), element)
    np.testing.assert_allclose(G[:, element] @ np.ones(9), b, rtol=0, atol=1e-14 * np.abs(b).max())
    points = trained_points(G, b, tol=1e-10)
    np.testing.assert_array_equal(points.indices, element)
    np.testing.assert_allclose(points.weights, 1.0, rtol=1e-8)
    assert points.residual <= 1e-10
    reset(body)


# ---- (d) accuracy against the full model ------------------------------------------------------

TEST_MOTION = ExcitationSchedule.ramp_and_hold({"top": 0.8}, 0.15)  # not a training run
DT, STEPS = 0.01, 30


def full_run(body):
    reset(body)
    scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")  # as reset() left it
    scene.add(body)
    scene.add_controller(TEST_MOTION.controller(body))
    n = ndofs(body)
    u = [np.zeros(n)]
    for _ in range(STEPS):
        scene.step(DT)
        u.append(body.u.x.array[:n].copy())
    reset(body)
    return np.array(u)


def reduced_run(body, U, points):
    reset(body)
    reduced = ReducedFemBody(body, U, points)
    scene = Scene(gravity=(0.0, 0.0, 0.0))  # as reset() left it
    scene.add(reduced)
    scene.add_controller(TEST_MOTION.controller(body))
    u = [reduced.nodal_displacement()]
    for _ in range(STEPS):
        scene.step(DT)
        u.append(reduced.nodal_displacement())
    reset(body)
    assert scene.halvings == 0
    return np.array(u)


def max_mean_error(u, u_ref):
    """Max over time of the mean over nodes of |u - u_ref| (m)."""
    return float(np.linalg.norm((u - u_ref).reshape(u.shape[0], -1, 3), axis=2).mean(axis=1).max())


def test_error_decreases_with_the_basis_size_and_the_number_of_trained_points(beam):
    body, snapshots, mass = beam
    u_full = full_run(body)
    assert np.abs(u_full).max() > 0.05  # 12.7 cm tip motion
    scale = np.linalg.norm(u_full.reshape(STEPS + 1, -1, 3), axis=2).mean(axis=1).max()

    # r = 1, 2, 4 with every point (measured: 0.052, 0.016, 0.0059 m).
    by_r = [
        max_mean_error(
            reduced_run(body, pod_basis(snapshots.displacements, mass, r=r)[0], all_points(body)),
            u_full,
        )
        for r in (1, 2, 4)
    ]
    assert by_r[0] > by_r[1] > by_r[2] > 0, by_r
    # r = 4: 12.7 % of the largest mean displacement (0.0468 m); measured (two runs, same
    # digits): within 1.25 x
    assert by_r[2] < 1.25 * 0.005925241570750098, (by_r, scale)

    # r = 4 with m = 5, 20 trained points and all 144 (measured: 0.01874, 0.00781, 0.00782 m).
    U, _ = pod_basis(snapshots.displacements, mass, r=4)
    q = project(U, mass, snapshots.displacements)
    G, b = training_forces(body, U, q, snapshots.excitations)
    path = trained_points_path(G, b, sizes=[5, 20], tol=1e-6)
    assert path[5].m == 5 and path[20].m == 20
    assert path[5].residual > path[20].residual
    runs = [
        reduced_run(body, U, path[5]),
        reduced_run(body, U, path[20]),
        reduced_run(body, U, all_points(body)),
    ]
    by_m = [max_mean_error(u, u_full) for u in runs]
    # Against the full model the error is the basis error plus the cubature error, and the
    # two can partly cancel: 20 trained points end 0.2% *closer* to the full model than the
    # exact quadrature of the same basis. Hence a 5% slack on the last comparison only.
    assert by_m[0] > by_m[1], by_m
    assert by_m[2] <= 1.05 * by_m[1], by_m
    assert by_m[2] == pytest.approx(by_r[2], rel=1e-12)  # the same run as r = 4 above
    # The cubature error alone (against the all-points reduced run) decreases strictly.
    cubature = [max_mean_error(u, runs[2]) for u in runs[:2]]
    assert cubature[0] > cubature[1] > 0, cubature
    # Measured: 0.0153 and 0.0012 m; 20 points: small next to the basis error.
    assert cubature[1] < 0.3 * by_m[2]


# ---- (e) energy -----------------------------------------------------------------------------


@pytest.mark.parametrize("start", ["displacement", "velocity"])
def test_undamped_trained_reduced_model_never_gains_energy(beam, start):
    """Rayleigh (0, 0), no loads, a constant excitation, 300 semi-implicit steps of 2 ms.
    The linearized backward Euler step dissipates; measured, the total energy falls at
    every step, by at least 7e-4 of max |E| (the bound asserted is round-off, 1e-12)."""
    _, snapshots, _ = beam
    body = make_body(rayleigh=(0.0, 0.0))
    mass = body_mass(body)
    U, _ = pod_basis(snapshots.displacements, mass, r=6)
    q = project(U, mass, snapshots.displacements)
    G, b = training_forces(body, U, q, snapshots.excitations)
    points = trained_points(G, b, tol=1e-3)
    reduced = ReducedFemBody(body, U, points)
    assert reduced.alpha == reduced.beta == 0.0
    if start == "displacement":
        # Released from the most bent muscle state with the muscle off.
        reset(body, excitation=0.0)
        reduced.set_state((q[19], np.zeros(6)))
    else:
        # Thrown from rest with the muscle held at 0.3.
        reset(body, excitation=0.3)
        reduced.set_state((np.zeros(6), 20.0 * q[5]))
    scene = Scene(gravity=(0.0, 0.0, 0.0))  # no loads
    scene.add(reduced)
    energy = [(scene.energy(), scene.kinetic_energy(), scene.potential_energy())]
    for _ in range(300):
        scene.step(0.002)
        energy.append((scene.energy(), scene.kinetic_energy(), scene.potential_energy()))
    assert scene.halvings == 0
    assert float(body.muscles["top"].excitation.value) == (0.0 if start == "displacement" else 0.3)
    total, kinetic, potential = np.array(energy).T
    assert np.all(np.isfinite(total))
    swing = potential.max() - potential.min()
    assert kinetic.max() > 0.2 * swing > 0  # it vibrates
    assert np.sum(np.diff(np.sign(np.diff(kinetic))) != 0) >= 4  # several kinetic peaks
    change = np.diff(total)
    assert change.max() <= 1e-12 * np.abs(total).max(), f"energy grew by {change.max():.3e}"
    assert total[-1] < total[0]
    reset(body)


def test_project_is_u_transpose_m_and_refuses_rows_of_another_shape():
    """q_s = U^T M u_s for each row, the lumped diagonal and a callable M x alike; rows
    of the wrong width, a single vector or a stack of matrices are refused by name."""
    from artifem.errors import InputError

    rng = np.random.default_rng(3)
    U, m = rng.normal(size=(12, 3)), rng.uniform(1.0, 2.0, size=12)
    rows = rng.normal(size=(4, 12))
    expected = np.array([U.T @ (m * u) for u in rows])
    np.testing.assert_allclose(project(U, m, rows), expected, rtol=1e-13)
    np.testing.assert_allclose(project(U, lambda x: m * x, rows), expected, rtol=1e-13)
    for bad in (rows[:, :11], rows[0], rows[None]):
        with pytest.raises(InputError, match=r"displacements must be rows \(n_snapshots"):
            project(U, m, bad)
