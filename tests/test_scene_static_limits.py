"""Statics honours joint limits (the constraint protocol's bounded rows in the static
Newton, artifem.scene.scene docstring: statics).

(1) A rod hinged at the world, held down by gravity and a spring to a point below the
    pivot: free, it hangs straight down; with an angle limit that this equilibrium
    would cross it rests on the limit, whose multiplier (>= 0) balances the restoring
    moment s (m g d + k l a) (analytic: pivot 0, tip at l, spring anchor at depth a).
(2) A block on a vertical slider hung from a spring: free at z = z_a - m g / k; an
    upper distance limit below that holds it with the multiplier k (z_a - z) - m g.
(3) Pendulums under gravity alone, on a hinge or a ball joint: they hang straight down.
    Gravity resists their swing only through the joint's reaction turning with them,
    and a ball-jointed rod's spin about its own axis is resisted by nothing and worked
    on by nothing (neutral).
"""

import numpy as np
import pytest

import artifem as af  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.multibody.frame_paths import FramePath
from artifem.multibody.joints import axis_rotation
from artifem.multibody.muscles import AxialSpring
from artifem.multibody.rigid_body import Frame

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled islands are serial")

G = 9.81
M, LENGTH, K_SPRING, ANCHOR = 1.0, 1.0, 20.0, 2.0


def sprung_rod(theta0=0.6, limits=None):
    """A rod of length 1 hinged at the origin about y, started theta0 from hanging, its tip
    pulled by a zero-length spring toward (0, 0, -ANCHOR)."""
    c, s = np.cos(theta0), np.sin(theta0)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    rod = af.RigidBody(
        "rod",
        M,
        M * LENGTH**2 / 12 * np.diag([1.0, 1.0, 0.01]),
        position=R @ (0.0, 0.0, -0.5 * LENGTH),
        rotation=R,
    )
    hinge = af.RevoluteJoint.at_world(
        rod, None, (0.0, 0.0, 0.0), axis_rotation((0, 1, 0)), name="hinge", limits=limits
    )
    spring = FramePath(
        AxialSpring(K_SPRING),
        [Frame(rod, (0.0, 0.0, -0.5 * LENGTH)), Frame(None, (0.0, 0.0, -ANCHOR))],
        name="spring",
    )
    scene = af.Scene(gravity=(0, 0, -G))
    scene.add(rod, hinge, spring)
    return scene, rod, hinge


def kkt_multipliers(scene, touching):
    """The constraint forces at the static solution: lambda of F_m + G_a^T lambda = 0 on
    the bilateral rows and the bounded rows with phi = 0 (``touching``), by least squares;
    (lambda of the touching bounded rows, |F_m + G_a^T lambda| / |F_m|)."""
    L = scene._ready()
    F = scene.master_forces()
    rows = L.constraint_map.rows(L.prolongation(), np.zeros(L.n_all), 1.0, 1.0)
    G = np.vstack([g.G for g in rows])
    bounded = np.concatenate([g.block.bounded for g in rows])
    phi = np.concatenate([g.block.phi for g in rows])
    on_limit = bounded & (np.abs(phi) < 1e-9)
    assert on_limit.sum() == touching
    active = ~bounded | on_limit
    lam = np.linalg.lstsq(G[active].T, -F, rcond=None)[0]
    return lam[on_limit[active]], np.linalg.norm(F + G[active].T @ lam) / np.linalg.norm(F)


