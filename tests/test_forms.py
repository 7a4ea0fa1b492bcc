"""Tests of artifem.forms: energies, stresses and tangents against closed forms.

Each distinct material is compiled once (artifem.pointwise caches evaluators),
so the materials below are module constants reused by every test.
"""

import math

import numpy as np
import pytest
import ufl
from scipy.integrate import quad

import artifem as af  # first: orders dolfinx_solver before dolfinx
from artifem.forms import (
    BlemkerFiber,
    CombinedMaterial,
    LinearElastic,
    MooneyRivlin,
    NeoHookean,
    StVenantKirchhoff,
    fiber_stretch,
    green_lagrange,
    invariants,
    isochoric_invariants,
    jacobian,
    small_strain,
)
from artifem.errors import InputError, SolverError
from artifem.material_response import plot_stress_stretch, point_response, stress_stretch_curves
from artifem.pointwise import PointEvaluator, evaluator_for

I3 = np.eye(3)
A0_OBLIQUE = np.array([1.0, 0.3, 0.2]) / np.linalg.norm([1.0, 0.3, 0.2])
E1 = np.array([1.0, 0.0, 0.0])

NEO = NeoHookean(mu=2.0e3, lmbda=8.0e3)
SVK = StVenantKirchhoff.from_young_poisson(5.0e3, 0.3)
LINEAR = LinearElastic(mu=1.5e3, lmbda=4.0e3)
MR_FULL = MooneyRivlin(1037.0, C01=250.0, C11=120.0, C20=486.0, C02=80.0, kappa=2.0e4, bulk="log")
MR_TONGUE = MooneyRivlin.tongue()
FIBER = BlemkerFiber(1.0e5, optimal_stretch=1.1, stretch_star=1.3)
TONGUE_MUSCLE = CombinedMaterial(MR_TONGUE, BlemkerFiber(1.0e5))
MR_NEARLY_INCOMPRESSIBLE = MooneyRivlin(1037.0, C20=486.0, kappa=1.037e6)


# --- independent closed forms (numpy) --------------------------------------------------------


def blemker_fL(l):
    if 0.4 <= l <= 0.6:
        return 9.0 * (l - 0.4) ** 2
    if 0.6 < l <= 1.4:
        return 1.0 - 4.0 * (1.0 - l) ** 2
    if 1.4 < l <= 1.6:
        return 9.0 * (l - 1.6) ** 2
    return 0.0


def blemker_fP(l, P1, P2, l_star):
    if l <= 1.0:
        return 0.0
    if l < l_star:
        return P1 * (math.exp(P2 * (l - 1.0)) - 1.0)
    P3 = P1 * P2 * math.exp(P2 * (l_star - 1.0))
    P4 = P1 * (math.exp(P2 * (l_star - 1.0)) - 1.0) - P3 * l_star
    return P3 * l + P4


def fiber_closed_form(m, F, a0, excitation):
    c = m.optimal_stretch
    lam = np.linalg.norm(F @ a0)

    def stress(s):
        return m.max_stress * (
            excitation * blemker_fL(s / c) + blemker_fP(s / c, m.P1, m.P2, m.stretch_star)
        )

    kinks = [c * b for b in (0.4, 0.6, 1.0, 1.4, 1.6, m.stretch_star)]
    psi = quad(
        stress, 1.0, lam, points=[k for k in kinks if min(1, lam) < k < max(1, lam)], epsabs=1e-10
    )[0]
    return psi, stress(lam) * np.outer(F @ a0, a0) / lam


def neo_closed_form(m, F):
    J = np.linalg.det(F)
    FinvT = np.linalg.inv(F).T
    psi = 0.5 * m.mu * (np.trace(F.T @ F) - 3) - m.mu * np.log(J) + 0.5 * m.lmbda * np.log(J) ** 2
    return psi, m.mu * (F - FinvT) + m.lmbda * np.log(J) * FinvT


def svk_closed_form(m, F):
    E = 0.5 * (F.T @ F - I3)
    S = m.lmbda * np.trace(E) * I3 + 2 * m.mu * E
    return 0.5 * m.lmbda * np.trace(E) ** 2 + m.mu * np.trace(E @ E), F @ S


