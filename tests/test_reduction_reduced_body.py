"""Reduced FEM body (artifem.reduction.reduced_body) against the full model.

(a) full basis + every point with weight 1: the reduced semi-implicit
    trajectory equals the full one (Scene, MUMPS) to round-off, and so does the
    reduced implicit Euler with Rayleigh damping (same Newton iteration counts);
(b) U^T f consistency: f~(q) = U^T f(U q) and K~(q) = U^T K(U q) U for a
    general basis, all cells, weights 1; Pi~ is the potential of f~ (loads included);
(c) the points of a subset of cells with weights w equal the full-mesh assembly of the
    w-weighted (DG0) energy;
(d) muscles: the full body's excitation Constant drives the reduced force; overlapping
    muscles of two fiber kinds, each point's terms in one fused kernel, give U^T f and
    U^T K U, also after the excitations change;
(e) bad input (nonzero basis rows at fixed dofs) and inversion detection.
"""

import numpy as np
import pytest
import ufl

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import fem
from mpi4py import MPI

from artifem.errors import ElementInversionError
from artifem.forms import BlemkerFiber
from artifem.reduction.cubature import IntegrationPoints
from artifem.reduction.quadrature_points import quadrature_points
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from artifem.scene import Scene

from reduced_beam import full_basis, make_body, ndofs, random_basis

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="ReducedFemBody is serial")


def assert_projection_of_full(reduced, body, U, q, tangent_tol=1e-12):
    """The reduced force and tangent at q are U^T f(U q) and U^T K(U q) U; returns U^T f."""
    f, K = full_force_and_tangent(body, U @ q)
    f_ref, K_ref = U.T @ f, U.T @ K @ U
    np.testing.assert_allclose(reduced.force(), f_ref, rtol=0, atol=1e-12 * np.abs(f_ref).max())
    np.testing.assert_allclose(
        reduced.tangent(), K_ref, rtol=0, atol=tangent_tol * np.abs(K_ref).max()
    )
    return f_ref


def full_force_and_tangent(body, u):
    body.u.x.array[: u.size] = u
    body.u.x.scatter_forward()
    body.assemble(tangent=True)
    n = ndofs(body)
    K = body.K.copy().convert("dense").getDenseArray()[:n, :n]
    return -body.R.array[:n].copy(), K


# ---- (a) the key test: full basis, all cells ------------------------------------------------


@pytest.mark.parametrize("mass", ["lumped", "consistent"])
def test_full_basis_reproduces_the_full_trajectory(mass):
    body = make_body(mass=mass)
    reduced = ReducedFemBody(body, full_basis(body), all_points(body))
    # 2x2x2 Gauss points of the energy and the centre point of the penalty, per cell
    assert reduced.m == 9 * body.mesh.topology.index_map(3).size_local
    # Each scene with the body's gravity (Scene.add sets the body's gravity to the scene's).
    g = body.gravity.value.copy()
    scene = Scene(gravity=g, linear_solver="mumps")
    scene.add(body)
    reduced_scene = Scene(gravity=g)
    reduced_scene.add(reduced)
    n = ndofs(body)
    dt = 0.01
    for _ in range(10):
        scene.step(dt)
        reduced_scene.step(dt)
        u_full, v_full = body.u.x.array[:n], body.v.x.array[:n]
        assert np.abs(u_full).max() > 1e-4  # it moves
        np.testing.assert_allclose(
            reduced.nodal_displacement(), u_full, rtol=0, atol=1e-10 * np.abs(u_full).max()
        )
        np.testing.assert_allclose(
            reduced.nodal_velocity(), v_full, rtol=0, atol=1e-10 * np.abs(v_full).max()
        )
    assert reduced_scene.t == pytest.approx(scene.t)


def test_full_basis_reproduces_the_full_implicit_euler_with_rayleigh_damping():
    """ImplicitEuler.advance_reduced on the full basis against ImplicitEuler.advance on the
    full body, Rayleigh damping alpha = 0.5, beta = 0.01 on: the same Newton on the same
    equations, so the same trajectory to round-off and the same iteration count per step
    (2 or 3: quadratic convergence needs the exact Jacobian M + h D + h^2 K)."""
    body = make_body()
    assert body.alpha > 0 and body.beta > 0
    reduced = ReducedFemBody(body, full_basis(body), all_points(body))
    g = body.gravity.value.copy()
    scene = Scene(gravity=g, integrator="implicit", linear_solver="mumps")
    scene.add(body)
    reduced_scene = Scene(gravity=g, integrator="implicit")
    reduced_scene.add(reduced)
    n = ndofs(body)
    for _ in range(5):
        scene.step(0.01)
        reduced_scene.step(0.01)
        u_full, v_full = body.u.x.array[:n], body.v.x.array[:n]
        np.testing.assert_allclose(
            reduced.nodal_displacement(), u_full, rtol=0, atol=1e-10 * np.abs(u_full).max()
        )
        np.testing.assert_allclose(
            reduced.nodal_velocity(), v_full, rtol=0, atol=1e-10 * np.abs(v_full).max()
        )
        its = reduced_scene.integrator.iterations
        assert its == scene.integrator.iterations and 1 <= its <= 3
    assert np.abs(u_full).max() > 1e-2  # it moves
    assert scene.halvings == reduced_scene.halvings == 0


