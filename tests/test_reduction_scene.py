"""Reduced FEM bodies in a Scene, with the same integrators and excitations.

Nothing couples the bodies here: each is an island of its own, advanced by the
scene's integrator (``advance`` with a PETSc solver for a full body,
``advance_reduced`` for a reduced one). Each scene is built with the gravity of
its bodies (``Scene.add`` sets a body's gravity to the scene's).

(a) full basis + every cell with weight 1: a reduced body stepped in a Scene
    equals the full body stepped in another Scene (MUMPS) to round-off, with
    the semi-implicit and the implicit integrator;
(b) solve_static_reduced with the full basis equals the full static solve; one that starts
    inverted says so instead of passing as converged on a NaN force;
(c) a step that inverts is halved, and a failure that halving cannot cure
    restores the last good state and raises a clear error;
(d) undamped implicit Euler on a small random basis with random positive
    cubature weights never gains energy;
(e) an excitation controller on the full body drives the reduced body, with
    the full and the reduced body in the same Scene.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.excitation import ExcitationSchedule
from artifem.errors import ElementInversionError, StepFailed
from artifem.fem_body import FemBody
from artifem.forms import NeoHookean
from artifem.integrators import ImplicitEuler, solve_static_reduced
from artifem.reduction.cubature import IntegrationPoints
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from artifem.scene import Scene

from reduced_beam import free_rows, full_basis, make_body, ndofs

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="ReducedFemBody is serial")

INTEGRATORS = ["semi-implicit", "implicit"]


def full_reduced(body, **kwargs):
    return ReducedFemBody(body, full_basis(body), all_points(body), **kwargs)


def assert_same(reduced, body):
    """Reduced u = U q and v = U q' equal the full body's u, v to 1e-10 relative."""
    n = ndofs(body)
    u, v = body.u.x.array[:n], body.v.x.array[:n]
    np.testing.assert_allclose(
        reduced.nodal_displacement(), u, rtol=0, atol=1e-10 * np.abs(u).max()
    )
    np.testing.assert_allclose(reduced.U @ reduced.qdot, v, rtol=0, atol=1e-10 * np.abs(v).max())


# ---- (a) same trajectory as the full body ---------------------------------------------------


def energies(scene) -> dict[str, float]:
    return {
        "kinetic": scene.kinetic_energy(),
        "potential": scene.potential_energy(),
        "total": scene.energy(),
    }


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_full_basis_reduced_body_in_a_scene_reproduces_the_full_body(integrator):
    body = make_body()
    reduced = full_reduced(body)
    g = body.gravity.value.copy()
    full_scene = Scene(gravity=g, integrator=integrator, linear_solver="mumps")
    full_scene.add(body)
    reduced_scene = Scene(gravity=g, integrator=integrator)
    reduced_scene.add(reduced)
    # Each body is an island of its own (the reduced one is stepped densely by
    # advance_reduced, without a linear solver).
    assert full_scene.islands() == ([body], [])
    assert reduced_scene.islands() == ([reduced], [])
    dt = 0.01
    for _ in range(10):
        full_scene.step(dt)
        reduced_scene.step(dt)
        assert np.abs(body.u.x.array).max() > 1e-4  # it moves
        assert_same(reduced, body)
    assert full_scene.halvings == reduced_scene.halvings == 0
    assert reduced_scene.t == pytest.approx(0.1)

    # The energy of the reduced body is the full one's.
    e_full, e_red = energies(full_scene), energies(reduced_scene)
    for key in ("kinetic", "potential", "total"):
        assert e_red[key] == pytest.approx(e_full[key], rel=1e-9, abs=1e-12)
    assert e_full["kinetic"] > 0


# ---- (b) statics ----------------------------------------------------------------------------


def test_reduced_static_solve_equals_the_full_one():
    body = make_body(young=1.0e6)
    reduced = full_reduced(body)
    scene = Scene(gravity=body.gravity.value.copy(), linear_solver="mumps")
    scene.add(body)
    scene.solve_static(load_steps=2)
    n = ndofs(body)
    u = body.u.x.array[:n]
    assert np.abs(u).max() > 1e-2  # a large, nonlinear deflection

    counts = solve_static_reduced(reduced, load_steps=2)
    assert len(counts) == 2 and all(0 < c <= 30 for c in counts)
    np.testing.assert_allclose(reduced.nodal_displacement(), u, rtol=0, atol=1e-8 * np.abs(u).max())
    # load steps chosen by the solver (integrators.ramp_load), from rest: the same answer
    reduced.set_q(np.zeros(reduced.r))
    counts = solve_static_reduced(reduced, load_steps="auto")
    assert counts.factors[-1] == 1.0 and max(counts) <= 10, counts
    np.testing.assert_allclose(reduced.nodal_displacement(), u, rtol=0, atol=1e-8 * np.abs(u).max())
    # Through a Scene (already at equilibrium: no Newton step moves it).
    reduced_scene = Scene(gravity=body.gravity.value.copy())
    reduced_scene.add(reduced)
    reduced_scene.solve_static()
    np.testing.assert_allclose(reduced.nodal_displacement(), u, rtol=0, atol=1e-8 * np.abs(u).max())


# ---- (c) inversion --------------------------------------------------------------------------


def soft_cube(total_load, corner=False):
    """A soft 1 m cube (E = 1 kPa) clamped at z = 0, pushed down on its top face (or corner)."""
    msh = dmesh.create_box(
        MPI.COMM_WORLD, [np.zeros(3), np.ones(3)], [3, 3, 3], dmesh.CellType.hexahedron
    )
    body = FemBody(msh, NeoHookean.from_young_poisson(1.0e3, 0.3), 100.0, rayleigh=(1.0, 0.0))
    x = msh.geometry.x
    inputs = np.asarray(msh.geometry.input_global_indices, dtype=np.int64)
    body.fix_nodes(inputs[x[:, 2] < 1e-12])
    top = x[:, 2] > 1 - 1e-12
    if corner:
        top &= (x[:, 0] > 1 - 1e-12) & (x[:, 1] > 1 - 1e-12)
    body.add_nodal_load(inputs[top], [0.0, 0.0, -total_load / top.sum()])
    return body, full_reduced(body)


def top_displacement(reduced):
    u = reduced.nodal_displacement().reshape(-1, 3)
    z = reduced.full.V.tabulate_dof_coordinates()[:, 2]
    return u[z > 1 - 1e-12]


def cell_containing(msh, point) -> int:
    """Input index of the cell whose vertex centroid is closest to ``point``."""
    n = msh.topology.index_map(3).size_local
    centroids = msh.geometry.x[msh.geometry.dofmaps[0][:n]].mean(axis=1)
    local = int(np.argmin(np.linalg.norm(centroids - point, axis=1)))
    return int(msh.topology.original_cell_index[local])


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_a_step_that_inverts_is_halved(integrator):
    """1 kN on the top face of the soft cube, dt = 0.3 s: the full step fails (the
    semi-implicit step inverts, see test_dynamics; the implicit Newton does not
    converge without inverting); with halving it recovers, as the full body does: the
    reduced body has the full basis, so its halved steps are the full body's (the same
    halvings, the same state to 1e-10)."""
    _, reduced = soft_cube(1.0e3)
    strict = Scene(gravity=(0.0, 0.0, 0.0), integrator=integrator, max_halvings=0)
    strict.add(reduced)
    with pytest.raises((ElementInversionError, StepFailed)) as info:
        strict.step(0.3)
    if integrator == "semi-implicit":
        assert isinstance(info.value, ElementInversionError)
        assert info.value.elements.size > 0 and info.value.min_det <= 0
    # Restored: the state at the start of the failed step.
    assert np.all(reduced.q == 0) and np.all(reduced.qdot == 0)
    assert strict.t == 0

    _, reduced = soft_cube(1.0e3)
    scene = Scene(gravity=(0.0, 0.0, 0.0), integrator=integrator)
    scene.add(reduced)
    scene.step(0.3)
    body, _ = soft_cube(1.0e3)
    full = Scene(gravity=(0.0, 0.0, 0.0), integrator=integrator, linear_solver="mumps")
    full.add(body)
    full.step(0.3)
    assert scene.halvings == full.halvings > 0
    assert scene.t == pytest.approx(0.3)
    bad, min_det = reduced.inverted_elements()
    assert bad.size == 0 and min_det > 0
    assert_same(reduced, body)
    assert top_displacement(reduced)[:, 2].max() < -0.1


def test_unrecoverable_inversion_names_the_elements_and_keeps_a_good_state():
    """3 kN on one corner of the soft cube crushes the corner element (the semi-implicit
    step alone: the implicit integrator, and so the default fallback, survives this by
    halving)."""
    body, reduced = soft_cube(3.0e3, corner=True)
    scene = Scene(gravity=(0.0, 0.0, 0.0), fallback=None)
    scene.add(reduced)
    dt = 0.1
    with pytest.raises(ElementInversionError) as info:
        for _ in range(10):
            scene.step(dt)
    err = info.value
    corner_cell = cell_containing(body.mesh, np.array([5 / 6, 5 / 6, 5 / 6]))
    assert corner_cell in err.elements.tolist() and err.min_det <= 0
    # Sub-steps of the failing step that succeeded stay done: the state is the one
    # at the start of the smallest sub-step that failed (finite, nothing inverted).
    assert scene.halvings >= scene.max_halvings
    assert scene.t > 0
    assert err.time == pytest.approx(scene.t + dt / 2**scene.max_halvings)
    assert all(np.all(np.isfinite(a)) for a in reduced.state())
    bad, min_det = reduced.inverted_elements()
    assert bad.size == 0 and min_det > 0
    assert np.abs(reduced.q).max() > 1e-3


# ---- (d) energy -----------------------------------------------------------------------------


def test_undamped_implicit_reduced_body_never_gains_energy():
    """Backward Euler on a conservative system dissipates at least the jump of the
    kinetic energy: E_{k+1} - E_k = -1/2 dq'^T M~ dq' - (Pi~(q_k) - Pi~(q_{k+1})
    - f~(q_{k+1}) . (q_k - q_{k+1})), the bracket >= 0 where Pi~ is convex (small
    strains). Measured: the energy drop is 1.015 to 20 times 1/2 dq'^T M~ dq', and the
    run ends at 0.1950 of its initial energy (its own seeded basis: deterministic)."""
    body = make_body(excitation=0.3, gravity=(0.0, 0.0, 0.0), loads=False, rayleigh=(0.0, 0.0))
    rng = np.random.default_rng(11)
    # A random basis, mass-orthonormalized (lumped mass): U^T M U = I.
    body.compile()
    n, r = ndofs(body), 8
    U = np.zeros((n, r))
    U[free_rows(body)] = rng.standard_normal((free_rows(body).size, r))
    m = body.M_lumped.array[:n]
    L = np.linalg.cholesky(U.T @ (m[:, None] * U))
    U = np.linalg.solve(L, U.T).T
    # Half the cells, random positive weights (about the right total volume).
    cells = np.sort(rng.choice(all_points(body).indices, size=8, replace=False))
    points = IntegrationPoints(cells, rng.uniform(1.5, 2.5, size=8), "random")
    reduced = ReducedFemBody(body, U, points)
    np.testing.assert_allclose(reduced.M, np.eye(r), atol=1e-12)
    q0 = rng.standard_normal(r)
    reduced.set_q(0.02 * q0 / np.abs(U @ q0).max())  # 2 cm initial displacement

    scene = Scene(gravity=(0.0, 0.0, 0.0), integrator="implicit")
    scene.add(reduced)
    total, kinetic, jumps = [scene.energy()], [0.0], []
    for _ in range(200):
        _, qdot = reduced.state()
        scene.step(0.002)
        dqdot = reduced.qdot - qdot
        jumps.append(0.5 * dqdot @ reduced.M @ dqdot)
        total.append(scene.energy())
        kinetic.append(scene.kinetic_energy())
    total, jumps = np.array(total), np.array(jumps)
    assert scene.halvings == 0
    assert total[0] > 0 and max(kinetic) > 0.1 * total[0]  # it vibrates
    change = np.diff(total)
    assert change.max() < 0, f"energy grew by {change.max():.3e}"
    # Dissipation at least the kinetic-energy jump (round-off of E: ~1e-13 of it).
    excess = change + jumps
    assert excess.max() <= 1e-10 * np.abs(total).max(), f"dissipation short by {excess.max():.3e}"
    # dissipative, but not overdamped: measured (two runs, same digits), rel 1e-6
    assert total[-1] / total[0] == pytest.approx(0.19503076202538575, rel=1e-6)


# ---- (e) excitations --------------------------------------------------------------------------


def test_excitation_controller_on_the_full_body_drives_the_reduced_body():
    """No loads, excitation 0: nothing moves until the controller ramps the muscle up.
    The full body and its full-basis reduced twin in one Scene move alike (each its own
    island: the twin shares the body's excitation constants, nothing couples them)."""
    body = make_body(excitation=0.0, gravity=(0.0, 0.0, 0.0), loads=False)
    reduced = full_reduced(body, name="twin")
    scene = Scene(
        gravity=(0.0, 0.0, 0.0), integrator=ImplicitEuler(rtol=1e-12), linear_solver="mumps"
    )
    scene.add(body, reduced)
    assert [b.name for b in scene.bodies] == [body.name, "twin"]
    assert scene.islands() == ([body, reduced], [])
    scene.step(0.01)
    assert np.abs(reduced.q).max() == 0.0 and np.abs(body.u.x.array).max() == 0.0

    schedule = ExcitationSchedule.ramp_and_hold({"top": 0.8}, ramp_time=0.05)
    scene.add_controller(schedule.controller(body))
    for _ in range(8):
        scene.step(0.01)
        assert_same(reduced, body)
    assert body.muscles["top"].excitation.value == pytest.approx(0.8)
    assert np.abs(reduced.nodal_displacement()).max() > 1e-4
    assert scene.kinetic_energy() > 0


def test_a_static_reduced_solve_from_an_inverted_state_says_so():
    reduced = full_reduced(make_body(excitation=0.3))
    q = np.zeros(reduced.r)
    q[0::3] = -2.0  # every free node 2 m back past the clamp
    reduced.set_q(q)
    with pytest.raises(StepFailed, match="inverted element"):
        solve_static_reduced(reduced)
