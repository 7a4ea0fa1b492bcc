"""Points attached to full and reduced FEM bodies: weights, G, virtual work, bad input."""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.multibody.point_attachments import (FemPointAttachment, ReducedPointAttachment,
                                                 nearest_nodes, shape_function_weights,
                                                 support_weights)
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from reduced_beam import make_body, ndofs, random_basis

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="attachments are serial for now")

INSIDE = np.array([0.61, 0.17, 0.07])            # inside the 1 x 0.3 x 0.2 beam, off the nodes


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
    assert np.linalg.norm(w24.weights) < np.linalg.norm(w4.weights)   # minimum norm


def test_virtual_work_and_G_of_full_and_reduced_attachments():
    body = make_body()
    rng = np.random.default_rng(4)
    weights = shape_function_weights(body, INSIDE)
    full = FemPointAttachment(body, weights)
    v = rng.standard_normal(ndofs(body))
    body.v.x.array[:ndofs(body)] = v
    f = rng.standard_normal(3)
    np.testing.assert_allclose(full.velocity(), full.G @ v, atol=1e-14)
    assert f @ full.velocity() == pytest.approx(full.master_force(f) @ v, rel=1e-13)
    # G is the derivative of the position: exact for a linear map, checked by differences
    u0 = rng.standard_normal(ndofs(body)) * 1e-3
    du = rng.standard_normal(ndofs(body))
    body.u.x.array[:ndofs(body)] = u0
    x0 = full.position()
    body.u.x.array[:ndofs(body)] = u0 + 1e-6 * du
    np.testing.assert_allclose((full.position() - x0) / 1e-6, full.G @ du, rtol=1e-7)

    U = random_basis(body, 5, seed=2, scale=1e-2)
    reduced = ReducedFemBody(body, U, all_points(body))
    att = ReducedPointAttachment(reduced, weights)
    np.testing.assert_allclose(att.G, full.G @ U, atol=1e-15)
    q, qdot = rng.standard_normal(5), rng.standard_normal(5)
    reduced.set_state((q, qdot))
    reduced.to_full()
    np.testing.assert_allclose(att.position(), full.position(), atol=1e-14)
    np.testing.assert_allclose(att.velocity(), full.velocity(), atol=1e-14)
    assert f @ att.velocity() == pytest.approx(att.master_force(f) @ qdot, rel=1e-13)


def test_points_outside_are_refused_or_snapped_with_their_distance():
    body = make_body()
    outside = np.array([1.05, 0.1, 0.1])          # 5 cm beyond the tip face
    with pytest.raises(ValueError, match=r"outside FEM body .*distance 0.05"):
        shape_function_weights(body, outside)
    w = shape_function_weights(body, outside, snap=True)
    assert w.distance == pytest.approx(0.05, abs=1e-12)
    np.testing.assert_allclose(w.rest_position, [1.0, 0.1, 0.1], atol=1e-12)


def test_bad_supports_are_clear_errors():
    body = make_body()
    x = body.V.tabulate_dof_coordinates()
    inverse = {d: n for n, d in body._input_node_to_dof().items()}
    flat = [inverse[d] for d in np.flatnonzero(np.abs(x[:, 2]) < 1e-12)[:6]]   # all at z = 0
    with pytest.raises(ValueError, match="coplanar"):
        support_weights(body, INSIDE, flat)
    with pytest.raises(ValueError, match="not nodes"):
        support_weights(body, INSIDE, [0, 1, 2, 10**6])
    with pytest.raises(ValueError, match="at least 4"):
        nearest_nodes(body, INSIDE, 3)
