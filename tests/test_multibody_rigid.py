"""Rigid bodies, joints and the constrained semi-implicit step (artifem.multibody).

(a) mass properties from closed surfaces against analytic box and sphere
    values (translated, rotated, hollow); open / inverted surfaces are errors;
(b) pendulum periods: simple (spherical joint) and compound (revolute);
(c) an undamped double pendulum keeps its energy over 2.5 s: with constant
    gravity and no force Jacobians the step is symplectic Euler, so the energy
    error oscillates with an O(h) amplitude and does not drift;
(d) joints: G matches a finite difference of phi for every joint type and
    limit, drift stays bounded, and G u+ = -beta phi / h after a step;
(e) a free body: rotations stay orthonormal, momentum is conserved (torque-free
    precession), energy never grows;
(f) prescribed bodies, joint limits, force elements with stiffness Jacobians;
(g) bad input.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.multibody.joints import (
    FixedJoint,
    PlanarJoint,
    RevoluteJoint,
    SliderJoint,
    SphericalJoint,
    axis_rotation,
)
from artifem.multibody.rigid_body import BodyState, Frame, MassProperties, RigidBody, exp_so3
from artifem.errors import StepFailed
from artifem.multibody.attachments import RigidAttachment
from artifem.multibody.force_elements import point_force_wrenches
from artifem.scene import Scene
from periods import zero_crossing_period

G = 9.81
GRAVITY = (0.0, 0.0, -G)
#: A rotation taking z to the world y axis: hinges about y swing in the xz plane.
HINGE_Y = axis_rotation((0.0, 1.0, 0.0))
JOINTS = [FixedJoint, SphericalJoint, RevoluteJoint, SliderJoint, PlanarJoint]
ROWS = {FixedJoint: 6, SphericalJoint: 3, RevoluteJoint: 5, SliderJoint: 5, PlanarJoint: 3}


# ---- helpers -------------------------------------------------------------------------------


def box_surface(size, center=(0.0, 0.0, 0.0)):
    """The 8 corners and 12 outward triangles of an axis-aligned box."""
    size, center = np.asarray(size, float), np.asarray(center, float)
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    vertices = center + (corners - 0.5) * size
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    triangles = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return vertices, np.array(triangles)


def box_inertia(mass, size):
    a, b, c = size
    return mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


def rotation(seed):
    return exp_so3(np.random.default_rng(seed).normal(size=3))


def advanced(body_pose, u, eps):
    """(p, R) moved along the twist u for a time eps: p + eps v, exp(eps [w]) R."""
    p, R = body_pose
    return p + eps * u[:3], exp_so3(eps * u[3:]) @ R


def rod(name, length, theta, pivot=(0.0, 0.0, 0.0), mass=1.0):
    """A thin rod (inertia about its axis 1% of the transverse) hanging from ``pivot`` at
    angle theta from the downward vertical in the xz plane; its local z axis is the rod."""
    direction = np.array([np.sin(theta), 0.0, -np.cos(theta)])
    R = np.array([[np.cos(theta), 0, np.sin(theta)], [0, 1, 0], [-np.sin(theta), 0, np.cos(theta)]])
    inertia = mass * length**2 / 12 * np.diag([1.0, 1.0, 0.01])
    body = RigidBody(
        name, mass, inertia, position=np.asarray(pivot) + 0.5 * length * direction, rotation=R
    )
    return body, np.asarray(pivot) + length * direction


def two_body_joint(joint_type, seed, limits=None, world=False):
    """Two dynamic bodies at random poses (or one and the world), a joint with random frames."""
    rng = np.random.default_rng(seed)
    bodies = [
        RigidBody(
            f"b{k}",
            1.0 + k,
            np.diag([1.0, 1.5, 2.0]) * (1 + k),
            position=rng.normal(size=3),
            rotation=rotation(seed + 10 + k),
        )
        for k in range(2)
    ]
    frame_a = Frame(bodies[0], rng.normal(size=3), rotation(seed + 20))
    frame_b = Frame(None if world else bodies[1], rng.normal(size=3), rotation(seed + 21))
    kwargs = {"limits": limits} if limits is not None else {}
    return bodies, joint_type(frame_a, frame_b, **kwargs)


class Spring:
    """A zero-length linear spring with damping between two frames (either may be a world
    frame): the ForceElement protocol through point_force_wrenches, with
    f_a = -k (x_a - x_b) - c (v_a - v_b) = -f_b, K = df/dx and D = df/dv."""

    def __init__(self, frame_a, frame_b, k, c=0.0, implicit=True):
        self.frames, self.k, self.c = (frame_a, frame_b), k, c
        self.pair = np.kron([[-1.0, 1.0], [1.0, -1.0]], np.eye(3))
        if not implicit:
            self.jacobians = lambda t: ()

    def _mapped(self):
        fa, fb = self.frames
        f = -self.k * (fa.world_position() - fb.world_position()) - self.c * (
            fa.velocity() - fb.velocity()
        )
        return point_force_wrenches(self.frames, [f, -f], self.k * self.pair, self.c * self.pair)

    def wrenches(self, t):
        return self._mapped()[0]

    def jacobians(self, t):
        return self._mapped()[1]

    def potential_energy(self):
        d = self.frames[0].world_position() - self.frames[1].world_position()
        return 0.5 * self.k * d @ d


# ---- (a) mass properties -------------------------------------------------------------------


def test_box_mass_properties_translated_and_rotated():
    size, density = np.array([0.3, 0.5, 0.9]), 1100.0
    vertices, triangles = box_surface(size)
    Q, shift = rotation(1), np.array([12.0, -7.0, 30.0])
    props = MassProperties.from_surface(vertices @ Q.T + shift, triangles, density)
    mass = density * size.prod()
    assert props.mass == pytest.approx(mass, rel=1e-12)
    np.testing.assert_allclose(props.center, shift, atol=1e-12)
    np.testing.assert_allclose(props.inertia, Q @ box_inertia(mass, size) @ Q.T, atol=1e-11 * mass)


def test_sphere_mass_properties_converge_to_analytic(icosphere):
    radius, density = 0.2, 1000.0
    mass = density * 4 / 3 * np.pi * radius**3
    errors = []
    for level in (3, 4, 5):
        vertices, triangles = icosphere(level, radius)
        props = MassProperties.from_surface(vertices + [1.0, 2.0, 3.0], triangles, density)
        np.testing.assert_allclose(props.center, [1.0, 2.0, 3.0], atol=1e-12)
        I_exact = 0.4 * mass * radius**2
        assert np.abs(props.inertia - np.diag(np.diag(props.inertia))).max() < 1e-12 * I_exact
        errors.append((props.mass / mass - 1, props.inertia[0, 0] / I_exact - 1))
    errors = np.array(errors)
    # Inscribed polyhedra: both errors negative, second order in the edge length.
    assert np.all(errors < 0)
    np.testing.assert_allclose(errors[:-1] / errors[1:], 4.0, rtol=0.05)
    assert np.abs(errors[-1]).max() < 1.5e-3  # level 5: 20480 triangles


def test_hollow_box_is_outer_minus_offset_cavity():
    """Non-convex: a box with an off-centre box cavity (inner surface oriented inward)."""
    outer, inner = np.array([1.0, 0.8, 0.6]), np.array([0.4, 0.3, 0.2])
    cavity_center = np.array([0.2, -0.15, 0.1])
    vo, to = box_surface(outer)
    vi, ti = box_surface(inner, cavity_center)
    props = MassProperties.from_surface(np.vstack([vo, vi]), np.vstack([to, ti[:, ::-1] + 8]), 1.0)
    mo, mi = outer.prod(), inner.prod()
    mass = mo - mi
    com = -mi * cavity_center / mass
    assert props.mass == pytest.approx(mass, rel=1e-12)
    np.testing.assert_allclose(props.center, com, atol=1e-14)

    def shifted(I, m, c):  # parallel axis theorem: about the hollow body's COM
        d = c - com
        return I + m * (d @ d * np.eye(3) - np.outer(d, d))

    expected = shifted(box_inertia(mo, outer), mo, np.zeros(3)) - shifted(
        box_inertia(mi, inner), mi, cavity_center
    )
    np.testing.assert_allclose(props.inertia, expected, atol=1e-14)


def test_body_from_surface_sits_at_its_center_of_mass():
    vertices, triangles = box_surface([0.2, 0.2, 1.0], center=[0.0, 0.0, -0.5])
    body = RigidBody.from_surface("rod", vertices, triangles, 1000.0)
    np.testing.assert_allclose(body.position, [0.0, 0.0, -0.5], atol=1e-15)
    np.testing.assert_array_equal(body.rotation, np.eye(3))
    np.testing.assert_allclose(body.to_world(body.surface[0]), vertices, atol=1e-15)
    assert body.mass == pytest.approx(40.0)


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda v, t: (v, t[1:]), "not closed"),
        (lambda v, t: (v, t[:, ::-1]), "oriented inward"),
        (lambda v, t: (v, np.vstack([t[:1, ::-1], t[1:]])), "inconsistently oriented"),
        (lambda v, t: (v, np.vstack([t[:-1], [[0, 1, 99]]])), "indices"),
        (lambda v, t: (v, np.vstack([t[:-1], [[0, 0, 1]]])), "repeat a vertex"),
        (lambda v, t: (v * np.nan, t), "finite"),
    ],
)
def test_bad_surfaces_are_clear_errors(damage, message):
    vertices, triangles = damage(*box_surface([1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match=message) as info:
        RigidBody.from_surface("skull", vertices, triangles, 1000.0)
    assert "'skull'" in str(info.value)


# ---- (b) pendulum periods ------------------------------------------------------------------


def test_simple_pendulum_period():
    """A 1 mm sphere on a 1 m massless link: T = 2 pi sqrt(I_pivot / (m g L)) -> 2 pi sqrt(L/g)."""
    length, mass, radius, theta0, h = 1.0, 0.5, 1e-3, 0.05, 1e-3
    inertia = 0.4 * mass * radius**2
    bob = RigidBody(
        "bob",
        mass,
        inertia * np.eye(3),
        position=(length * np.sin(theta0), 0.0, -length * np.cos(theta0)),
    )
    system = Scene(GRAVITY)
    system.add(bob, SphericalJoint.at_world(bob, None, (0.0, 0.0, 0.0)))
    t, x = [], []
    for _ in range(6500):
        system.step(h)
        t.append(system.t)
        x.append(bob.position[0])
    period = zero_crossing_period(np.array(t), np.array(x))
    T0 = 2 * np.pi * np.sqrt(length / G)
    assert abs(period / T0 - 1) < 5e-3
    # Sharper: with the rotary inertia and the finite-amplitude factor 1 + theta0^2 / 16.
    exact = 2 * np.pi * np.sqrt((inertia + mass * length**2) / (mass * G * length))
    assert abs(period / (exact * (1 + theta0**2 / 16)) - 1) < 1e-4


def test_compound_pendulum_period():
    """A box rod from a surface, hinged at its top end: T = 2 pi sqrt(I_pivot / (m g d))."""
    size, theta0, h = np.array([0.04, 0.06, 0.8]), 0.05, 1e-3
    vertices, triangles = box_surface(size, center=[0.0, 0.0, -0.4])
    Q = np.array(
        [[np.cos(theta0), 0, np.sin(theta0)], [0, 1, 0], [-np.sin(theta0), 0, np.cos(theta0)]]
    )
    rod_body = RigidBody.from_surface("rod", vertices @ Q.T, triangles, 1000.0)
    system = Scene(GRAVITY)
    system.add(rod_body, RevoluteJoint.at_world(rod_body, None, (0.0, 0.0, 0.0), HINGE_Y))
    t, x = [], []
    for _ in range(6000):
        system.step(h)
        t.append(system.t)
        x.append(rod_body.position[0])
    period = zero_crossing_period(np.array(t), np.array(x))
    m, d = rod_body.mass, 0.4
    I_pivot = m * (size[0] ** 2 + size[2] ** 2) / 12 + m * d * d
    T0 = 2 * np.pi * np.sqrt(I_pivot / (m * G * d))
    assert abs(period / T0 - 1) < 5e-3
    assert abs(period / (T0 * (1 + theta0**2 / 16)) - 1) < 1e-4


# ---- (c) double pendulum energy ------------------------------------------------------------


def double_pendulum_energy_error(h, duration=2.5):
    """max |E(t) - E(0)| / (m g L) of two hinged rods released horizontal (chaotic motion)."""
    system = Scene(GRAVITY)
    rod1, elbow = rod("upper", 1.0, np.pi / 2)
    rod2, _ = rod("lower", 1.0, np.pi / 2, pivot=elbow)
    system.add(
        rod1,
        rod2,
        RevoluteJoint.at_world(rod1, None, (0.0, 0.0, 0.0), HINGE_Y),
        RevoluteJoint.at_world(rod2, rod1, elbow, HINGE_Y),
    )
    E0 = system.energy()
    errors = []
    for _ in range(int(round(duration / h))):
        system.step(h)
        errors.append(system.energy() - E0)
    errors = np.abs(errors) / (1.0 * G * 1.0)
    assert max(system.constraint_errors().values()) < 1e-4
    return errors.max(), errors[-len(errors) // 10 :].max()


def test_double_pendulum_energy_is_kept_to_first_order():
    """Measured: max |dE| / (m g L) = 2.6e-3 at h = 1 ms and 5.2e-3 at 2 ms over 2.5 s
    (2.8e-3 and 5.7e-3 over 5 s, 2.9e-3 and 6.0e-3 over 10 s).

    The error is the O(h) oscillation of symplectic Euler, not a drift: it
    halves with h, and the run's last tenth is no worse than the whole run.
    """
    fine, fine_last = double_pendulum_energy_error(1e-3)
    coarse, _ = double_pendulum_energy_error(2e-3)
    assert fine < 4e-3
    assert 1.6 < coarse / fine < 2.4
    assert fine_last <= fine


# ---- (d) joints: Jacobians, drift, no work -------------------------------------------------


@pytest.mark.parametrize("world", [False, True])
@pytest.mark.parametrize("joint_type", JOINTS)
def test_joint_jacobian_matches_finite_difference(joint_type, world):
    """phi' = G_A u_A + G_B u_B at random (inconsistent) poses, bilateral and limit rows."""
    limits = {RevoluteJoint: (-2.0, 2.5), SliderJoint: (-1.0, 3.0)}.get(joint_type)
    bodies, joint = two_body_joint(
        joint_type, seed=JOINTS.index(joint_type), limits=limits, world=world
    )
    assert len(joint.constraint()) == ROWS[joint_type]
    assert len(joint.unilateral()) == (2 if limits else 0)
    rng = np.random.default_rng(5)
    twists = [rng.normal(size=6) for _ in bodies]
    for rows_of in (joint.constraint, joint.unilateral):
        rows = rows_of()
        expected = rows.G_a @ twists[0] + (0 if world else rows.G_b @ twists[1])
        poses = [(b.position, b.rotation) for b in bodies]
        values = []
        for eps in (1e-6, -1e-6):
            for b, pose, u in zip(bodies, poses, twists):
                b.position, b.rotation = advanced(pose, u, eps)
            values.append(rows_of().phi)
        for b, (p, R) in zip(bodies, poses):
            b.position, b.rotation = p, R
        np.testing.assert_allclose((values[0] - values[1]) / 2e-6, expected, rtol=1e-7, atol=1e-8)


