"""Axial springs and Thelen 2003 muscles on points (artifem.multibody.muscles).

Curves against Thelen 2003's equations, force Jacobians against finite
differences, Newton's third law, activation dynamics against the closed-form
solution of Thelen's ODE, spring energy, and clear errors for bad input.
"""

import math

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.errors import InputError
from artifem.multibody.muscles import (
    AxialSpring,
    PathForces,
    PathGeometry,
    ThelenMuscle,
    ThelenParameters,
    active_force_length,
    REST_STRAIN,
    REST_VELOCITY,
    force_velocity,
    force_velocity_inverse,
    passive_force_length,
    tendon_force_strain,
    tendon_toe_constants,
)


def fd_jacobian(fun, z, eps=1e-7):
    """Central differences of fun (array -> array) with respect to every entry of z."""
    z = np.asarray(z, float)
    cols = []
    for k in range(z.size):
        zp, zm = z.copy().ravel(), z.copy().ravel()
        zp[k] += eps
        zm[k] -= eps
        cols.append(
            (fun(zp.reshape(z.shape)).ravel() - fun(zm.reshape(z.shape)).ravel()) / (2 * eps)
        )
    return np.array(cols).T


def fd_slope(fun, x, eps=1e-6):
    return (fun(x + eps) - fun(x - eps)) / (2 * eps)


def relerr(a, b):
    return np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300)


def random_path(rng, n_points, length=0.3):
    """A wiggly path of exactly ``length`` through n points, with random point velocities."""
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    s = np.linspace(0.0, length, n_points)
    x = np.outer(s, direction) + 0.02 * rng.normal(size=(n_points, 3))
    x *= length / PathGeometry.of(x).length
    return x + rng.normal(size=3), 0.3 * rng.normal(size=(n_points, 3))


# ---- curves ----------------------------------------------------------------------------------


def test_active_force_length_is_thelen_gaussian():
    assert active_force_length(1.0) == 1.0
    gamma = 0.45
    for ln in (0.5, 0.8, 1.3, 1.7):
        assert active_force_length(ln) == pytest.approx(
            math.exp(-((ln - 1) ** 2) / gamma), rel=1e-15
        )
    # e^-1 at one width-root away from the optimum; a single peak at 1
    assert active_force_length(1 + math.sqrt(gamma)) == pytest.approx(math.exp(-1))
    ln = np.linspace(0.2, 1.8, 401)
    f = active_force_length(ln)
    assert np.all(np.diff(f[ln < 1]) > 0) and np.all(np.diff(f[ln > 1]) < 0)
    f1, df = active_force_length(ln, derivative=True)
    assert np.allclose(f1, f)
    assert np.allclose(df, fd_slope(active_force_length, ln), atol=1e-8)


def test_passive_force_length_reaches_one_at_eps0m():
    for e0, kpe in ((0.6, 5.0), (0.5, 4.0)):
        assert passive_force_length(1 + e0, kpe, e0) == pytest.approx(1.0, rel=1e-14)
        ln = 1.3
        assert passive_force_length(ln, kpe, e0) == pytest.approx(
            (math.exp(kpe * (ln - 1) / e0) - 1) / (math.exp(kpe) - 1), rel=1e-14
        )
    ln = np.linspace(0.3, 1.9, 801)
    f, df = passive_force_length(ln, derivative=True)
    assert np.all(f[ln <= 1] == 0.0)
    assert np.all(np.diff(f) >= 0) and np.all(np.diff(f[ln > 1]) > 0)
    assert passive_force_length(1.0 + 1e-12) < 1e-11  # continuous at the optimal length
    # at the optimal length, to round-off of either sign, the slope is the unstretched one
    for rest in (1.0 - 1e-15, 1.0, 1.0 + 1e-15, 1.0 + REST_STRAIN):
        assert passive_force_length(rest, derivative=True) == (0.0, 0.0), rest
    assert passive_force_length(1.0 + 2 * REST_STRAIN, derivative=True)[1] > 0.05
    mask = np.abs(ln - 1) > 1e-3
    assert np.allclose(df[mask], fd_slope(passive_force_length, ln[mask]), rtol=1e-6, atol=1e-9)


