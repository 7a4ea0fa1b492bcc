"""The implicit coupled step's Jacobian is the derivative of its residual as formed
(artifem.scene.implicit_step.NewtonSystem), hence Newton converges quadratically.

(1) Finite differences of the equations Newton solves, [r - G_m^T lambda; phi / h] at a
    trial z_m and impulses lambda, against the Jacobian and the constraint rows: an FEM
    beam carried by a spinning rigid body (NodeAttachment), a loaded hinged rod
    (RevoluteJoint: the rows turn with the rod), the rod pressed on a joint limit, and
    the joint rows' stiffness of every joint type against finite differences of G^T lambda.
(2) Newton's merits fall quadratically (merit_{k+1} <= C merit_k^2 once close) with a
    loaded hinge and with an active limit, in at most 3 iterations per step.
"""

import numpy as np
import pytest

import artifem as af  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.multibody.joints import axis_rotation
from artifem.multibody.rigid_body import exp_so3
from coupled_fd import _dense, implicit_jacobian_check

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled islands are serial")

G = 9.81
H = 0.01


def carried_beam():
    """A soft beam whose end nodes ride on a spinning, translating rigid body."""
    body = af.RigidBody(
        "carrier",
        2.0,
        0.02 * np.diag([1.0, 2.0, 1.5]),
        position=(0.0, 0.1, 0.1),
        velocity=(0.1, 0.0, 0.0),
        angular_velocity=(0.5, 1.5, -0.7),
    )
    box = dmesh.create_box(
        MPI.COMM_SELF,
        [np.zeros(3), np.array([1.0, 0.2, 0.2])],
        [4, 1, 1],
        dmesh.CellType.hexahedron,
    )
    beam = af.FemBody(
        box, af.NeoHookean.from_young_poisson(1e5, 0.3), 1000.0, rayleigh=(0.3, 0.0), name="beam"
    )
    carried = af.NodeAttachment(beam, beam.find_nodes(lambda x: x[0] < 1e-12), body)
    scene = af.Scene(gravity=(0, 0, -G), integrator="implicit")
    scene.add(body, beam, carried)
    return scene


def hinged_rod(theta0=0.6, limits=None, spin=(0.0, 0.0, 0.0)):
    """A rod hinged at the world origin about y, under gravity (a loaded joint)."""
    c, s = np.cos(theta0), np.sin(theta0)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    rod = af.RigidBody(
        "rod",
        1.0,
        np.diag([1.0, 1.0, 0.01]) / 12,
        position=R @ (0.0, 0.0, -0.5),
        rotation=R,
        angular_velocity=spin,
    )
    hinge = af.RevoluteJoint.at_world(
        rod, None, (0.0, 0.0, 0.0), axis_rotation((0, 1, 0)), name="hinge", limits=limits
    )
    scene = af.Scene(gravity=(0, 0, -G), integrator="implicit")
    scene.add(rod, hinge)
    return scene, rod, hinge


def last_impulses(scene):
    return np.concatenate([lam for parts in scene._impulses.values() for _, lam in parts])


def check(scene, z_m, lam):
    FD, Jac = implicit_jacobian_check(scene, H, z_m, lam)
    n = z_m.size
    layout = scene._ready()
    M = _dense(layout.prolongation().T @ layout.mass_matrix() @ layout.prolongation())
    scale = np.abs(FD[:n] - M).max()  # the configuration-dependent part
    assert scale > 0
    assert np.abs(FD[:n] - Jac[:n]).max() <= 1e-5 * scale
    if FD.shape[0] > n:
        assert np.abs(FD[n:] - Jac[n:]).max() <= 1e-7 * np.abs(FD[n:]).max()


def test_jacobian_of_a_beam_carried_by_a_spinning_body_is_the_residual_derivative(rng):
    scene = carried_beam()
    scene.step(H)
    layout = scene._ready()
    z = layout.current_velocities()[layout.master_rows]
    check(scene, z + 0.05 * rng.standard_normal(z.size), np.zeros(0))


def test_jacobian_of_a_loaded_hinge_is_the_residual_derivative(rng):
    scene, _, _ = hinged_rod(spin=(0.3, 2.0, -0.2))
    for _ in range(3):
        scene.step(H)
    layout = scene._ready()
    z = layout.current_velocities()[layout.master_rows]
    lam = last_impulses(scene)
    assert np.abs(lam).max() > 1e-3 * H  # the hinge carries the rod
    check(
        scene, z + 0.1 * rng.standard_normal(z.size), lam + 0.1 * H * rng.standard_normal(lam.size)
    )