def test_joint_errors_and_coordinates_have_their_meaning():
    """phi is metres and (sines of) radians about B's axes; free motions leave phi at zero."""
    R_b, alpha, theta, s = rotation(11), 0.01, 2.5, 0.7
    body = RigidBody("b", 1.0, np.eye(3))

    def pose_a(rotvec_in_b, offset_in_b=np.zeros(3)):
        """Put body (= frame A) at frame B's pose moved by a rotation and an offset in B's axes."""
        body.rotation = R_b @ exp_so3(rotvec_in_b)
        body.position = np.array([1.0, 2.0, 3.0]) + R_b @ offset_in_b

    frame_b = Frame(None, (1.0, 2.0, 3.0), R_b)
    fixed, hinge, slider, planar = (
        cls(Frame(body), frame_b) for cls in (FixedJoint, RevoluteJoint, SliderJoint, PlanarJoint)
    )
    pose_a([alpha, 0.0, 0.0], [0.0, 0.002, 0.0])
    np.testing.assert_allclose(
        fixed.constraint().phi, [0, 0.002, 0, np.sin(alpha), 0, 0], atol=1e-15
    )
    np.testing.assert_allclose(hinge.constraint().phi[3:], [np.sin(alpha), 0], atol=1e-15)
    pose_a([0.0, 0.0, theta], [0.0, 0.0, s])  # a hinge turn and a slide along z
    assert hinge.angle() == pytest.approx(theta, abs=1e-14)
    assert slider.distance() == pytest.approx(s, abs=1e-14)
    np.testing.assert_allclose(hinge.constraint().phi[3:], 0, atol=1e-15)
    np.testing.assert_allclose(slider.constraint().phi[:2], 0, atol=1e-15)
    pose_a([0.0, 0.0, theta], [0.4, -0.3, 0.0])  # a planar motion
    np.testing.assert_allclose(planar.constraint().phi, 0, atol=1e-15)