def test_force_velocity_reference_points():
    af, flen = 0.25, 1.4
    assert force_velocity(-1.0) == 0.0  # max shortening velocity
    assert force_velocity(-2.0) == 0.0  # beyond it: no active force
    assert force_velocity(0.0) == 1.0  # isometric
    assert force_velocity(1e6) == pytest.approx(flen, rel=1e-5)  # lengthening plateau
    assert force_velocity(-1e-12) == pytest.approx(1.0) and force_velocity(1e-12) == pytest.approx(
        1.0
    )
    v = np.linspace(-1.0, 5.0, 1201)
    f = force_velocity(v)
    assert np.all(np.diff(f) > 0) and np.all(f < flen)
    # Thelen's design: lengthening slope at 0 is twice the shortening slope; ArtiSynth's C1 option
    s_short = force_velocity(-1e-6, derivative=True)[1]
    s_long = force_velocity(1e-6, derivative=True)[1]
    assert s_short == pytest.approx(1 + 1 / af, rel=1e-4)  # O(v) from the slopes at 0
    assert s_long == pytest.approx(2 + 2 / af, rel=1e-4)
    one_slope = force_velocity(1e-6, c1_at_zero=True, derivative=True)[1]
    assert one_slope == pytest.approx(1 + 1 / af, rel=1e-4)
    # at rest (a velocity at round-off, of either sign) the slope is the shortening one, the
    # same on every machine: the step from rest does not depend on the round-off's sign
    for rest in (-1e-12, 0.0, 1e-12, REST_VELOCITY):
        slope = force_velocity(rest, derivative=True)[1]
        assert slope == pytest.approx(1 + 1 / af, rel=1e-9), rest
    assert force_velocity(2 * REST_VELOCITY, derivative=True)[1] == pytest.approx(
        2 + 2 / af, rel=1e-6
    )
    mask = (np.abs(v) > 1e-3) & (v > -1 + 1e-3)
    _, df = force_velocity(v, derivative=True)
    assert np.allclose(df[mask], fd_slope(force_velocity, v[mask]), rtol=1e-6)


@pytest.mark.parametrize("af,flen", [(0.25, 1.4), (0.25, 1.8), (0.4, 1.6)])
def test_force_velocity_inverts_thelen_equation_6(af, flen, rng):
    """Thelen 2003 eqs. (6)-(7) written literally: v_M = (0.25 + 0.75 a) v_max (F_M - a f_L)/b."""
    vmax = 10.0
    for _ in range(50):
        a, fl = rng.uniform(0.05, 1.0), rng.uniform(0.2, 1.0)
        fm = a * fl * rng.uniform(0.0, 0.999 * flen)  # active fiber force / F0
        if fm <= a * fl:
            b = a * fl + fm / af
        else:
            b = (2 + 2 / af) * (a * fl * flen - fm) / (flen - 1)
        vm = (0.25 + 0.75 * a) * vmax * (fm - a * fl) / b  # in optimal lengths per second
        vn = vm / ((0.25 + 0.75 * a) * vmax)
        assert force_velocity(vn, af, flen) == pytest.approx(fm / (a * fl), rel=1e-12, abs=1e-14)
        assert force_velocity_inverse(fm / (a * fl), af, flen) == pytest.approx(
            vn, rel=1e-12, abs=1e-14
        )
    f = np.linspace(0.0, 0.999 * flen, 300)
    assert np.allclose(force_velocity(force_velocity_inverse(f, af, flen), af, flen), f, atol=1e-12)