# ---- (b) U^T f consistency ------------------------------------------------------------------


def test_reduced_force_and_tangent_are_projections_of_the_full_ones():
    body = make_body()
    U = random_basis(body, 7, seed=3)
    reduced = ReducedFemBody(body, U, all_points(body))
    q = 1e-2 * np.random.default_rng(4).standard_normal(7)
    reduced.set_q(q)
    f_full, K_full = full_force_and_tangent(body, U @ q)
    f_red = reduced.force()
    np.testing.assert_allclose(f_red, U.T @ f_full, rtol=0, atol=1e-12 * np.abs(U.T @ f_full).max())
    K_ref = U.T @ K_full @ U
    np.testing.assert_allclose(reduced.tangent(), K_ref, rtol=0, atol=1e-12 * np.abs(K_ref).max())
    # Mass: U^T M U with the lumped mass.
    m = body.M_lumped.array[: ndofs(body)]
    np.testing.assert_allclose(reduced.M, U.T @ (m[:, None] * U), rtol=1e-13)


def test_reduced_potential_is_the_potential_of_the_reduced_force():
    """dPi~/dq = -f~(q) by central differences along random directions, with gravity, the
    body force, the tip load and an active muscle on (the loads f~_ext are a visible part
    of f~: their work -q . f~_ext enters Pi~ with its sign)."""
    rng = np.random.default_rng(11)
    body = make_body()
    U = random_basis(body, 6, seed=12)
    reduced = ReducedFemBody(body, U, all_points(body))
    q = 1e-4 * rng.standard_normal(6)  # small: the internal force does not swamp the loads
    reduced.set_q(q)
    f = reduced.force()
    assert np.linalg.norm(reduced.external_force()) > 0.2 * np.linalg.norm(f)
    eps = 1e-6
    for _ in range(3):
        dq = rng.standard_normal(6)
        dq /= np.linalg.norm(dq)
        reduced.set_q(q + eps * dq)
        plus = reduced.potential_energy()
        reduced.set_q(q - eps * dq)
        minus = reduced.potential_energy()
        slope = (plus - minus) / (2 * eps)
        assert slope == pytest.approx(-(f @ dq), rel=1e-6, abs=1e-8 * np.abs(f).max())


# ---- (c) subset of cells with weights -------------------------------------------------------


def weighted_full_residual(body, cells, weights):
    """Full-mesh assembly of the w-weighted internal energy (w = 0 off the subset)."""
    W = fem.functionspace(body.mesh, ("DG", 0))
    w = fem.Function(W)
    w.x.array[W.dofmap.list[cells, 0]] = weights
    F = body.kinematics()
    md = {"quadrature_degree": body.quadrature_degree}
    dx = ufl.Measure("dx", domain=body.mesh, metadata=md)
    Pi = w * body.material.strain_energy(F) * dx
    data = [(i + 1, m.cells) for i, m in enumerate(body.muscles.values())]
    dxm = ufl.Measure("dx", domain=body.mesh, metadata=md, subdomain_data=data)
    for i, m in enumerate(body.muscles.values()):
        Pi += w * m.fiber.strain_energy(F, m.direction, m.excitation) * dxm(i + 1)
    centre = ufl.Measure("dx", domain=body.mesh, metadata={"quadrature_degree": 1})
    Pi += w * 0.5 * body.incompressibility * (ufl.det(F) - 1) ** 2 * centre
    R = fem.assemble_vector(fem.form(ufl.derivative(Pi, body.u, ufl.TestFunction(body.V))))
    return R.array[: ndofs(body)].copy()