def test_frame_jacobian_and_wrench_stiffness_match_finite_differences():
    body = RigidBody(
        "b", 2.0, np.diag([1.0, 2.0, 3.0]), position=(1.0, 2.0, 3.0), rotation=rotation(3)
    )
    frame = Frame(body, (0.3, -0.2, 0.5))
    force = np.array([1.0, -2.0, 0.5])
    u = np.random.default_rng(2).normal(size=6)
    pose = (body.position, body.rotation)
    x, wrench = [], []
    for eps in (1e-6, -1e-6):
        body.position, body.rotation = advanced(pose, u, eps)
        x.append(frame.world_position())
        wrench.append(frame.wrench(force))
    body.position, body.rotation = pose
    np.testing.assert_allclose((x[0] - x[1]) / 2e-6, frame.jacobian() @ u, rtol=1e-8)
    np.testing.assert_allclose(
        (wrench[0] - wrench[1]) / 2e-6, frame.wrench_stiffness(force) @ u, rtol=1e-7, atol=1e-9
    )
    body.set_twist(u)
    np.testing.assert_allclose(frame.velocity(), frame.jacobian() @ u, rtol=1e-14)


def joint_scene(joint_type, seed=0):
    """A body swinging from the world on a spherical joint, a second body on the tested joint,
    both spinning: every row of the tested joint is exercised with both bodies moving. A
    spring to the world keeps the second body from falling away along a slider or a plane."""
    system = Scene(GRAVITY)
    rng = np.random.default_rng(seed)
    upper = RigidBody(
        "upper",
        1.0,
        np.diag([0.02, 0.03, 0.01]),
        position=(0.3, 0.0, -0.4),
        angular_velocity=rng.normal(size=3),
    )
    lower = RigidBody(
        "lower",
        0.5,
        np.diag([0.01, 0.005, 0.012]),
        position=(0.6, 0.1, -0.9),
        rotation=rotation(seed),
        velocity=rng.normal(size=3),
        angular_velocity=2 * rng.normal(size=3),
    )
    joint = joint_type.at_world(lower, upper, (0.5, 0.0, -0.7), rotation(seed + 1), name="tested")
    system.add(
        upper,
        lower,
        SphericalJoint.at_world(upper, None, (0.0, 0.0, 0.0)),
        joint,
        Spring(Frame(lower), Frame(None, (0.6, 0.1, -0.9)), 50.0),
    )
    return system, joint