def test_tendon_force_strain_matches_thelen_constants():
    e0 = 0.04
    eps_toe, k_lin = tendon_toe_constants(e0)
    assert eps_toe == pytest.approx(0.609 * e0, rel=1e-3)  # the paper's rounded constants
    assert k_lin == pytest.approx(1.712 / e0, rel=1e-3)
    exp3 = math.exp(3.0)  # OpenSim's exact ones
    assert eps_toe == pytest.approx(99 * e0 * exp3 / (166 * exp3 - 67), rel=1e-14)
    assert tendon_force_strain(e0) == pytest.approx(1.0, rel=1e-14)
    assert tendon_force_strain(0.033, 0.033) == pytest.approx(1.0, rel=1e-14)
    assert tendon_force_strain(eps_toe) == pytest.approx(0.33, rel=1e-14)
    assert tendon_force_strain(0.0) == 0.0 and tendon_force_strain(-0.01) == 0.0
    e = 0.5 * eps_toe
    assert tendon_force_strain(e) == pytest.approx(
        0.33 / (exp3 - 1) * (math.exp(3 * e / eps_toe) - 1)
    )
    # continuous value and slope at the end of the toe; monotone; derivative
    lo, hi = (
        tendon_force_strain(eps_toe * (1 - 1e-9), derivative=True),
        tendon_force_strain(eps_toe * (1 + 1e-9), derivative=True),
    )
    assert lo[0] == pytest.approx(hi[0], abs=1e-7) and lo[1] == pytest.approx(hi[1], rel=1e-6)
    eps = np.linspace(-0.01, 0.08, 901)
    f, df = tendon_force_strain(eps, derivative=True)
    assert np.all(np.diff(f) >= 0) and np.all(np.diff(f[eps > 0]) > 0)
    mask = np.abs(eps) > 1e-4
    assert np.allclose(df[mask], fd_slope(tendon_force_strain, eps[mask], 1e-8), rtol=1e-5)


def test_curve_constants_are_checked():
    with pytest.raises(ValueError, match="width"):
        active_force_length(1.0, width=0.0)
    with pytest.raises(ValueError, match="flen must be finite and > 1"):
        force_velocity(0.0, flen=1.0)
    with pytest.raises(ValueError, match=r"in \[0, flen=1.4\)"):
        force_velocity_inverse(1.4)
    with pytest.raises(ValueError, match=r"in \[0, flen"):
        force_velocity_inverse(-0.1)
    with pytest.raises(ValueError, match="f_toe must be in"):
        tendon_force_strain(0.01, f_toe=1.2)


# ---- path geometry ---------------------------------------------------------------------------


@pytest.mark.parametrize("n_points", [2, 4])
def test_path_geometry_derivatives(n_points, rng):
    x, v = random_path(rng, n_points)
    geo = PathGeometry.of(x, v)
    assert np.allclose(
        geo.gradient,
        fd_jacobian(lambda y: np.array([PathGeometry.of(y).length]), x).reshape(n_points, 3),
        atol=1e-8,
    )
    assert np.allclose(
        geo.hessian, fd_jacobian(lambda y: PathGeometry.of(y).gradient, x), atol=1e-6
    )
    rate = fd_jacobian(lambda y: np.array([PathGeometry.of(y, v).length_rate]), x).ravel()
    assert np.allclose(geo.rate_gradient, rate, atol=1e-6)
    # Ldot is the time derivative of L along x + t v (abs: the difference quotient's
    # round-off, eps_mach L / 1e-7 ~ 1e-9 m/s, matters when Ldot itself is nearly 0)
    assert geo.length_rate == pytest.approx(
        (PathGeometry.of(x + 1e-7 * v).length - PathGeometry.of(x - 1e-7 * v).length) / 2e-7,
        rel=1e-6,
        abs=1e-8,
    )


# ---- springs ---------------------------------------------------------------------------------


@pytest.mark.parametrize("n_points", [2, 3, 5])
def test_spring_jacobians_match_finite_differences(n_points, rng):
    spring = AxialSpring(stiffness=250.0, rest_length=0.2, damping=3.0)
    for _ in range(5):
        x, v = random_path(rng, n_points)
        r = spring.evaluate(x, v)
        assert relerr(r.stiffness, fd_jacobian(lambda y: spring.evaluate(y, v).forces, x)) < 1e-6
        assert relerr(r.damping, fd_jacobian(lambda w: spring.evaluate(x, w).forces, v)) < 1e-6


@pytest.mark.parametrize("n_points", [2, 4])
def test_undamped_spring_force_is_minus_energy_gradient(n_points, rng):
    spring = AxialSpring(stiffness=80.0, rest_length=0.1)
    x, _ = random_path(rng, n_points)
    r = spring.evaluate(x)
    grad = fd_jacobian(lambda y: np.array([spring.energy(y)]), x, eps=1e-6).reshape(n_points, 3)
    assert np.allclose(r.forces, -grad, rtol=1e-7, atol=1e-9)
    # and the stiffness is minus the energy Hessian: symmetric
    assert np.allclose(r.stiffness, r.stiffness.T, atol=1e-10)
    assert np.all(r.damping == 0.0)


