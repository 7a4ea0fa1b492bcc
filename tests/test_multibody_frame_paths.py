"""Springs and Hill muscles between rigid bodies: statics, oscillation, activation."""

import numpy as np
import pytest

from artifem.multibody.frame_paths import FramePath
from artifem.multibody.muscles import AxialSpring, ThelenMuscle, ThelenParameters
from artifem.multibody.rigid_body import Frame, RigidBody
from artifem.scene import Scene

G = 9.81


def hanging(mass=2.0, z=-0.5):
    body = RigidBody("weight", mass, np.eye(3) * 1e-3, position=(0.0, 0.0, z))
    return body, Frame(None, np.zeros(3)), Frame(body, np.zeros(3))


def test_a_mass_on_a_spring_oscillates_at_its_natural_frequency():
    body, top, bottom = hanging(z=-0.6)
    k, L0, m = 400.0, 0.5, 2.0
    system = Scene(gravity=(0.0, 0.0, 0.0))
    system.add(body, FramePath(AxialSpring(k, L0), [top, bottom], name="spring"))
    h, z = 1e-4, []
    for _ in range(int(1.5 / h)):
        system.step(h)
        z.append(body.position[2])
    z = np.array(z) + L0                                  # oscillation about -L0
    crossings = np.flatnonzero(np.diff(np.sign(z)) > 0) * h
    period = np.mean(np.diff(crossings))
    assert period == pytest.approx(2 * np.pi * np.sqrt(m / k), rel=2e-3)
    assert abs(body.position[0]) + abs(body.position[1]) < 1e-12      # stays on the line


def test_a_hanging_weight_settles_where_the_muscle_holds_it():
    params = ThelenParameters(max_isometric_force=100.0, optimal_fiber_length=0.1,
                              tendon_slack_length=0.2)
    muscle = ThelenMuscle(params, excitation=0.5)
    body, top, bottom = hanging(mass=3.0, z=-0.31)
    body.velocity[:] = 0.0
    path = FramePath(muscle, [top, bottom], excitation=lambda t: 0.5, name="hill")
    system = Scene(gravity=(0.0, 0.0, -G))
    system.add(body, path)
    for _ in range(3000):
        system.step(1e-3)
    assert np.linalg.norm(body.velocity) < 1e-4                         # at rest
    assert path.tension() == pytest.approx(3.0 * G, rel=1e-3)          # holds the weight
    assert muscle.activation == pytest.approx(0.5, abs=1e-6)           # activation settled


def test_stiffer_activation_lifts_the_weight():
    params = ThelenParameters(max_isometric_force=100.0, optimal_fiber_length=0.1,
                              tendon_slack_length=0.2)
    heights = []
    for level in (0.3, 0.8):
        body, top, bottom = hanging(mass=3.0, z=-0.31)
        system = Scene(gravity=(0.0, 0.0, -G))
        system.add(body, FramePath(ThelenMuscle(params), [top, bottom],
                                   excitation=lambda t, u=level: u))
        for _ in range(3000):
            system.step(1e-3)
        heights.append(body.position[2])
    assert heights[1] > heights[0] + 1e-3


def test_bad_paths_are_clear_errors():
    body, top, bottom = hanging()
    with pytest.raises(ValueError, match="at least two frames"):
        FramePath(AxialSpring(1.0), [top])
    with pytest.raises(ValueError, match="takes no excitation"):
        FramePath(AxialSpring(1.0), [top, bottom], excitation=lambda t: 1.0)
