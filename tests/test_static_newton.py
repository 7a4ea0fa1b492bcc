"""The static Newton (integrators.solve_static) converges quadratically and picks its own
load steps: dead and follower loads, compressible and hard-incompressible bodies, and a
10:1 beam under a follower pressure solved with load_steps="auto" (docs/verification.md,
"Static Newton"; scripts/static_newton_counts.py measures the larger cases)."""

import numpy as np
import pytest
from mpi4py import MPI

import artifem as af
from dolfinx import mesh as dmesh

from artifem.incompressibility import Incompressible
from artifem.integrators import _extrapolation_weights, solve_static
from artifem.scene import Scene

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial checks")


def box(n, size):
    return dmesh.create_box(
        MPI.COMM_SELF,
        [np.zeros(3), np.array(size, dtype=float)],
        list(n),
        dmesh.CellType.hexahedron,
    )


def cantilever(hard: bool = False):
    """1 x 0.2 x 0.2 (tests/test_surface_loads.py's cantilever, coarser), clamped at x = 0."""
    E, nu = 1e5, 0.3
    body = af.FemBody(
        box((6, 2, 2), (1.0, 0.2, 0.2)),
        af.NeoHookean.from_young_poisson(E, nu),
        1000.0,
        incompressibility=Incompressible(kappa=10 * E / 2.6) if hard else None,
    )
    body.fix_nodes(body.find_nodes(lambda x: x[0] < 1e-12))
    return body


def top(x):
    return np.isclose(x[2], 0.2)


def assert_quadratic(residuals, counts):
    """Each increment's residuals fall to the tolerance with r_{k+1} / r_k^2 bounded once
    r_k is small (relative to the first residual of the increment)."""
    assert max(counts) <= 10, counts  # target 6: not yet on the hard or first increments
    for norms in residuals:
        r0 = norms[0]
        rel = [r / r0 for r in norms]
        close = [(a, b) for a, b in zip(rel, rel[1:]) if a < 1e-2 and b > 1e-12]
        for a, b in close:  # the absolute ratio, as test_surface_loads
            assert (b * r0) / (a * r0) ** 2 < 10.0, (norms, b * r0 / (a * r0) ** 2)


def assert_volume_held(body, reference):
    """The body's volume int J dX changed by no more than its worst element (a weighted mean
    of the elements' changes g_i / V_i), which the solve holds to the constraint's tol: by
    7.6e-9 and 3.1e-8 under the dead and follower loads alone, the first 1.3e-8 in a run of
    the whole suite (where the solve stops, within tol, turns on round-off: not a figure to pin)."""
    vc = body.volume_constraint
    vc.at_current_state()
    assert abs(body.volume() / reference - 1.0) <= vc.violation() * (1 + 1e-6) + 1e-14
    assert vc.violation() <= vc.spec.tol


@pytest.mark.parametrize("hard", [False, True], ids=["compressible", "hard"])
def test_quadratic_under_a_dead_traction(hard, direct_solver):
    """Hard: the solve stops once every element's volume change is within the constraint's
    tol (1e-6): assert_volume_held."""
    body = cantilever(hard)
    reference = body.volume()
    body.add_traction((0.0, 0.0, -200.0), where=top)
    counts = solve_static(body, direct_solver(body), load_steps=3)
    assert body.u.x.array.reshape(-1, 3)[:, 2].min() < -0.1
    assert_quadratic(counts.residuals, counts)
    if hard:
        assert_volume_held(body, reference)


@pytest.mark.parametrize("hard", [False, True], ids=["compressible", "hard"])
def test_quadratic_under_a_follower_pressure(hard, direct_solver):
    """Hard: assert_volume_held."""
    body = cantilever(hard)
    reference = body.volume()
    body.add_pressure(200.0, where=top)
    counts = solve_static(body, direct_solver(body), load_steps=3)
    assert body.u.x.array.reshape(-1, 3)[:, 2].min() < -0.1
    assert_quadratic(counts.residuals, counts)
    if hard:
        assert_volume_held(body, reference)


def long_beam():
    """10 x 1 x 1 neo-Hookean (E = 10, nu = 0.3), clamped at x = 0, follower pressure 0.004
    on its bottom face (docs/verification.md's 10:1 beam)."""
    body = af.FemBody(
        box((20, 2, 2), (10.0, 1.0, 1.0)), af.NeoHookean.from_young_poisson(10.0, 0.3), 1.0
    )
    body.fix_nodes(body.find_nodes(lambda x: x[0] < 1e-12))
    body.add_pressure(0.004, where=lambda x: np.isclose(x[2], 0.0))
    return body


def test_the_long_beam_takes_at_most_six_iterations_per_load_step(direct_solver):
    """Five load steps of the 10:1 beam, each in at most 6 Newton iterations with none cut:
    the first step's linear solution fails every line search test (theta = 11) and is
    taken under the watchdog (backtracking it: 8 iterations); the later increments start
    from the quadratic predictor (4 iterations; the secant: 5)."""
    body = long_beam()
    counts = solve_static(body, direct_solver(body), load_steps=5)
    assert counts.failed == 0 and len(counts) == 5, counts
    assert max(counts) <= 6 and max(counts[2:]) <= 4, list(counts)