def test_two_point_spring_by_hand():
    spring = AxialSpring(stiffness=100.0, rest_length=1.0, damping=2.0)
    x = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    v = np.array([[0.0, 0.0, 0.0], [0.5, 0.3, 0.0]])
    r = spring.evaluate(x, v)
    assert r.length == 2.0 and r.length_rate == 0.5
    assert r.tension == pytest.approx(100.0 * 1.0 + 2.0 * 0.5)
    assert np.allclose(r.forces, [[101.0, 0, 0], [-101.0, 0, 0]])
    kaa = PathForces.block(r.stiffness, 0, 0)
    # axial: -k; lateral: -T/L (string tension), plus the rate term -c (v_lateral/L) along u
    assert kaa[0, 0] == pytest.approx(-100.0) and kaa[1, 1] == pytest.approx(-101.0 / 2.0)
    assert kaa[0, 1] == pytest.approx(-2.0 * 0.3 / 2.0)
    assert np.allclose(PathForces.block(r.damping, 0, 1), np.diag([2.0, 0.0, 0.0]))


@pytest.mark.parametrize("n_points", [2, 3, 5])
def test_newtons_third_law(n_points, rng):
    spring = AxialSpring(stiffness=50.0, rest_length=0.05, damping=1.0)
    muscle = ThelenMuscle(ThelenParameters(300.0, 0.1, 0.15, pennation_angle=0.1), activation=0.7)
    for element in (spring, muscle):
        x, v = random_path(rng, n_points)
        f = element.evaluate(x, v).forces
        assert np.allclose(f.sum(axis=0), 0.0, atol=1e-12 * np.abs(f).max())
        assert np.allclose(np.cross(x, f).sum(axis=0), 0.0, atol=1e-11 * np.abs(f).max())
        if n_points == 2:  # along the line, pulling together
            d = x[1] - x[0]
            assert np.allclose(np.cross(f[0], d), 0.0, atol=1e-12 * np.abs(f).max())
            assert np.dot(f[0], d) > 0 or element is spring
        # each via point is pulled along the bisector of its two segments
        for i in range(1, n_points - 1):
            u0 = (x[i - 1] - x[i]) / np.linalg.norm(x[i - 1] - x[i])
            u1 = (x[i + 1] - x[i]) / np.linalg.norm(x[i + 1] - x[i])
            assert np.allclose(np.cross(f[i], u0 + u1), 0.0, atol=1e-10 * np.abs(f).max())


def test_tension_only_spring_is_slack_when_short(rng):
    """A ligament: no force and no energy below its rest length, the linear spring above."""
    ligament = AxialSpring(stiffness=100.0, rest_length=1.0, damping=2.0, tension_only=True)
    spring = AxialSpring(stiffness=100.0, rest_length=1.0, damping=2.0)
    x = np.array([[0.0, 0.0, 0.0], [0.8, 0.0, 0.0]])
    v = np.array([[0.0, 0.0, 0.0], [-0.5, 0.0, 0.0]])
    r = ligament.evaluate(x, v)
    assert r.tension == 0.0 and not r.forces.any() and not r.stiffness.any()
    assert not r.damping.any() and ligament.energy(x) == 0.0
    x[1, 0] = 1.3
    taut, linear = ligament.evaluate(x, v), spring.evaluate(x, v)
    assert np.array_equal(taut.forces, linear.forces)
    assert np.array_equal(taut.stiffness, linear.stiffness)
    assert ligament.energy(x) == pytest.approx(0.5 * 100.0 * 0.3**2)
    with pytest.raises(TypeError, match="tension_only must be True or False"):
        AxialSpring(1.0, tension_only="yes")
    with pytest.raises(ValueError, match="toe region needs tension_only"):
        AxialSpring(1.0, toe=0.1)


