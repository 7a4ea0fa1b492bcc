"""Springs and Hill muscles between rigid bodies: statics, oscillation, activation."""

import numpy as np
import pytest

from artifem.errors import SingularSystem
from artifem.multibody.frame_paths import FramePath
from artifem.multibody.joints import SliderJoint
from artifem.multibody.muscles import AxialSpring, ThelenMuscle, ThelenParameters
from artifem.multibody.rigid_body import Frame, RigidBody, exp_so3
from artifem.scene import Scene
from periods import zero_crossing_period

G = 9.81


def hanging(mass=2.0, z=-0.5):
    body = RigidBody("weight", mass, np.eye(3) * 1e-3, position=(0.0, 0.0, z))
    return body, Frame(None, np.zeros(3)), Frame(body, np.zeros(3))


def test_a_mass_on_a_spring_oscillates_at_its_natural_frequency():
    """T = 2 pi sqrt(m / k): measured 6.7e-5 off at h = 1 ms (2.7e-6 at 0.2 ms: the
    O(h^2) of the step and of the crossings' interpolation); the bound 5e-4."""
    body, top, bottom = hanging(z=-0.6)
    k, L0, m = 400.0, 0.5, 2.0
    system = Scene(gravity=(0.0, 0.0, 0.0))
    system.add(body, FramePath(AxialSpring(k, L0), [top, bottom], name="spring"))
    h, t, z = 1e-3, [], []
    for _ in range(int(round(1.5 / h))):
        system.step(h)
        t.append(system.t)
        z.append(body.position[2] + L0)  # oscillation about -L0
    period = zero_crossing_period(t, z)
    assert period == pytest.approx(2 * np.pi * np.sqrt(m / k), rel=5e-4)
    assert abs(body.position[0]) + abs(body.position[1]) < 1e-12  # stays on the line


def test_a_hanging_weight_settles_where_the_muscle_holds_it():
    params = ThelenParameters(
        max_isometric_force=100.0, optimal_fiber_length=0.1, tendon_slack_length=0.2
    )
    muscle = ThelenMuscle(params, excitation=0.5)
    body, top, bottom = hanging(mass=3.0, z=-0.31)
    body.velocity[:] = 0.0
    path = FramePath(muscle, [top, bottom], excitation=lambda t: 0.5, name="hill")
    system = Scene(gravity=(0.0, 0.0, -G))
    system.add(body, path)
    for _ in range(3000):
        system.step(1e-3)
    assert np.linalg.norm(body.velocity) < 1e-4  # at rest
    assert path.tension() == pytest.approx(3.0 * G, rel=1e-3)  # holds the weight
    assert muscle.activation == pytest.approx(0.5, abs=1e-6)  # activation settled


def test_stiffer_activation_lifts_the_weight():
    """Either way the muscle holds the weight (tension m g); at 0.8 the weight is at rest
    after 3 s, at 0.3 it still creeps up at 2.4 mm/s: near the top of the force-length
    curve the muscle is nearly as strong over a range of lengths (measured: at rest at
    -0.232918 m; -0.304185 m at 3 s). The heights are pinned to those runs to 1e-5 m."""
    params = ThelenParameters(
        max_isometric_force=100.0, optimal_fiber_length=0.1, tendon_slack_length=0.2
    )
    heights, speeds = [], []
    for level in (0.3, 0.8):
        body, top, bottom = hanging(mass=3.0, z=-0.31)
        system = Scene(gravity=(0.0, 0.0, -G))
        path = FramePath(ThelenMuscle(params), [top, bottom], excitation=lambda t, u=level: u)
        system.add(body, path)
        for _ in range(3000):
            system.step(1e-3)
        assert path.tension() == pytest.approx(3.0 * G, rel=1e-3)  # holding the weight
        heights.append(body.position[2])
        speeds.append(np.linalg.norm(body.velocity))
    assert speeds[1] < 1e-4 and speeds[0] == pytest.approx(2.4e-3, rel=0.05)
    assert heights == pytest.approx([-0.304185, -0.232918], abs=1e-5)


def test_bad_paths_are_clear_errors():
    body, top, bottom = hanging()
    with pytest.raises(ValueError, match="at least two frames"):
        FramePath(AxialSpring(1.0), [top])
    with pytest.raises(ValueError, match="takes no excitation"):
        FramePath(AxialSpring(1.0), [top, bottom], excitation=lambda t: 1.0)


def guided(body):
    """A vertical slider that holds the body's turns (statics has no inertia for them)."""
    return SliderJoint(
        Frame.at_world(body, body.position, np.eye(3)),
        Frame.at_world(None, body.position, np.eye(3)),
        name="guide",
    )


def test_the_static_solve_holds_the_weight_on_the_muscle():
    """Statics through a FramePath muscle (its energy the merit): the tension at the length
    found is the weight."""
    params = ThelenParameters(
        max_isometric_force=100.0, optimal_fiber_length=0.1, tendon_slack_length=0.2
    )
    muscle = ThelenMuscle(params, excitation=0.5, activation_dynamics=False)
    # on the ascending limb of f_L (l_M = 0.6 l0), where the tension rises with the length
    body, top, bottom = hanging(mass=3.0, z=-0.26)
    path = FramePath(muscle, [top, bottom], name="hill")
    system = Scene(gravity=(0.0, 0.0, -G))
    system.add(body, path, guided(body))
    system.solve_static()
    assert muscle.tension(-body.position[2])[0] == pytest.approx(3.0 * G, rel=1e-9)
    assert path.conservative