def linear_closed_form(m, F):
    eps = 0.5 * (F + F.T) - I3
    return (
        0.5 * m.lmbda * np.trace(eps) ** 2 + m.mu * np.trace(eps @ eps),
        m.lmbda * np.trace(eps) * I3 + 2 * m.mu * eps,
    )


def mooney_rivlin_closed_form(m, F):
    """P = 2 F dW/dC with the invariant derivatives written out."""
    C = F.T @ F
    Cinv = np.linalg.inv(C)
    J = np.linalg.det(F)
    I1 = np.trace(C)
    I2 = 0.5 * (I1**2 - np.trace(C @ C))
    I1b, I2b = J ** (-2 / 3) * I1, J ** (-4 / 3) * I2
    d1, d2 = I1b - 3, I2b - 3
    W1 = m.C10 + m.C11 * d2 + 2 * m.C20 * d1
    W2 = m.C01 + m.C11 * d1 + 2 * m.C02 * d2
    dI1b = J ** (-2 / 3) * (I3 - I1 / 3 * Cinv)
    dI2b = J ** (-4 / 3) * (I1 * I3 - C - 2 / 3 * I2 * Cinv)
    if m.bulk == "quadratic":
        U, dU = 0.5 * m.kappa * (J - 1) ** 2, m.kappa * (J - 1)
    else:
        U, dU = 0.5 * m.kappa * np.log(J) ** 2, m.kappa * np.log(J) / J
    S = 2 * W1 * dI1b + 2 * W2 * dI2b + dU * J * Cinv
    psi = m.C10 * d1 + m.C01 * d2 + m.C11 * d1 * d2 + m.C20 * d1**2 + m.C02 * d2**2 + U
    return psi, F @ S


def tongue_muscle_closed_form(F, a0, excitation):
    psi_m, P_m = mooney_rivlin_closed_form(MR_TONGUE, F)
    psi_f, P_f = fiber_closed_form(TONGUE_MUSCLE.parts[1], F, a0, excitation)
    return psi_m + psi_f, P_m + P_f


# (id, material, fields, closed form (F, fields) -> (psi, P))
CASES = [
    ("neo_hookean", NEO, {}, lambda F: neo_closed_form(NEO, F)),
    ("st_venant_kirchhoff", SVK, {}, lambda F: svk_closed_form(SVK, F)),
    ("linear_elastic", LINEAR, {}, lambda F: linear_closed_form(LINEAR, F)),
    ("mooney_rivlin_full_log", MR_FULL, {}, lambda F: mooney_rivlin_closed_form(MR_FULL, F)),
    ("mooney_rivlin_tongue", MR_TONGUE, {}, lambda F: mooney_rivlin_closed_form(MR_TONGUE, F)),
    (
        "blemker_fiber",
        FIBER,
        {"a0": A0_OBLIQUE, "excitation": 0.4},
        lambda F: fiber_closed_form(FIBER, F, A0_OBLIQUE, 0.4),
    ),
    (
        "mooney_rivlin_plus_fiber",
        TONGUE_MUSCLE,
        {"a0": A0_OBLIQUE, "excitation": 0.7},
        lambda F: tongue_muscle_closed_form(F, A0_OBLIQUE, 0.7),
    ),
]
CASE_IDS = [case[0] for case in CASES]

# A general, well-conditioned deformation (det > 0); |F a0| / 1.1 = 1.06 stays away from Blemker's
# kinks.
F_GENERAL = np.array([[1.17, 0.08, -0.05], [0.03, 0.92, 0.06], [-0.04, 0.02, 1.05]])
SHEAR = I3 + 0.3 * np.outer(E1, [0.0, 1.0, 0.0])
DEFORMATIONS = {
    "uniaxial_tension": np.diag([1.3, 0.88, 0.88]),
    "uniaxial_compression": np.diag([0.8, 1.1, 1.1]),
    "simple_shear": SHEAR,
    "general": F_GENERAL,
}