@pytest.mark.parametrize("stretch", [0.02, 0.07, 0.3])
def test_ligament_toe_region_is_smooth_and_a_gradient(stretch, rng):
    """Blankevoort's toe (t = 0.1): inside it and beyond, the force is minus the energy's
    gradient and the Jacobians match finite differences; T and dT/dL are continuous at
    d = t (k t / 2 and k on both sides)."""
    ligament = AxialSpring(200.0, rest_length=1.0, damping=3.0, tension_only=True, toe=0.1)
    x = np.array([[0.0, 0.0, 0.0], [1.0 + stretch, 0.0, 0.0]]) + 1e-3 * rng.standard_normal((2, 3))
    v = rng.standard_normal((2, 3))
    r = ligament.evaluate(x, v)
    assert relerr(r.stiffness, fd_jacobian(lambda y: ligament.evaluate(y, v).forces, x)) < 1e-6
    assert relerr(r.damping, fd_jacobian(lambda w: ligament.evaluate(x, w).forces, v)) < 1e-6
    grad = fd_jacobian(lambda y: np.array([ligament.energy(y)]), x, eps=1e-7).reshape(2, 3)
    assert np.allclose(ligament.evaluate(x).forces, -grad, rtol=1e-6, atol=1e-8)
    below, above = ligament.tension(1.1 - 1e-12), ligament.tension(1.1 + 1e-12)
    assert below[0] == pytest.approx(above[0]) == pytest.approx(200.0 * 0.05)
    assert below[1] == pytest.approx(above[1]) == pytest.approx(200.0)


# ---- Thelen muscle ---------------------------------------------------------------------------


def test_rigid_tendon_isometric_force_at_optimal_length():
    f0, l0, lts = 500.0, 0.08, 0.12
    for alpha0 in (0.0, 0.3):
        m = ThelenMuscle(ThelenParameters(f0, l0, lts, pennation_angle=alpha0), activation=1.0)
        x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, lts + l0 * math.cos(alpha0)]])
        r = m.evaluate(x)
        assert r.fiber.length == pytest.approx(l0, rel=1e-14)
        assert r.fiber.pennation_angle == pytest.approx(alpha0, abs=1e-7)
        assert r.tension == pytest.approx(f0 * math.cos(alpha0), rel=1e-13)
        assert np.allclose(r.forces[0], [0, 0, r.tension])
    # slack path: no force
    assert m.evaluate(np.array([[0.0, 0, 0], [0.0, 0, 0.9 * lts]])).tension == 0.0


def test_rigid_tendon_force_composition():
    """T = F0 (a f_L f_V + f_PE) cos(alpha) with l_M cos(alpha) = L - lTS, v_M = cos(alpha) Ldot."""
    p = ThelenParameters(400.0, 0.1, 0.2, pennation_angle=0.25)
    m = ThelenMuscle(p, activation=0.45)
    length, rate = 0.33, -0.4
    t, _, _, fiber = m.tension(length, rate)
    h = 0.1 * math.sin(0.25)
    lm = math.hypot(length - 0.2, h)
    c = (length - 0.2) / lm
    vn = c * rate / ((0.25 + 0.75 * 0.45) * 10.0 * 0.1)
    expected = (
        400.0
        * (
            0.45 * active_force_length(lm / 0.1) * force_velocity(vn)
            + passive_force_length(lm / 0.1)
        )
        * c
    )
    assert t == pytest.approx(expected, rel=1e-14)
    assert fiber.velocity == pytest.approx(c * rate)


@pytest.mark.parametrize("n_points", [2, 4])
@pytest.mark.parametrize("alpha0", [0.0, 0.35])
def test_rigid_muscle_jacobians_match_finite_differences(n_points, alpha0, rng):
    p = ThelenParameters(300.0, 0.1, 0.15, pennation_angle=alpha0)
    checked = 0
    while checked < 6:
        x, v = random_path(rng, n_points, length=rng.uniform(0.2, 0.33))
        m = ThelenMuscle(p, activation=rng.uniform(0.05, 1.0))
        r = m.evaluate(x, v)
        vn = r.fiber.velocity / ((0.25 + 0.75 * m.activation) * 1.0)
        if abs(vn) < 1e-3 or vn < -1 + 1e-3 or abs(r.fiber.length / 0.1 - 1) < 1e-3:
            continue  # skip the curves' kinks
        assert relerr(r.stiffness, fd_jacobian(lambda y: m.evaluate(y, v).forces, x)) < 1e-5
        # eps 1e-5: at fast lengthening (v_n ~ 3) the damping is ~1e-4 of the forces, and the
        # round-off of a 1e-7 difference (eps_mach |f| / eps) would be 1e-5 of it
        assert relerr(r.damping, fd_jacobian(lambda w: m.evaluate(x, w).forces, v, 1e-5)) < 1e-5
        assert np.abs(r.damping).max() > 0  # force-velocity gives damping
        checked += 1


