"""Points attached to full and reduced FEM bodies: weights, G, virtual work, bad input."""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.multibody.point_attachments import (
    FemPointAttachment,
    ReducedPointAttachment,
    nearest_nodes,
    shape_function_weights,
    support_weights,
)
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from reduced_beam import make_body, ndofs, random_basis

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="attachments are serial for now")

INSIDE = np.array([0.61, 0.17, 0.07])  # inside the 1 x 0.3 x 0.2 beam, off the nodes


def affine_displacement(body, A, c):
    x = body.V.tabulate_dof_coordinates()
    u = x @ A.T + c
    body.u.x.array[:] = u.ravel()
    return u


@pytest.mark.parametrize("support", ["element", 4, 24])
def test_weights_reproduce_the_point_and_any_affine_motion(support):
    body = make_body()
    if support == "element":
        w = shape_function_weights(body, INSIDE)
        assert w.dofs.size == 8 and np.all(w.weights >= -1e-14)
    else:
        w = support_weights(body, INSIDE, nearest_nodes(body, INSIDE, support))
        assert w.dofs.size == support
    assert w.weights.sum() == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(w.rest_position, INSIDE, atol=1e-14)
    A = np.array([[0.1, -0.2, 0.05], [0.3, 0.02, -0.1], [0.0, 0.15, -0.05]])
    c = np.array([0.01, -0.02, 0.03])
    affine_displacement(body, A, c)
    att = FemPointAttachment(body, w)
    np.testing.assert_allclose(att.position(), INSIDE + A @ INSIDE + c, atol=1e-14)


def test_more_support_nodes_spread_the_force_thinner():
    body = make_body()
    w4 = support_weights(body, INSIDE, nearest_nodes(body, INSIDE, 4))
    w24 = support_weights(body, INSIDE, nearest_nodes(body, INSIDE, 24))
    assert np.abs(w24.weights).max() < np.abs(w4.weights).max()
    assert np.linalg.norm(w24.weights) < np.linalg.norm(w4.weights)  # minimum norm


def point_evaluation(function, X) -> np.ndarray:
    """function(X) (3,) by DOLFINx's own point evaluation (bounding-box tree, colliding
    cell, Function.eval): a reference that does not use the attachment's weights."""
    from dolfinx import geometry

    msh = function.function_space.mesh
    X = np.asarray(X, dtype=float).reshape(1, 3)
    tree = geometry.bb_tree(msh, msh.topology.dim)
    cells = geometry.compute_colliding_cells(msh, geometry.compute_collisions_points(tree, X), X)
    return function.eval(X, np.array([cells.links(0)[0]], dtype=np.int32)).reshape(3)


def position_difference(body, position, du, eps=1e-4) -> np.ndarray:
    """Central difference of ``position()`` along the nodal displacement direction du (the
    point's position is linear in u: exact to round-off, 1e-16 / eps); u is restored."""
    u0 = body.u.x.array.copy()
    x = []
    for sign in (1.0, -1.0):
        body.u.x.array[: ndofs(body)] = u0[: ndofs(body)] + sign * eps * du
        x.append(position())
    body.u.x.array[:] = u0
    return (x[0] - x[1]) / (2 * eps)


def test_virtual_work_and_G_of_full_and_reduced_attachments():
    """The velocity, G and the master force G^T f against a central difference of the
    attached point's position along a random motion (f . dx = G^T f . du is the virtual
    work), the full point's position against DOLFINx's own evaluation of u_h there (so the
    differences are of the real position map). (The check this replaces, f . G v against
    G^T f . v, holds for any G.) Measured: 1e-12 relative; asserted 1e-9."""
    body = make_body()
    rng = np.random.default_rng(4)
    weights = shape_function_weights(body, INSIDE)
    full = FemPointAttachment(body, weights)
    v = rng.standard_normal(ndofs(body))
    body.v.x.array[: ndofs(body)] = v
    f = rng.standard_normal(3)
    u0 = rng.standard_normal(ndofs(body)) * 1e-3
    body.u.x.array[: ndofs(body)] = u0
    np.testing.assert_allclose(
        full.position(), INSIDE + point_evaluation(body.u, INSIDE), rtol=0, atol=1e-14
    )
    dx = position_difference(body, full.position, v)
    assert np.linalg.norm(dx) > 0.1
    np.testing.assert_allclose(full.velocity(), dx, rtol=0, atol=1e-9 * np.linalg.norm(dx))
    np.testing.assert_allclose(full.G @ v, dx, rtol=0, atol=1e-9 * np.linalg.norm(dx))
    assert full.master_force(f) @ v == pytest.approx(f @ dx, rel=1e-9)

    U = random_basis(body, 5, seed=2, scale=1e-2)
    reduced = ReducedFemBody(body, U, all_points(body))
    att = ReducedPointAttachment(reduced, weights)
    np.testing.assert_allclose(att.G, full.G @ U, atol=1e-15)
    q, qdot = rng.standard_normal(5), rng.standard_normal(5)
    reduced.set_state((q, qdot))
    reduced.to_full()
    np.testing.assert_allclose(att.position(), full.position(), atol=1e-14)
    np.testing.assert_allclose(att.velocity(), full.velocity(), atol=1e-14)
    # along qdot, through the full body (u_bar + U q written by to_full, the full point's
    # position): the reduced generalized force does the work of f
    x = []
    for sign in (1.0, -1.0):
        reduced.set_q(q + sign * 1e-2 * qdot)
        reduced.to_full()
        x.append(full.position())
    reduced.set_q(q)
    dx = (x[0] - x[1]) / 2e-2
    assert np.linalg.norm(dx) > 1e-3
    np.testing.assert_allclose(att.velocity(), dx, rtol=0, atol=1e-9 * np.linalg.norm(dx))
    assert att.master_force(f) @ qdot == pytest.approx(f @ dx, rel=1e-9)