def test_subset_with_weights_equals_the_weighted_full_assembly():
    body = make_body()
    rng = np.random.default_rng(5)
    n = body.mesh.topology.index_map(3).size_local
    cells = np.sort(rng.choice(n, size=5, replace=False))
    weights = rng.uniform(0.5, 3.0, size=5)
    U = random_basis(body, 6, seed=6)
    # Every point of the chosen cells, weighted by its cell's weight.
    table = quadrature_points(body)
    at = np.flatnonzero(np.isin(table.cell, cells))
    point_weights = weights[np.searchsorted(cells, table.cell[at])]
    reduced = ReducedFemBody(body, U, IntegrationPoints(at, point_weights, "random"))
    assert reduced.m == 5 * 9
    q = 1e-2 * rng.standard_normal(6)
    reduced.set_q(q)
    body.u.x.array[: ndofs(body)] = U @ q
    ref = U.T @ weighted_full_residual(body, cells, weights)
    got = reduced.internal_residual()
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    # The external force stays exact (not sampled): U^T f_ext of the full model.
    body.u.x.array[:] = 0.0
    body.muscles["top"].excitation.value = 0.0
    f0, _ = full_force_and_tangent(body, np.zeros(ndofs(body)))
    # At u = 0 with no excitation the internal force vanishes: only the external
    # part is left, and it must equal the full model's.
    reduced.set_q(np.zeros(6))
    np.testing.assert_allclose(
        reduced.force(), U.T @ f0, rtol=0, atol=1e-12 * np.abs(U.T @ f0).max()
    )


# ---- (d) muscles ----------------------------------------------------------------------------


def test_full_body_excitation_drives_the_reduced_force():
    body = make_body(excitation=0.0)
    U = random_basis(body, 5, seed=7)
    reduced = ReducedFemBody(body, U, all_points(body))
    q = 1e-2 * np.random.default_rng(8).standard_normal(5)
    reduced.set_q(q)
    f0 = reduced.force()
    body.set_excitation("top", 0.8)
    f1 = reduced.force()
    assert np.abs(f1 - f0).max() > 1e-3 * np.abs(f0).max()
    f_full, _ = full_force_and_tangent(body, U @ q)
    np.testing.assert_allclose(f1, U.T @ f_full, rtol=0, atol=1e-12 * np.abs(f1).max())


def test_fused_kernels_of_overlapping_muscles_are_projections_of_the_full_body():
    """Three muscles: two of one fiber kind overlapping (two layers of it), one of another
    kind, with the material and the penalty (degree-1 points): each point's terms share
    one fused kernel, whose force and tangent are U^T f and U^T K U of the full body, also
    after the excitations change (read live from the muscles)."""
    body = make_body(excitation=0.3)
    msh = body.mesh
    n = msh.topology.index_map(3).size_local
    centroids = msh.geometry.x[msh.geometry.dofmaps[0][:n]].mean(axis=1)
    original = np.asarray(msh.topology.original_cell_index[:n])
    rng = np.random.default_rng(11)
    front = original[centroids[:, 0] < 0.6]
    side = original[centroids[:, 1] < 0.15]
    body.add_muscle(
        "front", front, rng.standard_normal((front.size, 3)), BlemkerFiber(3.0e4), excitation=0.6
    )
    body.add_muscle("side", side, (0.0, 1.0, 0.2), BlemkerFiber(1.0e4, P2=5.0), excitation=0.9)
    U = random_basis(body, 6, seed=12)
    reduced = ReducedFemBody(body, U, all_points(body))
    assert max(len(k.slots) for k in reduced._stresses.kernels) >= 3  # fused terms
    q = 1e-2 * np.random.default_rng(13).standard_normal(6)
    for excitations in ({}, {"top": 0.0, "front": 1.0, "side": 0.25}):
        for name, value in excitations.items():
            body.set_excitation(name, value)
        reduced.set_q(q)
        assert_projection_of_full(reduced, body, U, q)


# ---- (e) bad input and inversion ------------------------------------------------------------


def test_basis_rows_at_fixed_dofs_must_be_zero():
    body = make_body()
    U = random_basis(body, 3)
    U[3 * body.fixed_dofs[0], 1] = 1.0
    with pytest.raises(ValueError, match="fixed dofs"):
        ReducedFemBody(body, U, all_points(body))
    # round-off up to 1e-10 max|U| is not a nonzero row: a node at exactly that is not named
    U /= np.abs(U).max()
    U[3 * body.fixed_dofs[1] + 2, 0] = 1e-10
    with pytest.raises(ValueError, match=r"nonzero at 1 fixed node\(s\)"):
        ReducedFemBody(body, U, all_points(body))
    with pytest.raises(ValueError, match="shape"):
        ReducedFemBody(body, U[:-1], all_points(body))