def test_muscle_without_force_velocity_has_no_damping(rng):
    m = ThelenMuscle(ThelenParameters(300.0, 0.1, 0.15, force_velocity=False), activation=1.0)
    x, v = random_path(rng, 2, length=0.26)
    r = m.evaluate(x, v)
    assert np.all(r.damping == 0.0) and r.fiber.force_velocity == 1.0


def test_elastic_tendon_static_equilibrium():
    p = ThelenParameters(600.0, 0.1, 0.25, pennation_angle=0.2)
    m = ThelenMuscle(p, tendon="elastic", activation=0.8)
    x = np.array([[0.0, 0.0, 0.0], [0.36, 0.0, 0.0]])
    fiber = m.initialize_fiber(x)
    assert m.fiber_length == fiber.length
    tendon = 600.0 * tendon_force_strain(fiber.tendon_strain)
    muscle = (
        600.0
        * (0.8 * active_force_length(fiber.length / 0.1) + passive_force_length(fiber.length / 0.1))
        * fiber.cos_pennation
    )
    assert tendon == pytest.approx(muscle, rel=1e-10)
    # the geometry closes: L = lT + l_M cos(alpha)
    assert 0.25 * (1 + fiber.tendon_strain) + fiber.length * fiber.cos_pennation == pytest.approx(
        0.36
    )
    # a stiff tendon approaches the rigid-tendon force
    stiff = ThelenParameters(600.0, 0.1, 0.25, pennation_angle=0.2, fmax_tendon_strain=1e-5)
    rigid = ThelenMuscle(stiff, activation=0.8).evaluate(x).tension
    e = ThelenMuscle(stiff, tendon="elastic", activation=0.8)
    e.initialize_fiber(x)
    assert e.evaluate(x, dt=1e-3).tension == pytest.approx(rigid, rel=1e-3)


@pytest.mark.parametrize("n_points", [2, 3])
def test_elastic_muscle_stiffness_matches_finite_differences(n_points, rng):
    p = ThelenParameters(600.0, 0.1, 0.25, pennation_angle=0.2)
    for _ in range(4):
        x, v = random_path(rng, n_points, length=0.355)
        m = ThelenMuscle(p, tendon="elastic", activation=rng.uniform(0.2, 1.0))
        m.initialize_fiber(x)
        y = x + 0.003 * rng.normal(size=x.shape)  # the step moved the points
        dt = 10 ** rng.uniform(-4, -2)
        r = m.evaluate(y, v, dt)
        assert not r.fiber.clamped and not r.fiber.slack
        assert (
            relerr(r.stiffness, fd_jacobian(lambda z: m.evaluate(z, v, dt).forces, y, 1e-8)) < 1e-5
        )
        assert np.all(r.damping == 0.0)