def test_points_outside_are_refused_or_snapped_with_their_distance():
    body = make_body()
    outside = np.array([1.05, 0.1, 0.1])  # 5 cm beyond the tip face
    with pytest.raises(ValueError, match=r"outside FEM body .*distance 0.05"):
        shape_function_weights(body, outside)
    w = shape_function_weights(body, outside, snap=True)
    assert w.distance == pytest.approx(0.05, abs=1e-12)
    np.testing.assert_allclose(w.rest_position, [1.0, 0.1, 0.1], atol=1e-12)


def test_bad_supports_are_clear_errors():
    body = make_body()
    x = body.V.tabulate_dof_coordinates()
    inverse = {d: n for n, d in body._input_node_to_dof().items()}
    flat = [inverse[d] for d in np.flatnonzero(np.abs(x[:, 2]) < 1e-12)[:6]]  # all at z = 0
    with pytest.raises(ValueError, match="coplanar"):
        support_weights(body, INSIDE, flat)
    with pytest.raises(ValueError, match="not nodes"):
        support_weights(body, INSIDE, [0, 1, 2, 10**6])
    with pytest.raises(ValueError, match="at least 4"):
        nearest_nodes(body, INSIDE, 3)


def test_nonnegative_weights_partition_reproduce_and_keep_virtual_work():
    body = make_body()
    # where the min-norm weights are already >= 0 they are the answer
    nodes = nearest_nodes(body, INSIDE, 24)
    np.testing.assert_allclose(
        support_weights(body, INSIDE, nodes, nonnegative=True).weights,
        support_weights(body, INSIDE, nodes).weights,
        atol=1e-12,
    )
    near = np.array([0.61, 0.17, 0.195])  # 5 mm under the top face
    nodes = nearest_nodes(body, near, 24)
    w24 = support_weights(body, near, nodes)
    assert w24.weights.min() < -0.01  # the min-norm weights are signed here
    w = support_weights(body, near, nodes, nonnegative=True)
    assert w.weights.min() >= 0.0
    assert w.weights.sum() == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(w.rest_position, near, atol=1e-14)
    # minimum norm among the non-negative weights: between the signed minimum and the
    # element's shape functions (also non-negative)
    assert (
        np.linalg.norm(w24.weights) - 1e-12
        <= np.linalg.norm(w.weights)
        <= np.linalg.norm(shape_function_weights(body, near).weights) + 1e-12
    )
    X = body.V.tabulate_dof_coordinates()[w.dofs]
    A = np.vstack([X.T, np.ones(len(X))])
    assert np.linalg.norm(A @ w.weights - np.append(near, 1.0)) < 1e-14
    att = FemPointAttachment(body, w)
    rng = np.random.default_rng(7)
    v, f = rng.standard_normal(ndofs(body)), rng.standard_normal(3)
    body.v.x.array[: ndofs(body)] = v
    # virtual work: G^T f against f . a central difference of the point's position along v
    dx = position_difference(body, att.position, v)
    np.testing.assert_allclose(att.velocity(), dx, rtol=0, atol=1e-9 * np.linalg.norm(dx))
    assert att.master_force(f) @ v == pytest.approx(f @ dx, rel=1e-9)
    # coplanar nodes are fine when the point lies in their hull: a face centre, 1/4 each
    x = body.V.tabulate_dof_coordinates()
    inverse = {d: n for n, d in body._input_node_to_dof().items()}
    face = [
        inverse[d]
        for d in np.flatnonzero(
            (np.abs(x[:, 2] - 0.2) < 1e-12) & (x[:, 0] <= 0.25 + 1e-12) & (x[:, 1] <= 0.15 + 1e-12)
        )
    ]
    centre = np.array([0.125, 0.075, 0.2])
    wf = support_weights(body, centre, face, nonnegative=True)
    np.testing.assert_allclose(wf.weights, 0.25, atol=1e-12)


def test_nonnegative_weights_refuse_a_point_outside_the_hull_with_its_distance():
    body = make_body()
    outside = np.array([1.05, 0.1, 0.1])  # 5 cm beyond the tip face
    with pytest.raises(
        ValueError,
        match=r"not in the convex hull of its 24 support nodes "
        r"\(distance 0.05\)",
    ):
        support_weights(body, outside, nearest_nodes(body, outside, 24), nonnegative=True)
