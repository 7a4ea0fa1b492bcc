"""Reduced FEM bodies in the coupled step (artifem.scene, reduction.rigid_lift).

(1) the lift columns reproduce any rigid pose of the carried nodes exactly
    (g is linear in (p, R)) and G_g is the derivative of g;
(2) with the full basis (identity on the free, uncarried dofs, plus the lift)
    and every integration point, a reduced body carried by a prescribed,
    turning bone reproduces the full body carried by NodeAttachment to
    round-off, step by step;
(3) statics on a hinged bone: the same equilibrium as the full scene;
(4) finite differences: the static tangent P^T K P - K_geo with the lift's
    lever term, and the step matrix built from it;
(5) a spring on a point of the reduced body (G = sum_j w_j U_j): statics equal the
    full scene's; G is the derivative of the point's position (DOLFINx's evaluation of
    the full displacement, by central differences) and G^T f does the work of f on it;
(6) bad input.
"""

import dataclasses

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.multibody.attachments import FemPoint, LiftAttachment, NodeAttachment
from artifem.multibody.point_paths import PointPath
from artifem.scene import Scene
from artifem.multibody.joints import RevoluteJoint, axis_rotation
from artifem.multibody.muscles import AxialSpring
from artifem.multibody.point_attachments import shape_function_weights
from artifem.multibody.rigid_body import BodyState, RigidBody, exp_so3
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from artifem.reduction.rigid_lift import rigid_lift
from reduced_beam import make_body, ndofs
from coupled_fd import master_force_difference

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")

G = 9.81


def end_nodes(body):
    return body.find_nodes(lambda x: x[0] > 1.0 - 1e-12)


def bone(motion="dynamic", **kw):
    return RigidBody(
        "bone",
        0.3,
        np.diag([2e-3, 3e-3, 4e-3]),
        position=(1.1, 0.15, 0.1),
        rotation=exp_so3([0.2, -0.1, 0.3]),
        motion=motion,
        **kw,
    )