def rotation(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.cross(np.eye(3), axis)
    return I3 + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


R = rotation([1.0, 2.0, 3.0], 0.7)


# --- (1) stresses and energies against closed forms --------------------------------------------


@pytest.mark.parametrize("deformation", DEFORMATIONS)
@pytest.mark.parametrize("name, material, fields, closed_form", CASES, ids=CASE_IDS)
def test_point_response_matches_closed_form(name, material, fields, closed_form, deformation):
    F = DEFORMATIONS[deformation]
    psi, P, dPdF = point_response(material, F, **fields)
    psi_exact, P_exact = closed_form(F)
    scale = np.abs(P_exact).max() + 1.0
    assert psi == pytest.approx(psi_exact, rel=1e-9, abs=1e-9 * scale)
    np.testing.assert_allclose(P, P_exact, rtol=1e-9, atol=1e-10 * scale)
    assert P.shape == (3, 3) and dPdF.shape == (3, 3, 3, 3)


@pytest.mark.parametrize("l", [0.3, 0.5, 0.8, 1.0, 1.05, 1.2, 1.35, 1.5, 1.7])
def test_blemker_nominal_fiber_stress_on_every_branch(l):
    """Along a0 = e1: P11 = max_stress (a f_L(lambda/c) + f_P(lambda/c)), lambda = c l."""
    excitation = 0.6
    lam = FIBER.optimal_stretch * l
    F = np.diag([lam, lam**-0.5, lam**-0.5])
    _, P, _ = point_response(FIBER, F, a0=E1, excitation=excitation)
    expected = FIBER.max_stress * (
        excitation * blemker_fL(l) + blemker_fP(l, FIBER.P1, FIBER.P2, FIBER.stretch_star)
    )
    assert P[0, 0] == pytest.approx(expected, rel=1e-10, abs=1e-6)
    assert FIBER.fiber_stress(lam, excitation) == pytest.approx(expected, rel=1e-12, abs=1e-6)
    np.testing.assert_allclose(np.delete(P.ravel(), 0), 0.0, atol=1e-8)


@pytest.mark.parametrize("l", [0.3, 0.5, 0.8, 1.2, 1.45, 1.55, 1.7])
def test_blemker_energy_is_the_integral_of_the_fiber_stress_on_every_branch(l):
    """W(lambda) = int_1^lambda max_stress (a f_L(s/c) + f_P(s/c)) ds by quadrature, beyond
    l = 1.4 and 1.6 too (the closed-form antiderivative's constants at the breakpoints)."""
    excitation = 0.6
    lam = FIBER.optimal_stretch * l
    F = np.diag([lam, lam**-0.5, lam**-0.5])
    psi, _, _ = point_response(FIBER, F, a0=E1, excitation=excitation)
    psi_exact, _ = fiber_closed_form(FIBER, F, E1, excitation)
    assert abs(psi_exact) > 1e2  # a real energy on every branch
    assert psi == pytest.approx(psi_exact, rel=1e-9)


def test_blemker_passive_curve_is_C1_at_stretch_star():
    from artifem.forms import passive_force_length

    l_star, h = 1.3, 1e-7
    values = passive_force_length([l_star - h, l_star, l_star + h], stretch_star=l_star)
    assert values[2] - values[1] == pytest.approx(values[1] - values[0], rel=1e-5)
    assert values[1] == pytest.approx(0.05 * (math.exp(6.6 * 0.3) - 1.0), rel=1e-12)


def test_blemker_passive_false_drops_passive_stress():
    fiber = BlemkerFiber(2.0e4, passive=False)
    psi, P, _ = point_response(fiber, np.diag([1.3, 1.0, 1.0]), a0=E1, excitation=0.0)
    assert psi == 0.0 and np.all(P == 0.0)


# --- (2) tangent against finite differences ---------------------------------------------------


@pytest.mark.parametrize("name, material, fields, closed_form", CASES, ids=CASE_IDS)
def test_tangent_matches_central_differences(name, material, fields, closed_form):
    evaluate = evaluator_for(material, **fields)
    _, _, dPdF = evaluate(F_GENERAL, **fields)
    h = 1e-6
    fd = np.empty((3, 3, 3, 3))
    for k in range(3):
        for L in range(3):
            dF = np.zeros((3, 3))
            dF[k, L] = h
            fd[:, :, k, L] = (
                evaluate(F_GENERAL + dF, **fields)[1] - evaluate(F_GENERAL - dF, **fields)[1]
            ) / (2 * h)
    np.testing.assert_allclose(dPdF, fd, rtol=1e-6, atol=1e-7 * np.abs(dPdF).max())
    # a hyperelastic tangent has major symmetry A[iJkL] = A[kLiJ]
    np.testing.assert_allclose(dPdF, dPdF.transpose(2, 3, 0, 1), atol=1e-9 * np.abs(dPdF).max())


# --- (3) rigid rotations ----------------------------------------------------------------------

ROTATION_CASES = [
    (name, m, dict(f, excitation=0.0) if "excitation" in f else f) for name, m, f, _ in CASES
]


@pytest.mark.parametrize("name, material, fields", ROTATION_CASES, ids=CASE_IDS)
def test_rigid_rotation_is_stress_free_except_linear_elastic(name, material, fields):
    psi, P, _ = point_response(material, R, **fields)
    if material is LINEAR:
        # eps = sym(R) - I != 0: small-strain elasticity sees a rotation as strain, with its
        # closed-form energy mu eps:eps + lambda/2 (tr eps)^2 and stress 2 mu eps + lambda tr(eps) I
        eps = 0.5 * (R + R.T) - np.eye(3)
        mu, lmbda = LINEAR.mu, LINEAR.lmbda
        assert np.abs(eps).max() > 0.1  # a rotation large enough to matter
        assert psi == pytest.approx(
            mu * np.sum(eps * eps) + 0.5 * lmbda * np.trace(eps) ** 2, rel=1e-12
        )
        expected = 2 * mu * eps + lmbda * np.trace(eps) * np.eye(3)
        np.testing.assert_allclose(P, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    else:
        assert psi == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(P, 0.0, atol=1e-8)


@pytest.mark.parametrize(
    "name, material, fields, closed_form", CASES[:2] + CASES[3:], ids=CASE_IDS[:2] + CASE_IDS[3:]
)
def test_frame_indifference(name, material, fields, closed_form):
    """psi(R F) = psi(F), P(R F) = R P(F) (active fibers included)."""
    psi, P, _ = point_response(material, F_GENERAL, **fields)
    psi_rotated, P_rotated, _ = point_response(material, R @ F_GENERAL, **fields)
    assert psi_rotated == pytest.approx(psi, rel=1e-10)
    np.testing.assert_allclose(P_rotated, R @ P, rtol=1e-9, atol=1e-9 * np.abs(P).max())


def test_active_fiber_at_rest_length_carries_tension():
    _, P, _ = point_response(TONGUE_MUSCLE, I3, a0=E1, excitation=0.5)
    assert P[0, 0] == pytest.approx(0.5 * 1.0e5, rel=1e-12)


# --- (4) validation ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "build, match",
    [
        (lambda: MooneyRivlin(1037.0, kappa=-5.0), r"MooneyRivlin: kappa must be > 0, got -5\.0"),
        (lambda: MooneyRivlin(1037.0, kappa=0.0), "kappa"),
        (lambda: MooneyRivlin(-1.0, kappa=10.0), "MooneyRivlin: C10 must be >= 0"),
        (lambda: MooneyRivlin(0.0, kappa=10.0), r"C10 \+ C01 must be > 0"),
        (lambda: MooneyRivlin(1.0, C20=-2.0, kappa=10.0), "C20"),
        (lambda: MooneyRivlin(1.0, C02=-2.0, kappa=10.0), "C02"),
        (lambda: MooneyRivlin(1.0, C11=float("nan"), kappa=10.0), "C11 must be finite"),
        (lambda: MooneyRivlin(1.0, kappa=10.0, bulk="cubic"), "bulk"),
        (lambda: NeoHookean(0.0, 1.0), "NeoHookean: mu must be > 0, got 0.0"),
        (lambda: NeoHookean(1.0, -1.0), "NeoHookean: lmbda"),
        (lambda: StVenantKirchhoff(-1.0, 1.0), "StVenantKirchhoff: mu"),
        (lambda: LinearElastic(1.0, float("inf")), "LinearElastic: lmbda must be finite"),
        (lambda: NeoHookean.from_young_poisson(-1.0, 0.3), "NeoHookean: E must be > 0"),
        (lambda: LinearElastic.from_young_poisson(1.0, 0.5), "LinearElastic: nu"),
        (lambda: BlemkerFiber(0.0), "BlemkerFiber: max_stress must be > 0"),
        (lambda: BlemkerFiber(1.0, optimal_stretch=-1.0), "optimal_stretch"),
        (lambda: BlemkerFiber(1.0, P1=-0.1), "P1"),
        (lambda: BlemkerFiber(1.0, P2=-0.1), "P2"),
        (lambda: BlemkerFiber(1.0, stretch_star=1.0), "stretch_star must be > 1"),
        (lambda: CombinedMaterial(), "at least one part"),
        (lambda: CombinedMaterial(NEO, object()), "part 1"),
    ],
)
def test_invalid_parameters_raise(build, match):
    """artifem's own InputError (a ValueError), caught by ``except af.ArtifemError``."""
    with pytest.raises(InputError, match=match) as info:
        build()
    assert isinstance(info.value, af.ArtifemError) and isinstance(info.value, ValueError)


def test_young_poisson_conversion():
    m = NeoHookean.from_young_poisson(3.0, 0.25)
    assert m.mu == pytest.approx(1.2) and m.lmbda == pytest.approx(1.2)


def test_bad_fields_are_rejected():
    with pytest.raises(InputError, match="no part accepts"):
        TONGUE_MUSCLE.strain_energy(ufl.Identity(3), a0=ufl.as_vector(E1), excitation=0.1, typo=1.0)
    evaluate = evaluator_for(FIBER, a0=E1, excitation=0.1)
    with pytest.raises(ValueError, match="expected fields"):
        evaluate(I3, a0=E1)
    with pytest.raises(ValueError, match="shape"):
        evaluate(I3, a0=np.ones(2), excitation=0.1)
    with pytest.raises(ValueError, match="3x3"):
        evaluate(np.eye(2), a0=E1, excitation=0.1)


def test_evaluators_are_compiled_once():
    assert evaluator_for(NEO) is evaluator_for(NEO)
    assert evaluator_for(FIBER, a0=E1, excitation=0.2) is evaluator_for(
        FIBER, a0=A0_OBLIQUE, excitation=0.9
    )
    assert isinstance(evaluator_for(NEO), PointEvaluator)


# --- (5) kinematics (UFL evaluated on literal matrices, no mesh) ------------------------------


def test_kinematics_on_known_F():
    F = ufl.as_matrix(F_GENERAL.tolist())
    C = F_GENERAL.T @ F_GENERAL
    I1, I2, I3_ = (float(v) for v in invariants(F))
    assert I1 == pytest.approx(np.trace(C))
    assert I2 == pytest.approx(0.5 * (np.trace(C) ** 2 - np.trace(C @ C)))
    assert I3_ == pytest.approx(np.linalg.det(C))
    J = np.linalg.det(F_GENERAL)
    assert float(jacobian(F)) == pytest.approx(J)
    I1b, I2b = (float(v) for v in isochoric_invariants(F))
    assert I1b == pytest.approx(J ** (-2 / 3) * I1) and I2b == pytest.approx(J ** (-4 / 3) * I2)
    assert float(fiber_stretch(F, ufl.as_vector(A0_OBLIQUE.tolist()))) == pytest.approx(
        np.linalg.norm(F_GENERAL @ A0_OBLIQUE)
    )
    E = green_lagrange(F)
    eps = small_strain(F)
    for i in range(3):
        for j in range(3):
            assert float(E[i, j]) == pytest.approx(0.5 * (C - I3)[i, j], abs=1e-14)
            assert float(eps[i, j]) == pytest.approx(
                (0.5 * (F_GENERAL + F_GENERAL.T) - I3)[i, j], abs=1e-14
            )


def test_isochoric_invariants_are_scale_invariant():
    F = ufl.as_matrix(F_GENERAL.tolist())
    scaled = ufl.as_matrix((1.7 * F_GENERAL).tolist())
    for plain, dilated in zip(isochoric_invariants(F), isochoric_invariants(scaled)):
        assert float(dilated) == pytest.approx(float(plain), rel=1e-13)
    assert float(jacobian(scaled)) == pytest.approx(1.7**3 * np.linalg.det(F_GENERAL))
    # and equal 3 for a pure dilation
    assert [float(v) for v in isochoric_invariants(2.5 * ufl.Identity(3))] == pytest.approx(
        [3.0, 3.0]
    )


# --- (6) stress-stretch curves ----------------------------------------------------------------

STRETCHES = np.linspace(0.7, 1.6, 10)


@pytest.fixture(scope="module")
def nearly_incompressible_curves():
    return stress_stretch_curves(MR_NEARLY_INCOMPRESSIBLE, STRETCHES)


def test_uniaxial_curve_is_traction_free_and_nearly_isochoric(nearly_incompressible_curves):
    uniaxial = nearly_incompressible_curves["uniaxial"]
    scale = np.abs(uniaxial["P11"]).max()
    assert scale > 100.0
    np.testing.assert_allclose(uniaxial["P22"], 0.0, atol=1e-9 * scale)
    np.testing.assert_allclose(uniaxial["P33"], 0.0, atol=1e-9 * scale)
    np.testing.assert_allclose(uniaxial["lateral_stretch_2"], STRETCHES**-0.5, rtol=2e-3)
    np.testing.assert_allclose(
        uniaxial["lateral_stretch_3"], uniaxial["lateral_stretch_2"], rtol=1e-10
    )
    # P11 of the solved state is the point response at that state
    k = 7
    F = np.diag([STRETCHES[k], uniaxial["lateral_stretch_2"][k], uniaxial["lateral_stretch_3"][k]])
    assert point_response(MR_NEARLY_INCOMPRESSIBLE, F)[1][0, 0] == pytest.approx(uniaxial["P11"][k])
    assert np.all(np.diff(uniaxial["P11"]) > 0)


def test_equibiaxial_and_shear_curves(nearly_incompressible_curves):
    biaxial = nearly_incompressible_curves["equibiaxial"]
    np.testing.assert_allclose(biaxial["P33"], 0.0, atol=1e-9 * np.abs(biaxial["P11"]).max())
    # J = l^2 t3 ~ 1; biaxial stresses reach ~1e4 Pa, so with kappa ~ 1e6 Pa J drifts by ~1 %
    np.testing.assert_allclose(biaxial["lateral_stretch_3"], STRETCHES**-2.0, rtol=2e-2)
    shear = nearly_incompressible_curves["simple_shear"]
    np.testing.assert_allclose(shear["shear"], STRETCHES - 1.0)
    # small-strain shear modulus 2 (C10 + C01)
    small = np.argmin(np.abs(shear["shear"] - 0.1))
    assert shear["P12"][small] / shear["shear"][small] == pytest.approx(2 * 1037.0, rel=0.05)


def test_curves_plot_to_png(nearly_incompressible_curves, tmp_path):
    path = tmp_path / "curves.png"
    plot_stress_stretch(nearly_incompressible_curves, path, title="Mooney-Rivlin")
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_fiber_curves_need_a_matrix():
    curves = stress_stretch_curves(TONGUE_MUSCLE, [0.9, 1.0, 1.2], a0=E1, excitation=0.5)
    assert curves["uniaxial"]["P11"][1] == pytest.approx(0.5e5, rel=1e-9)
    np.testing.assert_allclose(curves["uniaxial"]["P22"], 0.0, atol=1e-6)
    with pytest.raises(SolverError, match="CombinedMaterial"):
        stress_stretch_curves(FIBER, [1.1], a0=E1, excitation=0.5)