def drift(joint_type, stabilization):
    system, joint = joint_scene(joint_type)
    system.stabilization = stabilization
    errors = []
    for _ in range(1000):
        system.step(1e-3)
        errors.append(np.abs(joint.constraint().phi).max())
    return np.array(errors)


@pytest.mark.parametrize("joint_type", JOINTS)
def test_joint_drift_stays_bounded(joint_type):
    """1 s at h = 1 ms, bodies at up to ~6 rad/s: with beta = 1 the position error stays
    O(h^2 |u|^2 / l) (measured 1.7e-6 to 1.4e-5) and does not grow (its second half's
    largest over its first half's: 0.57 to 1.84); without stabilization it grows (1.3 to
    5.3 times from the first half to the second), to 70-220 times the stabilized error
    within the first half already."""
    errors = drift(joint_type, 1.0)
    assert errors.max() < 3e-5
    assert errors[500:].max() < 3 * errors[:500].max()
    unstabilized = drift(joint_type, 0.0)
    assert unstabilized[500:].max() > unstabilized[:500].max() > 30 * errors.max()


@pytest.mark.parametrize("stabilization", [0.0, 1.0])
@pytest.mark.parametrize("joint_type", JOINTS)
def test_constraint_velocity_after_a_step_is_the_stabilization(joint_type, stabilization):
    """G(q_k) u+ = -beta phi(q_k) / h, so the reaction's power is -lambda . beta phi / h^2
    with lambda the joint's impulses of the step: zero (to round-off) without
    stabilization, the drift correction's with it (measured: the power equals it to 1.3e-16
    of |wrench| |twist|, that is to 8e-13 of itself; the bound is 1e-12 of |wrench| |twist|)."""
    system, joint = joint_scene(joint_type, seed=4)
    system.stabilization = stabilization
    for _ in range(20):
        system.step(1e-3)
    rows = joint.constraint()
    upper, lower = system.rigid_bodies
    system.step(1e-3)
    correction = stabilization * rows.phi / 1e-3
    residual = rows.G_a @ lower.twist + rows.G_b @ upper.twist + correction
    assert np.abs(residual).max() < 1e-12 * max(1.0, np.abs(correction).max())
    wrench_a, wrench_b = system.reaction(joint)
    power = wrench_a @ lower.twist + wrench_b @ upper.twist
    scale = np.linalg.norm(wrench_a) * np.linalg.norm(lower.twist)
    ((block, lam),) = system._impulses[joint]  # the step's rows: those at q_k
    np.testing.assert_array_equal(block.phi, rows.phi)
    assert abs(power - (-(lam / 1e-3) @ correction)) < 1e-12 * scale
    if stabilization:
        assert abs(power) > 1e-9 * scale  # the correction does work