def test_elastic_tendon_commit_and_limits():
    p = ThelenParameters(600.0, 0.1, 0.25)
    m = ThelenMuscle(p, tendon="elastic", activation=1.0)
    x = np.array([[0.0, 0.0, 0.0], [0.35, 0.0, 0.0]])
    with pytest.raises(RuntimeError, match="initialize_fiber"):
        m.evaluate(x, dt=1e-3)
    m.initialize_fiber(x)
    with pytest.raises(ValueError, match="needs the step size dt"):
        m.evaluate(x)
    # a fast stretch: the viscous fiber hardly moves within a tiny step, the tendon takes it
    y = x.copy()
    y[1, 0] += 0.002
    dt = 1e-6
    r = m.evaluate(y, dt=dt)
    tendon_k = 600.0 * tendon_force_strain(r.fiber.tendon_strain, derivative=True)[1] / 0.25
    assert r.dtension_dlength == pytest.approx(tendon_k, rel=2e-2)
    # holding the stretch, the fiber creeps toward the static equilibrium
    lengths = []
    for _ in range(400):
        r = m.evaluate(y, dt=1e-3)
        m.commit(r)
        lengths.append(r.fiber.length)
    static = ThelenMuscle(p, tendon="elastic", activation=1.0)
    target = static.initialize_fiber(y).length
    assert abs(lengths[0] - target) > 1e-3 * target
    assert lengths[-1] == pytest.approx(target, rel=1e-4)
    assert np.all(np.diff(lengths) > -1e-15)
    # slack path: no force
    r = m.evaluate(np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0]]), dt=1e-3)
    assert r.tension == 0.0 and r.fiber.slack


def test_activation_dynamics_match_thelen_closed_form():
    """da/dt = (u - a)/tau: t(a) = tau_act (-1.5 a - 2 ln(1 - a)) from 0 up to u = 1 and
    2 ln(a/(0.5 + 1.5 a)) = 2 ln(a0/(0.5 + 1.5 a0)) - t/tau_deact down to u = 0."""
    p = ThelenParameters(100.0, 0.1, 0.2)
    ta, td = p.activation_time_constant, p.deactivation_time_constant

    def rise(dt, target):
        m = ThelenMuscle(p, activation=0.0, excitation=1.0)
        t_end = ta * (-1.5 * target - 2 * math.log(1 - target))
        n = round(t_end / dt)
        for _ in range(n):
            m.update_activation(t_end / n)
        return m.activation

    errors = [abs(rise(dt, 0.9) - 0.9) for dt in (1e-3, 5e-4, 2.5e-4)]
    assert errors[-1] < 1e-5
    assert errors[0] / errors[1] > 3.0 and errors[1] / errors[2] > 3.0  # second order

    m = ThelenMuscle(p, activation=1.0, excitation=0.0)
    t_end, a_prev = 0.1, 1.0
    for _ in range(400):
        m.update_activation(t_end / 400)
        assert 0.0 <= m.activation <= a_prev  # monotone, no overshoot
        a_prev = m.activation
    a = m.activation
    assert 2 * math.log(a / (0.5 + 1.5 * a)) == pytest.approx(
        2 * math.log(1 / 2) - t_end / td, abs=1e-5
    )
    # the initial time constants are those of the paper (15 ms, 50 ms at a = 0 and 1 scaled)
    assert m.activation_time_constant(0.0, 1.0) == pytest.approx(0.5 * 0.015)
    assert m.activation_time_constant(1.0, 0.0) == pytest.approx(0.050 / 2.0)
    # a large step never overshoots the excitation and settles on it
    m = ThelenMuscle(p, activation=0.1, excitation=0.6)
    m.update_activation(10.0)
    assert m.activation == pytest.approx(0.6, abs=1e-12)


def test_excitation_equals_activation_without_dynamics():
    m = ThelenMuscle(ThelenParameters(100.0, 0.1, 0.2), activation_dynamics=False)
    m.set_excitation(0.35)
    assert m.activation == 0.35
    assert m.update_activation(0.01) == 0.35
    m.excitation = 0.9
    assert m.activation == 0.9
    floor = ThelenMuscle(ThelenParameters(100.0, 0.1, 0.2, min_activation=0.01), excitation=0.0)
    assert floor.activation == 0.01
    floor.update_activation(1.0)
    assert floor.activation == 0.01