def test_inversion_is_reported_with_input_cell_indices():
    body = make_body()
    U = full_basis(body)
    reduced = ReducedFemBody(body, U, all_points(body))
    u = np.zeros(ndofs(body))
    x = body.V.tabulate_dof_coordinates()[: ndofs(body) // 3]
    u[0::3] = -3.0 * x[:, 0] * (x[:, 0] > 0.5)  # fold the outer half back
    q = U.T @ u
    reduced.set_q(q)
    bad, min_det = reduced.inverted_elements()
    body.u.x.array[: ndofs(body)] = U @ q
    bad_full, min_full = body.inverted_elements()
    assert bad.size > 0 and min_det <= 0
    np.testing.assert_array_equal(bad, bad_full)
    assert min_det == pytest.approx(min_full)
    state = reduced.state()
    strict = Scene(gravity=body.gravity.value.copy(), max_halvings=0)
    strict.add(reduced)
    with pytest.raises(ElementInversionError) as info:
        strict.step(1e-6)
    assert info.value.elements.size > 0
    np.testing.assert_array_equal(reduced.q, state[0])  # state kept


def test_full_mesh_inversion_sees_what_the_integration_points_cannot():
    """A corner node pushed through its cell: invisible to points outside that cell."""
    body = make_body()
    x = body.V.tabulate_dof_coordinates()[: ndofs(body) // 3]
    corner = int(np.argmax(x[:, 0] + x[:, 1] + x[:, 2]))  # (1, 0.3, 0.2): one hex only
    U = np.zeros((ndofs(body), 1))
    U[3 * corner, 0] = 1.0
    table = quadrature_points(body)
    corner_cells = np.unique(table.cell[np.any(table.dofs == corner, axis=1)])
    assert corner_cells.size == 1
    elsewhere = np.flatnonzero(table.cell != corner_cells[0])
    reduced = ReducedFemBody(
        body, U, IntegrationPoints(elsewhere, np.ones(elsewhere.size), "random")
    )
    reduced.set_q([-0.45])  # the cell is 0.25 long in x
    bad, min_det = reduced.inverted_elements()
    assert bad.size == 0 and min_det > 0
    bad_full, min_full = reduced.full_mesh_inversion()
    assert bad_full.tolist() == body.input_cell_index(corner_cells).tolist() and min_full < 0
    assert np.all(body.u.x.array == 0.0)  # the full body's state is left alone


def test_loads_changed_after_construction_act_on_the_reduced_body():
    """Every load changed after the reduced body was built acts on it as on the full body:
    a nodal load added, a body force set, a constant of that body force given another value,
    the gravity and a dead traction changed, a traction and a follower pressure added. After
    each change, f~(q) = U^T f(U q) and K~(q) = U^T K(U q) U of the full body at the same
    state (to round-off)."""
    body = make_body(loads=False)
    traction = body.add_traction((0.0, 0.0, 0.0), where=lambda x: np.isclose(x[0], 1.0))
    U = random_basis(body, 7, seed=3)
    reduced = ReducedFemBody(body, U, all_points(body))
    q = 1e-2 * np.random.default_rng(4).standard_normal(7)
    reduced.set_q(q)
    seen = []

    def check():
        seen.append(assert_projection_of_full(reduced, body, U, q, tangent_tol=1e-10))

    check()
    x = body.mesh.geometry.x
    inputs = np.asarray(body.mesh.geometry.input_global_indices, dtype=np.int64)
    body.add_nodal_load(inputs[np.isclose(x[:, 0], 1.0)], [0.0, 0.3, 0.1])
    check()
    c = fem.Constant(body.mesh, np.array([0.0, 50.0, 0.0]))
    body.set_body_force(c * ufl.SpatialCoordinate(body.mesh)[0])
    check()
    c.value = np.array([10.0, 0.0, -20.0])
    check()
    body.gravity.value = np.array([0.0, -3.0, 0.0])
    check()
    traction.value.value = np.array([5.0, 0.0, 2.0])
    check()
    body.add_traction((0.0, 4.0, 0.0), where=lambda x: np.isclose(x[1], 0.3))
    check()
    body.add_pressure(30.0, where=lambda x: np.isclose(x[2], 0.2))
    check()
    # negative control: a reduced body that kept the old loads would miss each check by
    # `change`, a million times the round-off tolerance above
    changes = [np.abs(b - a).max() for a, b in zip(seen, seen[1:])]
    assert min(changes) > 1e-6 * max(np.abs(f).max() for f in seen), changes