def pressed_on_its_limit():
    """The rod falls onto the hinge's upper limit (the angle grows as it swings down) and
    rests pressed on it."""
    scene, rod, hinge = hinged_rod(theta0=0.6, limits=(-1.0, 0.0))
    angle0 = hinge.angle()
    scene, rod, hinge = (
        hinged_rod(theta0=0.6, limits=(angle0 - 0.2, angle0 + 0.05))
        if angle0 < 0
        else hinged_rod(theta0=0.6, limits=(angle0 - 0.05, angle0 + 0.2))
    )
    return scene, hinge


def test_jacobian_with_an_active_joint_limit_is_the_residual_derivative(rng):
    scene, hinge = pressed_on_its_limit()
    for _ in range(20):
        scene.step(H)
    lam = last_impulses(scene)
    assert np.abs(lam[-2:]).max() > 1e-3 * H  # the limit pushes
    layout = scene._ready()
    z = layout.current_velocities()[layout.master_rows]
    check(scene, z + 0.1 * rng.standard_normal(z.size), lam)


@pytest.mark.parametrize("kind", ["revolute", "slider", "fixed", "spherical", "planar"])
@pytest.mark.parametrize("on_world", [False, True])
def test_joint_rows_stiffness_is_the_derivative_of_their_wrenches(rng, kind, on_world):
    cls = {
        "revolute": af.RevoluteJoint,
        "slider": af.SliderJoint,
        "fixed": af.FixedJoint,
        "spherical": af.SphericalJoint,
        "planar": af.PlanarJoint,
    }[kind]
    limits = {"limits": (-1.0, 1.0)} if kind in ("revolute", "slider") else {}
    a = af.RigidBody(
        "a",
        1.0,
        np.eye(3),
        position=rng.standard_normal(3),
        rotation=exp_so3(rng.standard_normal(3)),
    )
    b = (
        None
        if on_world
        else af.RigidBody(
            "b",
            1.0,
            np.eye(3),
            position=rng.standard_normal(3),
            rotation=exp_so3(rng.standard_normal(3)),
        )
    )
    joint = cls.at_world(a, b, rng.standard_normal(3), exp_so3(rng.standard_normal(3)), **limits)
    for body in (a, b):  # off the joint: phi != 0
        if body is not None:
            body.position = body.position + 0.1 * rng.standard_normal(3)
            body.rotation = exp_so3(0.2 * rng.standard_normal(3)) @ body.rotation
    blocks = joint.row_blocks()  # bilateral rows, then the limits
    assert [x.bounded.all() for x in blocks] == ([False, True] if limits else [False])
    for k, block in enumerate(blocks):
        lam = rng.standard_normal(len(block))

        def wrench():
            return np.concatenate([G.T @ lam for _, G in joint.row_blocks()[k].jacobians])

        FD, eps = np.zeros((12, 12)), 1e-6
        for col in range(12 if b is not None else 6):
            body = a if col < 6 else b
            p, R = body.position.copy(), body.rotation.copy()
            out = []
            for sign in (1.0, -1.0):
                d = np.zeros(6)
                d[col % 6] = sign * eps
                body.position, body.rotation = p + d[:3], exp_so3(d[3:]) @ R
                out.append(wrench())
            body.position, body.rotation = p, R
            FD[:, col] = (out[0] - out[1]) / (2 * eps)
        if b is None:
            FD[6:] = 0.0
        assert np.abs(FD - block.stiffness(lam)).max() <= 1e-7 * np.abs(FD).max()


def quadratic(merits, C=100.0, floor=1e-12):
    """merit_{k+1} <= C merit_k^2 wherever merit_k < 1e-2 and merit_{k+1} is above round-off."""
    for m0, m1 in zip(merits[:-1], merits[1:]):
        if m0 < 1e-2 and m1 > floor:
            assert m1 <= C * m0 * m0, merits


def test_newton_converges_quadratically_with_a_loaded_hinge():
    scene, _, _ = hinged_rod(spin=(0.0, 1.0, 0.0))
    for _ in range(10):
        scene.step(H)
        merits = scene.last_solve["merits"]
        assert len(merits) - 1 <= 3, merits
        quadratic(merits)
        assert scene.constraint_errors()["hinge"] < 1e-9


def test_newton_converges_quadratically_on_an_active_limit():
    scene, hinge = pressed_on_its_limit()
    pressed = 0
    for _ in range(25):
        scene.step(H)
        merits = scene.last_solve["merits"]
        assert len(merits) - 1 <= 3, merits
        quadratic(merits)
        pressed += bool(np.abs(last_impulses(scene)[-2:]).max() > 1e-3 * H)
    assert pressed >= 5
    lower, upper = hinge.limits
    assert lower - 1e-8 <= hinge.angle() <= upper + 1e-8