# ---- bad input -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(stiffness=-1.0), "stiffness must be >= 0"),
        (dict(stiffness=1.0, rest_length=-0.1), "rest_length must be >= 0"),
        (dict(stiffness=1.0, damping=math.nan), "damping must be finite"),
        (dict(stiffness="10"), "stiffness must be a real number"),
    ],
)
def test_bad_spring_parameters(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        AxialSpring(**kwargs)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(max_isometric_force=0.0), "max_isometric_force must be > 0"),
        (dict(optimal_fiber_length=-0.1), "optimal_fiber_length must be > 0"),
        (dict(tendon_slack_length=-0.1), "tendon_slack_length must be >= 0"),
        (dict(pennation_angle=30.0), r"pennation_angle must be in \[0, pi/2\).*degrees"),
        (dict(pennation_angle=-0.1), "pennation_angle must be >= 0"),
        (dict(flen=0.9), "flen must be > 1"),
        (dict(af=0.0), "af must be > 0"),
        (dict(activation_time_constant=math.inf), "activation_time_constant must be finite"),
        (dict(tendon_f_toe=1.0), r"tendon_f_toe must be in \(0, 1\)"),
        (dict(min_activation=1.0), r"min_activation must be in \[0, 1\)"),
        (dict(force_velocity=1), "force_velocity must be True or False"),
    ],
)
def test_bad_muscle_parameters(kwargs, match):
    base = dict(max_isometric_force=100.0, optimal_fiber_length=0.1, tendon_slack_length=0.2)
    with pytest.raises((ValueError, TypeError), match=match):
        ThelenParameters(**{**base, **kwargs})


def test_bad_muscle_usage():
    p = ThelenParameters(100.0, 0.1, 0.2)
    with pytest.raises(ValueError, match="tendon must be 'rigid' or 'elastic'"):
        ThelenMuscle(p, tendon="stiff")
    with pytest.raises(ValueError, match="elastic tendon needs tendon_slack_length > 0"):
        ThelenMuscle(ThelenParameters(100.0, 0.1, 0.0), tendon="elastic")
    with pytest.raises(TypeError, match="params must be ThelenParameters"):
        ThelenMuscle({"max_isometric_force": 100.0})
    m = ThelenMuscle(p, name="styloglossus")
    with pytest.raises(
        ValueError, match=r"'styloglossus': excitation must be in \[0, 1\], got 1.5"
    ):
        m.set_excitation(1.5)
    with pytest.raises(ValueError, match="dt must be > 0"):
        m.update_activation(0.0)
    with pytest.raises(ValueError, match="initialize_fiber is for the elastic tendon"):
        m.initialize_fiber(np.zeros((2, 3)))


def test_bad_points():
    spring = AxialSpring(10.0)
    with pytest.raises(ValueError, match=r"\(n, 3\) array with n >= 2"):
        spring.evaluate(np.zeros(3))
    with pytest.raises(ValueError, match=r"\(n, 3\) array with n >= 2"):
        spring.evaluate(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="velocities has 3 points, the positions have 2"):
        spring.evaluate(np.eye(3)[:2], np.zeros((3, 3)))
    with pytest.raises(ValueError, match="positions must be finite"):
        spring.evaluate(np.array([[0.0, 0, 0], [math.nan, 0, 0]]))
    with pytest.raises(ValueError, match="path points 1 and 2 coincide"):
        spring.evaluate(np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]]))


@pytest.mark.parametrize("activation", [0.01, 0.4, 1.0])
def test_a_rigid_tendon_muscles_energy_is_the_potential_of_its_tension_at_rest(activation):
    """dW/dL = T(L, 0) at a fixed activation (statics' merit), over the slack, active and
    passive (l_M > l0) ranges; W = 0 while the path is slack."""
    muscle = ThelenMuscle(
        ThelenParameters(300.0, 0.1, 0.15, pennation_angle=0.2),
        activation=activation,
        activation_dynamics=False,
        excitation=activation,
    )
    assert muscle.conservative

    def path(length):
        return np.array([[0.0, 0.0, 0.0], [length, 0.0, 0.0]])

    assert muscle.energy(path(0.14)) == 0.0
    for length in (0.16, 0.21, 0.25, 0.31):
        slope = fd_slope(lambda L: muscle.energy(path(L)), length)
        assert slope == pytest.approx(muscle.tension(length)[0], rel=1e-6)


def test_an_elastic_tendon_muscle_has_no_energy():
    muscle = ThelenMuscle(ThelenParameters(300.0, 0.1, 0.15), tendon="elastic")
    assert not muscle.conservative
    with pytest.raises(InputError, match="elastic tendon has no energy"):
        muscle.energy(np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]]))