@pytest.mark.parametrize("joint", ["hinge", "ball"])
def test_a_pendulum_under_gravity_alone_hangs_straight_down(joint):
    """(3): from 0.6 rad off, the rod's centre of mass comes to (0, 0, -l/2) and its axis
    to the vertical; on the ball joint its spin about that axis keeps the start's. Newton
    converges quadratically (4 iterations, measured, both): the tangent takes the joint
    reactions' turning with the forces that balance the load. Without it both failed
    (a singular tangent), and with it only where that is singular the hinge converged
    linearly (0.4 per iteration: 30 iterations at the full load, cut, then 27)."""
    scene, rod, _ = sprung_rod()
    scene.remove(*[p for p in scene.paths])  # gravity alone
    if joint == "ball":
        scene.remove(*scene.constraints)
        scene.add(af.SphericalJoint.at_world(rod, None, (0.0, 0.0, 0.0), name="ball"))
    counts = scene.solve_static()
    np.testing.assert_allclose(rod.position, [0.0, 0.0, -0.5 * LENGTH], atol=1e-10)
    np.testing.assert_allclose(rod.rotation[:, 2], [0.0, 0.0, 1.0], atol=1e-10)
    np.testing.assert_allclose(rod.rotation, np.eye(3), atol=1e-10)  # no spin either way
    assert max(counts) <= 6


def test_free_hinged_rod_hangs_straight_down():
    scene, rod, hinge = sprung_rod()
    scene.solve_static()
    np.testing.assert_allclose(rod.position, [0.0, 0.0, -0.5 * LENGTH], atol=1e-10)
    assert abs(hinge.angle()) == pytest.approx(0.6, abs=1e-10)


@pytest.mark.parametrize("limit", [0.3, 0.45])
def test_static_rod_rests_on_the_angle_limit_it_would_cross(limit):
    scene, rod, hinge = sprung_rod(limits=(-limit, limit))
    scene.solve_static()
    assert abs(hinge.angle()) == pytest.approx(limit, abs=1e-10)  # on the limit
    deflection = 0.6 - limit  # from hanging
    tip = rod.position + rod.rotation @ (0.0, 0.0, -0.5 * LENGTH)
    assert np.hypot(tip[0], tip[1]) == pytest.approx(LENGTH * np.sin(deflection), abs=1e-10)
    lam, residual = kkt_multipliers(scene, touching=1)
    moment = np.sin(deflection) * (M * G * 0.5 * LENGTH + K_SPRING * LENGTH * ANCHOR)
    assert lam[0] >= 0.0
    assert lam[0] == pytest.approx(moment, rel=1e-9)
    assert residual < 1e-10


def test_a_limit_the_equilibrium_does_not_reach_changes_nothing():
    scene, rod, hinge = sprung_rod(limits=(-1.0, 1.0))
    scene.solve_static()
    np.testing.assert_allclose(rod.position, [0.0, 0.0, -0.5 * LENGTH], atol=1e-10)
    kkt_multipliers(scene, touching=0)


@pytest.mark.parametrize(
    "limits, z", [(None, ANCHOR - 2.0 * G / 50.0), ((-1.0, 0.4), 1.4), ((0.9, 2.0), 1.9)]
)
def test_static_slider_rests_on_its_distance_limit(limits, z):
    """A 2 kg block on a vertical slider through (0, 0, 1), hung from a spring (k = 50)
    anchored at z = 2: free at 2 - m g / k = 1.608; the upper limit 0.4 holds it at 1.4
    (the limit pushes down by k 0.6 - m g), the lower limit 0.9 at 1.9 (pushes up by
    m g - k 0.1)."""
    block = af.RigidBody("block", 2.0, 0.1 * np.eye(3), position=(0.0, 0.0, 1.0))
    slider = af.SliderJoint.at_world(block, None, (0.0, 0.0, 1.0), limits=limits)
    spring = FramePath(AxialSpring(50.0), [Frame(block), Frame(None, (0.0, 0.0, ANCHOR))])
    scene = af.Scene(gravity=(0, 0, -G))
    scene.add(block, slider, spring)
    scene.solve_static()
    assert block.position[2] == pytest.approx(z, abs=1e-10)
    if limits is not None:
        lam, residual = kkt_multipliers(scene, touching=1)
        assert lam[0] >= 0.0
        assert lam[0] == pytest.approx(abs(50.0 * (ANCHOR - z) - 2.0 * G), rel=1e-9)
        assert residual < 1e-10