def test_the_predictor_extrapolates_a_quadratic_exactly():
    nodes, x = [0.1, 0.25, 0.5], 0.8
    w = _extrapolation_weights(nodes, x)
    for poly in ([1.0], [2.0, -3.0], [0.5, 1.0, -4.0]):
        assert abs(w @ np.polyval(poly, nodes) - np.polyval(poly, x)) < 1e-12
    assert abs(w @ np.power(nodes, 3) - x**3) > 1e-3  # not a cubic


def test_the_long_beam_is_solved_by_adaptive_load_steps():
    """The 10:1 neo-Hookean beam (E = 10) under a follower pressure 0.004 on its bottom
    face: load_steps="auto" chooses the increments (a failed one is cut) and solves the
    full load; a fixed count still works, and its increments are cut where they fail. The
    beam bends far up (large rotation): its highest node rises 5.0147820 (measured; pinned
    to rel 1e-8, the two runs agree to 2e-11 of it), and both runs reach the same
    equilibrium (measured to 1.2e-10; the bound is 1e-9)."""
    body = long_beam()
    scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
    scene.add(body)
    counts = scene.solve_static(load_steps="auto")
    assert body.load_factor.value == 1.0
    tip = body.u.x.array.reshape(-1, 3)[:, 2].max()
    assert tip == pytest.approx(5.0147820424, rel=1e-8)
    assert max(counts) <= 10 and len(counts) <= 20, counts
    fixed = long_beam()
    scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
    scene.add(fixed)
    scene.solve_static(load_steps=1)  # one step: cut until it converges
    assert np.abs(fixed.u.x.array - body.u.x.array).max() < 1e-9


def _compressed_cube(s: float):
    """The unit cube (3 x 3 x 3 hexahedra, neo-Hookean mu = lambda = 1e3) between symmetry
    planes x = y = z = 0, its face x = 1 prescribed to x = s: homogeneous, F = diag(s, l, l)
    with the lateral faces free, mu (l^2 - 1) + lambda ln(s l^2) = 0 (P_yy = 0)."""
    body = af.FemBody(box((3, 3, 3), (1.0, 1.0, 1.0)), af.NeoHookean(1e3, 1e3), 1000.0)
    for k in range(3):
        body.fix_nodes(body.find_nodes(lambda x, k=k: np.isclose(x[k], 0.0)), components=(k,))
    body.fix_nodes(
        body.find_nodes(lambda x: np.isclose(x[0], 1.0)),
        components=(0,),
        displacement=lambda x: np.vstack([(s - 1) * x[0], 0 * x[1], 0 * x[2]]),
    )
    return body


def test_a_prescribed_compression_deeper_than_an_element_reaches_the_closed_form():
    """Half the cube's length prescribed at once would put its face layer inside out (the
    face moves 0.5 past elements 1/3 thick): the static solve's first Newton iterate is the
    linear predictor of the prescribed step (the free nodes follow it), and the cube reaches
    the closed form in one increment; a second prescription from that equilibrium too."""
    from scipy.optimize import brentq

    body = _compressed_cube(0.5)
    scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
    scene.add(body)
    X = body.V.tabulate_dof_coordinates()
    for s in (0.5, 0.4):
        if s == 0.4:
            body.fix_nodes(
                body.find_nodes(lambda x: np.isclose(x[0], 1.0)),
                components=(0,),
                displacement=lambda x: np.vstack([(s - 1) * x[0], 0 * x[1], 0 * x[2]]),
            )
        counts = scene.solve_static(load_steps=1)
        assert counts.failed == 0 and max(counts) <= 6
        lateral = brentq(lambda l, s=s: 1e3 * (l**2 - 1) + 1e3 * np.log(s * l**2), 1.0, 3.0)
        expected = X * (np.array([s, lateral, lateral]) - 1)
        assert np.abs(body.u.x.array.reshape(-1, 3) - expected).max() < 1e-9


def test_the_load_steps_ramp_the_prescribed_displacement():
    """Each of four load increments ends with the prescribed face at its share of the way,
    before + k/4 (after - before), from the equilibrium the prescription was written on."""
    from artifem.linear_solver import LinearSolver

    body = _compressed_cube(0.8)
    solve_static(body, LinearSolver(MPI.COMM_SELF, "mumps"))
    face = body.local_dofs(body.find_nodes(lambda x: np.isclose(x[0], 1.0)))
    before = body.u.x.array.reshape(-1, 3)[face, 0].copy()
    body.fix_nodes(
        body.find_nodes(lambda x: np.isclose(x[0], 1.0)),
        components=(0,),
        displacement=lambda x: np.vstack([-0.5 * x[0], 0 * x[1], 0 * x[2]]),
    )
    after = body.u.x.array.reshape(-1, 3)[face, 0].copy()
    seen = []

    class Progress:
        def update(self, n):
            seen.append(body.u.x.array.reshape(-1, 3)[face, 0].copy())

    counts = solve_static(
        body, LinearSolver(MPI.COMM_SELF, "mumps"), load_steps=4, progress=Progress()
    )
    assert counts.factors == [0.25, 0.5, 0.75, 1.0]
    for k, values in enumerate(seen, start=1):
        np.testing.assert_allclose(values, before + k / 4 * (after - before), rtol=0, atol=1e-15)