def test_a_static_solve_names_the_motions_nothing_resists_that_the_loads_push():
    """A weight on a vertical slider with nothing to hold it up, and a free body: statics
    has no equilibrium, and says which motion of which body is left to the loads, at the
    first load increment and its one cut (the tangent does not depend on the load there),
    not after 12 cuts."""
    body, *_ = hanging(mass=3.0, z=-0.6)
    system = Scene(gravity=(0.0, 0.0, -G))
    system.add(body, guided(body))
    with pytest.raises(SingularSystem) as failed:
        system.solve_static()
    message = str(failed.value)
    assert "a smaller load increment does not change that" in message
    assert "nothing resists 'weight' translating along (0, 0, 1):" in message
    assert "the loads push that way, so there is no static equilibrium" in message
    free = RigidBody("free", 1.0, np.eye(3) * 1e-3)
    system = Scene(gravity=(0.0, 0.0, -G))
    system.add(free)
    with pytest.raises(
        SingularSystem, match="'free' translating along any axis and rotating about any axis"
    ):
        system.solve_static()


def test_a_weight_hung_by_its_centre_of_mass_keeps_its_orientation_in_statics():
    """Nothing resists its turns and nothing works on them (neutral motions): statics keeps
    the orientation it has and finds the height, z = -(L0 + m g / k)."""
    body, top, bottom = hanging(mass=3.0, z=-0.6)
    body.rotation = exp_so3((0.3, 0.2, -0.1))
    start = body.rotation.copy()
    system = Scene(gravity=(0.0, 0.0, -G))
    system.add(body, FramePath(AxialSpring(400.0, 0.5), [top, bottom], name="spring"))
    system.solve_static()
    assert body.position == pytest.approx([0.0, 0.0, -(0.5 + 3.0 * G / 400.0)], abs=1e-12)
    np.testing.assert_allclose(body.rotation, start, atol=1e-12)


class ConstantForce:
    """A load element: a constant force on a rigid body's centre of mass, with its
    potential -f . p."""

    def __init__(self, body, force):
        self.body, self.force, self.name = body, np.asarray(force, dtype=float), "push"

    @property
    def bodies(self):
        return (self.body,)

    def master_loads(self, t):
        return [(self.body, np.concatenate([self.force, np.zeros(3)]))]

    def potential_energy(self, t):
        return -float(self.force @ self.body.position)


class Tether(ConstantForce):
    """A load element pulling a body's centre of mass to the origin, f = -k p, with its
    Jacobian df/dp = -k 1 as a block over the body's 3 translations only (``narrow``) or
    padded to its 6 coordinates."""

    def __init__(self, body, k, narrow):
        super().__init__(body, np.zeros(3))
        self.k, self.narrow = k, narrow

    def master_loads(self, t):
        return [(self.body, np.concatenate([-self.k * self.body.position, np.zeros(3)]))]

    def master_load_jacobians(self, t):
        K = -self.k * np.eye(3 if self.narrow else 6)
        if not self.narrow:
            K[3:, 3:] = 0.0
        return [(self.body, self.body, K)]


def test_a_load_jacobian_block_may_cover_a_bodys_first_coordinates_only():
    """A load's Jacobian block (the static tangent's) narrower than its body's coordinates
    is placed on the first ones: statics finds the tether's equilibrium p = -m g / k either
    way, in one Newton iteration (the load is linear), the turns kept (neutral)."""
    k = 200.0
    for narrow in (True, False):
        body, *_ = hanging(mass=1.0, z=-0.5)
        system = Scene(gravity=(0.0, 0.0, -G))
        system.add(body, Tether(body, k, narrow))
        assert system.solve_static() == [1]
        np.testing.assert_allclose(body.position, [0.0, 0.0, -G / k], rtol=0.0, atol=1e-14)
        np.testing.assert_allclose(body.rotation, np.eye(3), rtol=0.0, atol=1e-14)


def test_a_load_elements_potential_enters_the_scenes_energy_and_its_statics():
    """Scene.potential_energy takes a load element's potential (times the load factor), so
    statics keeps the energy as its merit: a spring stretched by a constant force rests at
    f / k beyond its rest length."""
    body, top, bottom = hanging(mass=1.0, z=-0.6)
    k, L0, f = 400.0, 0.5, np.array([0.0, 0.0, -30.0])
    system = Scene(gravity=(0.0, 0.0, 0.0))
    system.add(
        body,
        FramePath(AxialSpring(k, L0), [top, bottom], name="spring"),
        ConstantForce(body, f),
        guided(body),
    )
    e0 = system.potential_energy()
    body.position = body.position + np.array([0.0, 0.0, -1e-3])
    spring = 0.5 * k * ((0.601 - L0) ** 2 - (0.6 - L0) ** 2)
    assert system.potential_energy() - e0 == pytest.approx(spring - 30.0 * 1e-3, rel=1e-9)
    system.solve_static()
    assert body.position[2] == pytest.approx(-(L0 + 30.0 / k), rel=1e-10)