def lifted_basis(body, lift, extra=None):
    """[identity on the free dofs not carried, (extra), lift columns]."""
    carried = (3 * lift.dofs[:, None] + np.arange(3)).ravel()
    fixed = (3 * body.fixed_dofs[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(ndofs(body)), np.concatenate([carried, fixed]))
    if extra is None:
        U = np.zeros((ndofs(body), free.size))
        U[free, np.arange(free.size)] = 1.0
    else:
        U = np.zeros((ndofs(body), extra))
        U[free] = np.random.default_rng(3).standard_normal((free.size, extra)) * 0.05
    return np.hstack([U, lift.columns])


def test_lift_reproduces_rigid_poses_and_its_jacobian():
    body = make_body()
    b = bone()
    lift = rigid_lift(body, end_nodes(body), b.position, b.rotation)
    X = body.V.tabulate_dof_coordinates()[lift.dofs]
    p, R = np.array([0.9, 0.3, -0.2]), exp_so3([1.2, -0.7, 2.0])  # a large motion
    g = lift.coordinates(p, R)
    d = (lift.columns @ g).reshape(-1, 3)[lift.dofs]
    x_rigid = p + (X - b.position) @ (R @ b.rotation.T).T
    assert np.abs(X + d - x_rigid).max() < 1e-14
    assert np.abs(lift.columns[3 * body.fixed_dofs]).max() == 0.0
    twist, eps = np.array([0.3, -0.2, 0.5, 0.7, -1.1, 0.4]), 1e-6
    g_of = [
        lift.coordinates(p + s * eps * twist[:3], exp_so3(s * eps * twist[3:]) @ R) for s in (1, -1)
    ]
    assert np.abs((g_of[0] - g_of[1]) / (2 * eps) - lift.jacobian(R) @ twist).max() < 1e-9


def prescribed_bone():
    p0, v0, w0 = np.array([1.1, 0.15, 0.1]), np.array([0.2, -0.1, 0.3]), np.array([0.8, -0.5, 1.0])
    R0 = exp_so3([0.2, -0.1, 0.3])
    return RigidBody(
        "bone",
        0.3,
        np.eye(3) * 1e-3,
        position=p0,
        rotation=R0,
        motion="prescribed",
        trajectory=lambda t: BodyState(p0 + v0 * t, exp_so3(t * w0) @ R0, v0, w0),
    )


def test_full_basis_reduced_body_on_a_prescribed_bone_matches_the_full_body():
    """Measured: max |u_reduced - u_full| = 1.5e-16 m on |u| = 0.08 m after 15 steps of a
    translating, turning bone (the secant of g is exact, the KKT systems are a change of
    variables)."""
    full, lifted = make_body(), make_body()
    b_full, b_red = prescribed_bone(), prescribed_bone()
    lift = rigid_lift(lifted, end_nodes(lifted), b_red.position, b_red.rotation)
    reduced = ReducedFemBody(lifted, lifted_basis(lifted, lift), all_points(lifted))
    s_full, s_red = Scene(gravity=(0, 0, -G)), Scene(gravity=(0, 0, -G))
    s_full.add(full, b_full)
    s_full.add(NodeAttachment(full, end_nodes(full), b_full))
    s_red.add(reduced, b_red)
    s_red.add(LiftAttachment(reduced, lift, b_red))
    for _ in range(15):
        s_full.step(0.01)
        s_red.step(0.01)
    u_full = full.u.x.array[: ndofs(full)]
    scale = np.abs(u_full).max()
    assert scale > 0.05
    assert np.abs(reduced.nodal_displacement() - u_full).max() < 1e-11 * scale
    v_full = full.v.x.array[: ndofs(full)]
    assert np.abs(reduced.nodal_velocity() - v_full).max() < 1e-10 * np.abs(v_full).max()


def hinged(reduced_basis=None, rayleigh=(0.5, 0.01)):
    """A beam whose end rides on a bone hinged to the world about z."""
    body = make_body(rayleigh=rayleigh)
    b = bone()
    hinge = RevoluteJoint.at_world(b, None, (1.2, 0.15, 0.1), axis_rotation((0.0, 0.0, 1.0)))
    scene = Scene(gravity=(0, 0, -G))
    scene.add(b, hinge)
    if reduced_basis is None:
        scene.add(body, NodeAttachment(body, end_nodes(body), b))
        return scene, body, b, None
    lift = rigid_lift(body, end_nodes(body), b.position, b.rotation)
    reduced = ReducedFemBody(body, reduced_basis(body, lift), all_points(body))
    scene.add(reduced, LiftAttachment(reduced, lift, b))
    return scene, body, b, reduced


def test_static_equilibrium_on_a_hinged_bone_matches_the_full_scene():
    """Equilibrium does not depend on the coordinates: measured 5e-11 m on 0.06 m."""
    s_full, full, b_full, _ = hinged()
    s_red, _, b_red, reduced = hinged(lifted_basis)
    s_full.solve_static(load_steps=2)
    s_red.solve_static(load_steps=2)
    u_full = full.u.x.array[: ndofs(full)]
    assert np.abs(u_full).max() > 0.02
    assert np.abs(reduced.nodal_displacement() - u_full).max() < 1e-8 * np.abs(u_full).max()
    assert np.abs(b_red.rotation - b_full.rotation).max() < 1e-8


def test_static_load_steps_chosen_by_the_solver_on_a_hinged_bone():
    """load_steps="auto" (integrators.ramp_load) on the coupled island, full and reduced
    body, with a joint (exact-penalty merit): the equilibrium of two fixed steps."""
    for basis in (None, lifted_basis):
        fixed, _, b_fixed, _ = hinged(basis)
        auto, _, b_auto, _ = hinged(basis)
        fixed.solve_static(load_steps=2)
        counts = auto.solve_static(load_steps="auto")
        assert 1 <= len(counts) <= 4 and max(counts) <= 10, counts
        for a, b in zip(auto.bodies, fixed.bodies):
            for x, y in zip(a.state(), b.state()):
                assert np.abs(x - y).max() <= 1e-8 * max(np.abs(y).max(), 1e-3)
        assert np.abs(b_auto.rotation - b_fixed.rotation).max() < 1e-8


def test_static_tangent_with_a_lift_matches_finite_differences():
    """-dF_m/dq_m = P^T K P - K_geo with the lift's levers (the columns of R and the bone's
    offset from its root). Measured: 4e-10 / 6e-9 of |K dq| (all masters / a rotation);
    without K_geo 6e-3 / 0.2."""
    rng = np.random.default_rng(0)
    scene, _, b, reduced = hinged(lambda body, lift: lifted_basis(body, lift, 8), (0.0, 0.0))
    scene.joints.clear()  # a free bone: all six directions
    scene.check()
    reduced.set_q(reduced.q + np.r_[0.02 * rng.standard_normal(8), np.zeros(12)])
    n = scene.master_count()
    assert n == 8 + 6
    K = scene.static_tangent()
    scene.geometric_stiffness = False
    K_without = scene.static_tangent()
    scene.geometric_stiffness = True
    for part in ("reduced", "rotation"):
        dq = 1e-2 * rng.standard_normal(n)
        if part == "rotation":
            dq[:-3] = 0.0
        eps = 1e-5
        fd = master_force_difference(scene, dq, eps)
        error = np.abs(fd + K @ dq).max()
        assert error < 1e-6 * np.abs(K @ dq).max()
        if part == "rotation":
            assert np.abs(fd + K_without @ dq).max() > 1e3 * error
    h1, h2 = 1e-2, 2e-2
    K_step = (scene.step_matrix(h2) - scene.step_matrix(h1)) / (h2**2 - h1**2)
    assert abs(K_step - K).max() < 1e-9 * abs(K).max()


def point_evaluation(function, X) -> np.ndarray:
    """function(X) (3,) by DOLFINx's own point evaluation (bounding-box tree, colliding
    cell, Function.eval): a reference that uses neither FemPoint's weights nor its G."""
    from dolfinx import geometry

    msh = function.function_space.mesh
    X = np.asarray(X, dtype=float).reshape(1, 3)
    tree = geometry.bb_tree(msh, msh.topology.dim)
    cells = geometry.compute_colliding_cells(msh, geometry.compute_collisions_points(tree, X), X)
    return function.eval(X, np.array([cells.links(0)[0]], dtype=np.int32)).reshape(3)


def test_spring_on_a_reduced_point_matches_the_full_scene_and_does_virtual_work():
    anchor = np.array([1.3, 0.5, 0.4])

    def scene_for(reduced: bool):
        body = make_body()
        scene = Scene(gravity=(0, 0, -G))
        X = np.array([0.8, 0.15, 0.2])
        w = shape_function_weights(body, X)
        if reduced:
            free = np.setdiff1d(
                np.arange(ndofs(body)), (3 * body.fixed_dofs[:, None] + np.arange(3)).ravel()
            )
            U = np.zeros((ndofs(body), free.size))
            U[free, np.arange(free.size)] = 1.0
            target = ReducedFemBody(body, U, all_points(body))
        else:
            target = body
        point = FemPoint(target, w)
        scene.add(target, PointPath(AxialSpring(400.0, 0.1), [anchor, point]))
        return scene, body, target, point

    s_full, full, _, _ = scene_for(False)
    s_red, _, reduced, point = scene_for(True)
    s_full.solve_static(load_steps=2)
    s_red.solve_static(load_steps=2)
    u_full = full.u.x.array[: ndofs(full)]
    assert np.abs(reduced.nodal_displacement() - u_full).max() < 1e-8 * np.abs(u_full).max()
    # G is the derivative of the point's position: a central difference along qdot of
    # X + u_h(X), u_h the full body's displacement u_bar + U q evaluated by DOLFINx (no
    # weights, no G); the map is linear in q, so it is exact to round-off (measured 1e-12)
    qdot = np.random.default_rng(1).standard_normal(reduced.r)
    reduced.qdot = qdot
    q0, X = reduced.q.copy(), np.array([0.8, 0.15, 0.2])
    x = []
    for sign in (1.0, -1.0):
        reduced.set_q(q0 + sign * 1e-4 * qdot)
        reduced.to_full()
        x.append(X + point_evaluation(reduced.full.u, X))
    reduced.set_q(q0)
    v_fd = (x[0] - x[1]) / 2e-4
    assert np.linalg.norm(v_fd) > 0.1  # the point moves with these modes
    np.testing.assert_allclose(point.velocity(), v_fd, rtol=0, atol=1e-9 * np.linalg.norm(v_fd))
    # virtual work: the generalized force G^T f does the work of f on that motion
    f = np.array([0.3, -1.0, 2.0])
    assert (point.G.T @ f) @ qdot == pytest.approx(f @ v_fd, rel=1e-9)


def test_bad_lift_attachments_are_clear_errors():
    body = make_body()
    b = bone()
    lift = rigid_lift(body, end_nodes(body), b.position, b.rotation)
    wrong = ReducedFemBody(body, lifted_basis(body, lift, 4)[:, :4], all_points(body))
    with pytest.raises(ValueError, match="does not contain the lift"):
        LiftAttachment(wrong, lift, b)
    n = lift.columns.shape[0]
    short = dataclasses.replace(lift, columns=lift.columns[:-3])  # another body's lift
    with pytest.raises(ValueError, match=f"the lift has {n - 3} rows, the basis {n}"):
        LiftAttachment(
            ReducedFemBody(body, lifted_basis(body, lift, 4), all_points(body)), short, b
        )
    U = lifted_basis(body, lift, 4)
    U[3 * lift.dofs[0], 0] = 1.0  # a column moving a carried node
    with pytest.raises(ValueError, match="would not follow the body"):
        LiftAttachment(ReducedFemBody(body, U, all_points(body)), lift, b)
    with pytest.raises(ValueError, match="fixed"):
        rigid_lift(body, body.find_nodes(lambda x: x[0] < 1e-12), b.position, b.rotation)
    with pytest.raises(ValueError, match="also held by another rigid body"):
        rigid_lift(body, end_nodes(body), b.position, b.rotation, held=end_nodes(body)[:2])
    for pose in (1.1 * b.rotation, b.rotation @ np.diag([1.0, 1.0, -1.0])):  # scaled, mirrored
        with pytest.raises(ValueError, match="not a proper rotation"):
            rigid_lift(body, end_nodes(body), b.position, pose)
    reduced = ReducedFemBody(body, lifted_basis(body, lift, 4), all_points(body))
    scene = Scene()
    scene.add(reduced, LiftAttachment(reduced, lift, b))
    with pytest.raises(ValueError, match="not in the scene"):
        scene.check()