def test_a_failed_static_solve_keeps_its_prescription_for_the_next():
    """A static solve that fails (one Newton iteration allowed, no cut) leaves the
    prescribed displacement written and the rest of the state where it was; the next solve
    ramps it from there and converges."""
    from artifem import integrators

    body = _compressed_cube(0.5)
    scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
    scene.add(body)
    start = body.u.x.array.copy()
    saved = integrators.MAX_CUTS
    integrators.MAX_CUTS = 0
    try:
        with pytest.raises(af.StepFailed):
            scene.solve_static(load_steps=1, max_iterations=1)
    finally:
        integrators.MAX_CUTS = saved
    np.testing.assert_array_equal(body.u.x.array, start)
    scene.solve_static(load_steps=1)
    assert body.u.x.array.reshape(-1, 3)[:, 0].min() == pytest.approx(-0.5, abs=1e-12)
    assert np.abs(body.u.x.array.reshape(-1, 3)[:, 1]).max() > 0.1  # it bulged


def test_the_coupled_island_ramps_a_prescribed_compression_as_the_body_alone():
    """The cube clamped at x = 0 and its face x = 1 pushed to x = 0.5 (deeper than an
    element, so that it must be ramped) solved on its own and in a coupled island (a plane
    contact far below puts it there): the same equilibrium."""

    def clamped(island: bool):
        body = af.FemBody(box((3, 3, 3), (1.0, 1.0, 1.0)), af.NeoHookean(1e3, 1e3), 1000.0)
        body.fix_nodes(body.find_nodes(lambda x: np.isclose(x[0], 0.0)))
        body.fix_nodes(
            body.find_nodes(lambda x: np.isclose(x[0], 1.0)),
            displacement=lambda x: np.vstack([-0.5 * x[0], 0 * x[1], 0 * x[2]]),
        )
        scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
        scene.add(body)
        if island:
            scene.add(af.PlaneContact(body, (0.0, 0.0, -1.0), (0.0, 0.0, 1.0)))
        scene.solve_static(load_steps="auto")
        return body.u.x.array.copy()

    alone, coupled = clamped(False), clamped(True)
    assert np.abs(alone).max() > 0.45
    np.testing.assert_allclose(coupled, alone, rtol=0, atol=1e-9)


@pytest.mark.parametrize("island", [False, True], ids=["alone", "coupled island"])
def test_the_load_steps_ramp_the_muscle_excitations(island):
    """A muscle's activation is a load of the static solve: the first of two increments of a
    beam excited to 1 ends at the equilibrium of the excitation 0.5 (it was the full one,
    so that a cut increment retried the same problem: the level-0 tongue's protrusion
    failed under ``load_steps="auto"`` at a load factor of 2e-4)."""

    def beam():
        body = af.FemBody(box((6, 2, 2), (1.0, 0.2, 0.2)), af.MooneyRivlin.tongue(), 1040.0)
        body.fix_nodes(body.find_nodes(lambda x: np.isclose(x[0], 0.0)))
        top_cells = body.find_cells(lambda x: x[2] > 0.1)
        body.add_muscle("top", top_cells, (1.0, 0.0, 0.0), af.BlemkerFiber(max_stress=1e4))
        scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
        scene.add(body)
        if island:  # a plane contact far below puts the body in a coupled island
            scene.add(af.PlaneContact(body, (0.0, 0.0, -1.0), (0.0, 0.0, 1.0)))
        return scene, body

    scene, body = beam()
    body.set_excitation("top", 0.5)
    scene.solve_static()
    half = body.u.x.array.copy()
    assert np.abs(half).max() > 0.01  # the top fibers curl the beam

    scene, body = beam()
    body.set_excitation("top", 1.0)
    seen = []

    class Progress:
        def update(self, n):
            seen.append(body.u.x.array.copy())

    counts = scene.solve_static(load_steps=2, progress=Progress())
    assert len(counts) == len(seen) == 2
    np.testing.assert_allclose(seen[0], half, rtol=0, atol=1e-9 * np.abs(half).max())
    assert np.abs(seen[1] - half).max() > 0.1 * np.abs(half).max()
    assert body.muscles["top"].excitation.value == 1.0
    assert body.load_factor.value == body.activation_factor.value == 1.0

    # a solve that fails gives the loads and the activation back as they were set
    scene, body = beam()
    body.set_excitation("top", 1.0)
    with pytest.raises(af.StepFailed):
        scene.solve_static(load_steps="auto", max_iterations=1)
    assert body.load_factor.value == body.activation_factor.value == 1.0