def test_redundant_joints_are_solved_with_minimum_norm_multipliers():
    """Two identical hinges (as in a closed loop): the KKT matrix is singular, the step is not.
    The rod swings as on one hinge (to round-off), and the minimum-norm multipliers split that
    hinge's reaction in two equal halves."""
    runs = []
    for count in (2, 1):
        rod1, _ = rod("rod", 1.0, 0.3)
        system = Scene(GRAVITY)
        hinge = [
            RevoluteJoint.at_world(rod1, None, (0.0, 0.0, 0.0), HINGE_Y, name=f"h{k}")
            for k in range(count)
        ]
        system.add(rod1, *hinge)
        for _ in range(500):
            system.step(1e-3)
        runs.append((rod1, [system.reaction(h)[0] for h in hinge]))
    (rod2, (r_a, r_b)), (rod1, (r_one,)) = runs
    np.testing.assert_allclose(rod2.position, rod1.position, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rod2.twist, rod1.twist, rtol=0, atol=1e-12)
    scale = np.abs(r_one).max()
    np.testing.assert_allclose(r_a, r_b, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(r_a + r_b, r_one, rtol=0, atol=1e-8 * scale)


def test_fixed_body_is_the_world_for_its_joints():
    """A double pendulum hinged to a fixed body moves exactly as one hinged to the world."""
    trajectories = []
    for fixed in (False, True):
        base = RigidBody(
            "base", 5.0, np.eye(3), position=(0.2, 0.0, 0.3), rotation=rotation(1), motion="fixed"
        )
        rod1, elbow = rod("upper", 1.0, 1.0)
        rod2, _ = rod("lower", 1.0, -0.5, pivot=elbow)
        system = Scene(GRAVITY)
        system.add(
            base,
            rod1,
            rod2,
            RevoluteJoint.at_world(rod1, base if fixed else None, (0, 0, 0), HINGE_Y),
            RevoluteJoint.at_world(rod2, rod1, elbow, HINGE_Y),
        )
        for _ in range(300):
            system.step(1e-3)
        trajectories.append(np.concatenate([rod2.position, rod2.twist]))
        np.testing.assert_array_equal(base.position, [0.2, 0.0, 0.3])
    np.testing.assert_allclose(trajectories[1], trajectories[0], atol=1e-12)


def test_hanging_body_reaction_is_its_weight():
    system = Scene(GRAVITY)
    bob = RigidBody("bob", 2.0, 0.01 * np.eye(3), position=(0.0, 0.0, -1.0))
    joint = SphericalJoint.at_world(bob, None, (0.0, 0.0, 0.0))
    system.add(bob, joint)
    system.step(1e-3)
    on_bob, on_world = system.reaction(joint)
    np.testing.assert_allclose(on_bob, [0, 0, 2.0 * G, 0, 0, 0], atol=1e-9)
    np.testing.assert_array_equal(on_world, np.zeros(6))


# ---- (e) free body -------------------------------------------------------------------------


def test_free_body_conserves_momentum_and_stays_orthonormal():
    """Torque-free precession near the unstable intermediate axis (inertia 1 : 2 : 3), 10 s.

    The step is first order in the angular momentum (M and I_w at the start of
    the step). Measured at h = 1 ms: |L| -0.23 %, direction 0.87 mrad, energy
    -0.47 % (the linearized implicit gyroscopic term dissipates, never adds).
    """
    R0 = rotation(7)
    body = RigidBody(
        "tumbler",
        2.0,
        np.diag([1.0, 2.0, 3.0]),
        rotation=R0,
        position=(1.0, -1.0, 0.5),
        velocity=(0.1, 0.2, -0.3),
        angular_velocity=R0 @ [0.3, 2.0, 0.4],
    )
    system = Scene((0.0, 0.0, 0.0))
    system.add(body)
    P0, L0 = system.momentum(), system.angular_momentum(about=body.position)
    p0, E0 = body.position.copy(), system.energy()
    h, E_prev, worst = 1e-3, system.energy(), 0.0
    flipped = False
    for _ in range(10000):
        system.step(h)
        E = system.energy()
        assert E <= E_prev * (1 + 1e-13)
        E_prev = E
        worst = max(worst, np.abs(body.rotation.T @ body.rotation - np.eye(3)).max())
        flipped |= (body.rotation.T @ body.angular_velocity)[1] < 0
    P, L = system.momentum(), system.angular_momentum(about=body.position)
    np.testing.assert_array_equal(P, P0)
    np.testing.assert_allclose(body.position, p0 + 10.0 * P0 / 2.0, atol=1e-12)
    assert flipped, "the body should tumble (Dzhanibekov flip) in 10 s"
    assert worst < 1e-12
    assert abs(np.linalg.norm(L) / np.linalg.norm(L0) - 1) < 4e-3
    angle = np.arccos(np.clip(L @ L0 / np.linalg.norm(L) / np.linalg.norm(L0), -1, 1))
    assert angle < 1.5e-3
    assert -1e-2 < E / E0 - 1 <= 0


# ---- (f) prescribed bodies, limits, force elements -----------------------------------------


def test_body_welded_to_a_prescribed_turntable_follows_it():
    """A turntable spins at omega about z; a body welded at radius r follows it and the weld
    carries the centripetal force m omega^2 r and the weight."""
    omega, r, m = 2.0, 0.5, 3.0

    def turntable(t):
        return BodyState(np.zeros(3), exp_so3([0, 0, omega * t]), np.zeros(3), [0, 0, omega])

    table = RigidBody("table", 1.0, np.eye(3), motion="prescribed", trajectory=turntable)
    rider = RigidBody(
        "rider",
        m,
        0.01 * np.eye(3),
        position=(r, 0.0, 0.0),
        velocity=(0.0, omega * r, 0.0),
        angular_velocity=(0, 0, omega),
    )
    weld = FixedJoint.at_world(rider, table, (r, 0.0, 0.0))
    system = Scene(GRAVITY)
    system.add(table, rider, weld)
    h = 1e-3
    for _ in range(2000):
        system.step(h)
    np.testing.assert_allclose(table.rotation, exp_so3([0, 0, omega * system.t]), atol=1e-14)
    expected = np.array([r * np.cos(omega * system.t), r * np.sin(omega * system.t), 0.0])
    np.testing.assert_allclose(rider.position, expected, atol=1e-5)
    assert max(system.constraint_errors().values()) < 1e-5
    force = system.reaction(weld)[0][:3]
    np.testing.assert_allclose(
        force, -m * omega**2 * expected + [0, 0, m * G], rtol=0, atol=1e-2 * m * omega**2 * r
    )


def test_body_carried_by_a_prescribed_body_moves_with_its_twist():
    """A RigidAttachment on a prescribed body that turns and translates: after each step the
    carried body sits at p + R d_b and moves with the rigid-body field, v_s = v + w x
    (p_s - p), w_s = w (the trajectory's twist at the step's end)."""
    rng = np.random.default_rng(31)
    w, v0, p0 = rng.standard_normal(3), rng.standard_normal(3), rng.standard_normal(3)
    R0 = exp_so3(rng.standard_normal(3))

    def trajectory(t):
        return BodyState(p0 + v0 * t, exp_so3(w * t) @ R0, v0, w)

    bone = RigidBody(
        "bone", 1.0, np.eye(3), position=p0, rotation=R0, motion="prescribed", trajectory=trajectory
    )
    offset = np.array([0.3, -0.2, 0.5])
    carried = RigidBody("carried", 0.5, 0.01 * np.eye(3), position=p0 + R0 @ offset, rotation=R0)
    system = Scene(GRAVITY)
    system.add(bone, carried, RigidAttachment(carried, bone))
    for _ in range(3):
        system.step(0.01)
        p, R, _, _ = trajectory(system.t)
        np.testing.assert_allclose(bone.position, p, atol=1e-14)
        np.testing.assert_allclose(carried.position, p + R @ offset, atol=1e-14)
        np.testing.assert_allclose(
            carried.velocity, v0 + np.cross(w, carried.position - p), atol=1e-13
        )
        np.testing.assert_allclose(carried.angular_velocity, w, atol=1e-14)


def test_revolute_limits_stop_the_swing():
    """A rod swung hard against limits (-0.5, 0.4) rad never passes them; at rest on the
    upper limit of a rod hinged horizontally, the limit carries the torque m g d."""
    rod1, _ = rod("rod", 1.0, 0.0)
    rod1.angular_velocity = np.array([0.0, -6.0, 0.0])  # theta decreases
    rod1.velocity = np.cross(rod1.angular_velocity, rod1.position)
    hinge = RevoluteJoint.at_world(rod1, None, (0.0, 0.0, 0.0), HINGE_Y, limits=(-0.5, 0.4))
    system = Scene(GRAVITY)
    system.add(rod1, hinge)
    angles = []
    for _ in range(3000):
        system.step(1e-3)
        angles.append(hinge.angle())
    assert min(angles) > -0.5 - 1e-9 and max(angles) < 0.4 + 1e-9
    assert min(angles) < -0.5 + 1e-6 and max(angles) > 0.4 - 1e-6  # both limits touched

    rod2, _ = rod("arm", 1.0, np.pi / 2)  # horizontal: gravity turns it down
    hinge2 = RevoluteJoint.at_world(rod2, None, (0.0, 0.0, 0.0), HINGE_Y, limits=(-np.pi, 0.0))
    system = Scene(GRAVITY)
    system.add(rod2, hinge2)
    for _ in range(100):
        system.step(1e-3)
    assert hinge2.angle() == pytest.approx(0.0, abs=1e-9)
    torque = system.reaction(hinge2)[0][3:]
    torque_about_pivot = torque + np.cross(rod2.position, system.reaction(hinge2)[0][:3])
    np.testing.assert_allclose(torque_about_pivot, [0.0, -1.0 * G * 0.5, 0.0], atol=1e-8)


def test_slider_limit_holds_the_weight():
    """A block on a vertical slider falls onto its lower limit and rests there."""
    block = RigidBody("block", 2.0, 0.1 * np.eye(3), position=(0.0, 0.0, 1.0))
    slider = SliderJoint.at_world(block, None, (0.0, 0.0, 1.0), limits=(-0.3, 1.0))
    system = Scene(GRAVITY)
    system.add(block, slider)
    distances = []
    for _ in range(1000):
        system.step(1e-3)
        distances.append(slider.distance())
    assert min(distances) > -0.3 - 1e-9
    assert slider.distance() == pytest.approx(-0.3, abs=1e-9)
    np.testing.assert_allclose(system.reaction(slider)[0][:3], [0, 0, 2.0 * G], atol=1e-8)


def test_slider_limit_with_partial_stabilization():
    """Limit rows with Baumgarte beta = 0.5: G u+ >= -phi / h while the limit is not reached
    (a block thrown at it stops exactly on it in the step that would cross it) and
    G u+ >= -beta phi / h once crossed (a block started 1 cm past it, still moving into
    it, recovers half of the violation in one step; the slider's coordinate is linear in
    the position, so phi+ = phi + h G u+ exactly)."""
    h, beta = 1e-3, 0.5

    def block_on_slider(lower, velocity):
        block = RigidBody(
            "block", 2.0, 0.1 * np.eye(3), position=(0.0, 0.0, 1.0), velocity=(0.0, 0.0, velocity)
        )
        slider = SliderJoint.at_world(block, None, (0.0, 0.0, 1.0), limits=(lower, 1.0))
        system = Scene(GRAVITY, stabilization=beta)
        system.add(block, slider)
        system.step(h)
        return slider.distance() - lower

    assert block_on_slider(-1e-3, -2.0) == pytest.approx(0.0, abs=1e-12)  # 1 mm away, 2 mm/step
    assert block_on_slider(0.01, -1.0) == pytest.approx(-0.5 * 0.01, rel=1e-9)


def test_point_force_jacobians_match_finite_differences():
    """A damped spring between two spinning bodies: the mapped K_bc and D_bc are the
    derivatives of the wrenches along pose and velocity perturbations."""
    bodies = [
        RigidBody(
            f"b{k}",
            1.0,
            np.eye(3),
            position=np.random.default_rng(k).normal(size=3),
            rotation=rotation(9 + k),
        )
        for k in range(2)
    ]
    rng = np.random.default_rng(3)
    for body in bodies:
        body.set_twist(rng.normal(size=6))
    spring = Spring(
        Frame(bodies[0], (0.1, 0.4, -0.2)), Frame(bodies[1], (-0.3, 0.2, 0.1)), k=50.0, c=3.0
    )
    blocks = {(id(bi), id(bj)): (K, D) for bi, bj, K, D in spring.jacobians(0.0)}
    assert len(blocks) == 4

    def wrenches():
        return {id(b): w for b, w in spring.wrenches(0.0)}

    du = [rng.normal(size=6) for _ in bodies]
    for j, body in enumerate(bodies):
        pose, twist = (body.position, body.rotation), body.twist
        plus_minus = []
        for eps in (1e-6, -1e-6):
            body.position, body.rotation = advanced(pose, du[j], eps)
            plus_minus.append(wrenches())
        body.position, body.rotation = pose
        velocity_pm = []
        for eps in (1e-6, -1e-6):
            body.set_twist(twist + eps * du[j])
            velocity_pm.append(wrenches())
        body.set_twist(twist)
        for bi in bodies:
            K, D = blocks[(id(bi), id(body))]
            np.testing.assert_allclose(
                (plus_minus[0][id(bi)] - plus_minus[1][id(bi)]) / 2e-6,
                K @ du[j],
                rtol=1e-6,
                atol=1e-7,
            )
            np.testing.assert_allclose(
                (velocity_pm[0][id(bi)] - velocity_pm[1][id(bi)]) / 2e-6,
                D @ du[j],
                rtol=1e-6,
                atol=1e-7,
            )


def test_mass_towed_by_a_prescribed_body_keeps_its_offset():
    """A mass on a stiff spring towed at constant velocity by a prescribed body, starting in
    equilibrium: nothing accelerates, so the exact solution keeps the offset. The step gets it
    to round-off only with the spring's stiffness coupling to the prescribed velocity
    (b += h^2 K_ij u_j): without it the mass lags."""
    V = np.array([0.3, -0.2, 0.1])
    tug = RigidBody(
        "tug",
        1.0,
        np.eye(3),
        motion="prescribed",
        trajectory=lambda t: BodyState(t * V, np.eye(3), V, np.zeros(3)),
    )
    barge = RigidBody("barge", 2.0, np.eye(3), position=(1.0, 0.0, 0.0), velocity=V)
    system = Scene((0.0, 0.0, 0.0))
    system.add(
        tug,
        barge,
        Spring(Frame.at_world(barge, (1.0, 0, 0)), Frame.at_world(tug, (1.0, 0, 0)), k=1e4),
    )
    for _ in range(200):
        system.step(0.01)
    np.testing.assert_allclose(barge.position - tug.position, [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(barge.velocity, V, atol=1e-12)


def spring_run(h, steps, implicit=True):
    mass, k = 2.0, 200.0
    body = RigidBody("mass", mass, 0.01 * np.eye(3), position=(0.1, 0.0, 0.0))
    system = Scene((0.0, 0.0, 0.0))
    system.add(body, Spring(Frame(body), Frame(None), k, implicit=implicit))
    x, E0 = [], system.energy()
    for _ in range(steps):
        system.step(h)
        x.append(body.position[0])
    return np.array(x), system.energy() / E0, 2 * np.pi * np.sqrt(mass / k)


def test_spring_element_period_and_implicit_stability():
    x, _, T = spring_run(1e-3, 3000)
    period = zero_crossing_period(1e-3 * np.arange(1, 3001), x)
    assert abs(period / T - 1) < 5e-3
    # h = T / 2: beyond the explicit limit h < T / pi. With its Jacobian the spring is
    # integrated implicitly: backward Euler on x'' = -w^2 x scales the energy by exactly
    # 1 / (1 + (w h)^2) per step, w h = pi here (measured over 40 steps to 2e-16; rel 1e-9).
    # Without it (explicit) the energy explodes.
    _, ratio_implicit, _ = spring_run(T / 2, 40)
    _, ratio_explicit, _ = spring_run(T / 2, 40, implicit=False)
    assert ratio_implicit == pytest.approx((1 + np.pi**2) ** -40, rel=1e-9)
    assert ratio_explicit > 1e6


# ---- (g) bad input -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"mass": -1.0}, "mass must be positive"),
        ({"inertia": np.diag([1.0, 1.0, 3.0])}, "triangle inequality"),
        ({"inertia": np.diag([1.0, -1.0, 1.0])}, "principal moments"),
        ({"inertia": [[1.0, 0.5, 0], [0, 1.0, 0], [0, 0, 1.0]]}, "symmetric"),
        ({"rotation": 2 * np.eye(3)}, "not a rotation"),
        ({"rotation": np.diag([1.0, 1.0, -1.0])}, "not a rotation"),
        ({"position": (0.0, np.nan, 0.0)}, "position"),
        ({"motion": "kinematic"}, "motion must be one of"),
        ({"motion": "prescribed"}, "trajectory is required"),
        ({"motion": "fixed", "velocity": (1.0, 0, 0)}, "fixed body cannot have a velocity"),
    ],
)
def test_bad_rigid_bodies_are_clear_errors(kwargs, message):
    args = {"mass": 1.0, "inertia": np.eye(3)} | kwargs
    with pytest.raises(ValueError, match=message) as info:
        RigidBody("femur", args.pop("mass"), args.pop("inertia"), **args)
    assert "'femur'" in str(info.value)


def test_bad_joints_are_clear_errors():
    body = RigidBody("jaw", 1.0, np.eye(3))
    with pytest.raises(ValueError, match="both frames are on the world"):
        SphericalJoint(Frame(None), Frame(None), name="tmj")
    with pytest.raises(ValueError, match="both frames are on body 'jaw'"):
        SphericalJoint(Frame(body), Frame(body), name="tmj")
    with pytest.raises(ValueError, match="'tmj'.*no coordinate to limit"):
        SphericalJoint(Frame(body), Frame(None), name="tmj", limits=(0.0, 1.0))
    with pytest.raises(ValueError, match="'tmj'.*lower < upper"):
        RevoluteJoint(Frame(body), Frame(None), name="tmj", limits=(0.5, -0.5))
    with pytest.raises(ValueError, match="'tmj'.*lower < upper"):
        RevoluteJoint(Frame(body), Frame(None), name="tmj", limits=(-4.0, 0.5))
    with pytest.raises(ValueError, match="'tmj'.*finite"):
        SliderJoint(Frame(body), Frame(None), name="tmj", limits=(-np.inf, 0.5))
    with pytest.raises(ValueError, match="axis must be a non-zero"):
        axis_rotation((0.0, 0.0, 0.0))


def test_bad_systems_are_clear_errors():
    jaw, skull = RigidBody("jaw", 1.0, np.eye(3)), RigidBody("skull", 1.0, np.eye(3))
    system = Scene(GRAVITY)
    system.add(jaw, RevoluteJoint.at_world(jaw, skull, (0.0, 0.0, 0.0), name="tmj"))
    with pytest.raises(ValueError, match="'tmj' connects rigid body 'skull', which is not in"):
        system.step(1e-3)
    with pytest.raises(ValueError, match="a body named 'jaw' is already in the scene"):
        system.add(RigidBody("jaw", 1.0, np.eye(3)))
    with pytest.raises(TypeError, match="cannot add str"):
        system.add("muscle")
    for h in (0.0, -1e-3, np.nan):
        with pytest.raises(ValueError, match="time step must be positive"):
            system.step(h)
    with pytest.raises(ValueError, match="stabilization must be in"):
        Scene(stabilization=2.0)

    class BadElement:
        def __init__(self, wrench):
            self.wrench = wrench

        def wrenches(self, t):
            return [(jaw, self.wrench)]

    for wrench in (np.zeros(3), np.zeros(7), np.zeros((6, 1)), np.full(6, np.nan)):
        other = Scene(GRAVITY)
        other.add(jaw, BadElement(wrench))
        with pytest.raises(ValueError, match="BadElement: expected a finite array of shape"):
            other.step(1e-3)

    def bad_trajectory(t):
        return BodyState(np.zeros(3), 2 * np.eye(3), np.zeros(3), np.zeros(3))

    with pytest.raises(ValueError, match="'cam': trajectory.*rotation"):
        Scene().add(
            RigidBody("cam", 1.0, np.eye(3), motion="prescribed", trajectory=bad_trajectory)
        )


def test_singular_step_is_reported():
    """A body whose mass is cancelled by a negative stiffness: a singular step matrix."""
    body = RigidBody("b", 1.0, np.eye(3))

    class Antispring:
        def wrenches(self, t):
            return [(body, np.zeros(6))]

        def jacobians(self, t):
            return [(body, body, np.diag([4.0, 0, 0, 0, 0, 0]), None)]

    system = Scene(GRAVITY, max_halvings=0)  # halving would make it regular
    system.add(body, Antispring())
    # A_00 = m - h^2 K_00 = 1 - 0.25 * 4 = 0: nothing resists the motion along x
    with pytest.raises(StepFailed, match=r"nothing resists 'b' translating along \(1, 0, 0\)"):
        system.step(0.5)
