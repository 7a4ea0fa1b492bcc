"""Reduced bases (artifem.reduction.bases): linear modes, extended modes, POD.

Serial tests (the basis code is written for owned dofs but only tested in serial).
"""

import numpy as np
import pytest
import scipy.linalg

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.fem_body import FemBody
from artifem.forms import LinearElastic, NeoHookean
from artifem.reduction.bases import (
    body_mass,
    extended_modes,
    linear_mode_residuals,
    linear_modes,
    mass_orthonormality_error,
    pod_basis,
)

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial tests")

E, NU, RHO = 1.0e6, 0.3, 1000.0
BETA_L = (1.8751041, 4.6940911)  # Euler-Bernoulli cantilever roots of cos cosh = -1


def cantilever(length, h, n, material=None, mass="lumped"):
    msh = dmesh.create_box(
        MPI.COMM_WORLD, [np.zeros(3), np.array([length, h, h])], list(n), dmesh.CellType.hexahedron
    )
    body = FemBody(msh, material or NeoHookean.from_young_poisson(E, NU), RHO, mass=mass)
    body.fix_nodes(body.find_nodes(lambda x: np.isclose(x[0], 0.0)))
    return body


def euler_bernoulli(length, h, k):
    I, A = h**4 / 12.0, h * h
    return BETA_L[k] ** 2 * np.sqrt(E * I / (RHO * A * length**4))


def fixed_rows(body):
    return (3 * body.fixed_dofs[:, None] + np.arange(3)[None, :]).ravel()


def m_projection_residual(Q, mass, v):
    """||v - Q Q^T M v||_M / ||v||_M for M-orthonormal Q."""
    Mv = mass * v if not callable(mass) else mass(v)
    w = v - Q @ (Q.T @ Mv)
    Mw = mass * w if not callable(mass) else mass(w)
    return np.sqrt(abs(w @ Mw) / (v @ Mv))


@pytest.fixture(scope="module")
def slender():
    """Slender (L/h = 20) clamped Q1 cantilever with cubic elements, NeoHookean at rest."""
    body = cantilever(2.0, 0.1, (80, 4, 4))
    U, lam = linear_modes(body, 6)
    return body, U, lam


@pytest.fixture(scope="module")
def stocky():
    """L/h = 10, 40x4x4 Q1 cells, linear elastic, lumped mass: 6 modes."""
    body = cantilever(1.0, 0.1, (40, 4, 4), LinearElastic.from_young_poisson(E, NU))
    U, lam = linear_modes(body, 6)
    return body, U, lam


# ---- linear modes -----------------------------------------------------------------------------


def test_a_non_finite_eigenvalue_stops_linear_modes(monkeypatch):
    """SLEPc giving NaN eigenvalues with finite vectors (the EPS below, SLEPc's own but for
    the values) stops linear_modes with a SolverError that says so, not a basis."""
    import types

    import slepc4py
    from slepc4py import SLEPc

    from artifem.errors import SolverError

    class NaNValues:
        ProblemType, Type, Which = SLEPc.EPS.ProblemType, SLEPc.EPS.Type, SLEPc.EPS.Which

        def __init__(self):
            self._eps = SLEPc.EPS()

        def create(self, comm=None):
            self._eps.create(comm=comm)
            return self

        def getEigenpair(self, k, v):
            self._eps.getEigenpair(k, v)
            return complex(np.nan)

        def __getattr__(self, name):
            return getattr(self._eps, name)

    body = cantilever(1.0, 0.1, (10, 2, 2))
    monkeypatch.setattr(slepc4py, "SLEPc", types.SimpleNamespace(EPS=NaNValues, ST=SLEPc.ST))
    with pytest.raises(SolverError, match="non-finite eigenvalue among the lowest modes"):
        linear_modes(body, 2)


def test_cantilever_bending_frequencies_match_euler_bernoulli(slender):
    """omega_k = (beta_k L)^2 sqrt(E I / (rho A L^4)), k = 1, 2, each a y/z double eigenvalue.

    Measured (L/h = 20, 80x4x4 cubic Q1 cells): omega_1/EB = 1.018, omega_2/EB = 1.006
    (160x8x8: 1.005 / 0.993; 40x2x2: 1.067 / 1.054). Fully integrated Q1 is too stiff in
    bending (parasitic shear) and that error falls with refinement; Euler-Bernoulli also
    neglects shear deformation and rotary inertia, which lower the second frequency by
    about 1% at L/h = 20. A 3% tolerance covers both with margin while still failing for
    the coarse mesh's 5-7% or any mass/stiffness scaling error.
    """
    body, U, lam = slender
    omega = np.sqrt(lam)
    # the square cross-section gives pairs (bending in y and in z)
    assert omega[1] == pytest.approx(omega[0], rel=1e-8)
    assert omega[3] == pytest.approx(omega[2], rel=1e-8)
    for k, pair in enumerate([(0, 1), (2, 3)]):
        w_eb = euler_bernoulli(2.0, 0.1, k)
        for i in pair:
            assert omega[i] == pytest.approx(w_eb, rel=0.03), (k, omega[i], w_eb)
        # Only what is invariant under a rotation inside the two-dimensional eigenspace
        # (the solver may return any M-orthonormal basis of it): the 2x2 matrix T of mean
        # (y, z) tip displacements turns into Q T, so its singular values are determined.
        # The pair spans both transverse directions equally (square section: sigma_1 =
        # sigma_2), and every mode of the pair is pure bending, antisymmetric in x, so
        # the tip's mean axial displacement vanishes (an axial mode would make it O(T)).
        tip = body.local_dofs(body.find_nodes(lambda x: np.isclose(x[0], 2.0)))
        T = np.array([[U[3 * tip + c, i].mean() for c in (1, 2)] for i in pair])
        sigma = np.linalg.svd(T, compute_uv=False)
        assert sigma[1] == pytest.approx(sigma[0], rel=1e-4)
        axial = np.array([U[3 * tip, i].mean() for i in pair])
        assert np.linalg.norm(axial) < 1e-8 * sigma[0]

    # refinement: the coarse mesh (element 2x as large) is farther from Euler-Bernoulli
    _, lam_c = linear_modes(cantilever(2.0, 0.1, (40, 2, 2)), 4)
    for k in range(2):
        err_fine = abs(omega[2 * k] / euler_bernoulli(2.0, 0.1, k) - 1)
        err_coarse = abs(np.sqrt(lam_c[2 * k]) / euler_bernoulli(2.0, 0.1, k) - 1)
        assert err_coarse > 2 * err_fine
        assert np.sqrt(lam_c[2 * k]) > omega[2 * k]  # Q1 converges from above


def test_linear_modes_orthonormal_fixed_and_residual(slender):
    body, U, lam = slender
    m = body_mass(body)
    assert U.shape == (body.V.dofmap.index_map.size_local * 3, 6)
    assert mass_orthonormality_error(U, m) < 1e-10
    assert np.all(U[fixed_rows(body)] == 0.0)
    assert np.all(np.diff(lam) >= 0) and lam[0] > 0
    # measured 1.5e-9 (mode 1) .. 5e-12: the round-off floor eps * cond(K) of ||K u|| = lambda_1
    # ||M u|| for this slender beam; tightening SLEPc's tolerance does not lower it
    assert linear_mode_residuals(body, U, lam).max() < 1e-8
    # the body's state is untouched
    assert np.all(body.u.x.array == 0.0)


def test_linear_modes_consistent_mass():
    body = cantilever(1.0, 0.1, (20, 2, 2), mass="consistent")
    U, lam = linear_modes(body, 4)
    mass = body_mass(body)
    assert callable(mass)
    assert mass_orthonormality_error(U, mass) < 1e-10
    assert np.all(U[fixed_rows(body)] == 0.0)
    assert linear_mode_residuals(body, U, lam).max() < 1e-8
    # consistent mass distributes the inertia differently: close to, but not equal to, lumped
    _, lam_l = linear_modes(cantilever(1.0, 0.1, (20, 2, 2)), 4)
    assert np.allclose(np.sqrt(lam), np.sqrt(lam_l), rtol=0.05)
    assert not np.allclose(lam, lam_l, rtol=1e-6)


def test_linear_modes_equal_dense_reduced_problem():
    """The elimination is exact and returns no spurious (fixed-dof) modes: the eigenvalues
    equal the lowest ones of the dense problem restricted to the free dofs."""
    for mass_kind in ("lumped", "consistent"):
        body = cantilever(
            1.0, 0.25, (6, 1, 1), LinearElastic.from_young_poisson(E, NU), mass=mass_kind
        )
        r = 8
        U, lam = linear_modes(body, r)
        body.assemble(tangent=True, diag=1.0)
        K = body.K.copy().convert("dense").getDenseArray()
        if mass_kind == "lumped":
            M = np.diag(body.M_lumped.array)
        else:
            M = body.M_consistent.copy().convert("dense").getDenseArray()
        free = np.setdiff1d(np.arange(K.shape[0]), fixed_rows(body))
        ref = scipy.linalg.eigh(K[np.ix_(free, free)], M[np.ix_(free, free)], eigvals_only=True)[:r]
        assert np.allclose(lam, ref, rtol=1e-9), (mass_kind, lam, ref)


def test_linear_modes_bad_input(stocky):
    body = stocky[0]
    for r in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="positive integer"):
            linear_modes(body, r)
    small = cantilever(1.0, 0.5, (1, 1, 1))  # 4 free nodes -> 12 free dofs
    with pytest.raises(ValueError, match="exceeds the 12 free dofs"):
        linear_modes(small, 13)


# ---- extended modes ---------------------------------------------------------------------------


def test_extended_modes(stocky):
    body, U, lam = stocky
    m = body_mass(body)
    Ue = extended_modes(U, m)
    # 6 modes x 9 maps, all independent on this mesh (stable for tol 1e-10 .. 1e-6; at 1e-4
    # three near-dependencies appear: the cross-sections are almost rigid, so e.g. E_zy of
    # the y-bending mode is close to the z-bending mode)
    assert Ue.shape == (U.shape[0], 54)
    assert mass_orthonormality_error(Ue, m) < 1e-10
    assert np.all(Ue[fixed_rows(body)] == 0.0)
    rng = np.random.default_rng(0)
    for k in range(U.shape[1]):
        phi = U[:, k]
        assert m_projection_residual(Ue, m, phi) < 1e-10
        A = rng.normal(size=(3, 3))
        affine = (phi.reshape(-1, 3) @ A.T).ravel()  # node-wise A phi_a
        assert m_projection_residual(Ue, m, affine) < 1e-10
    # a generic displacement is not in the span
    assert m_projection_residual(Ue, m, rng.normal(size=U.shape[0]) * (m > 0)) > 0.5
    # same result with the mass as a callable, and with the fixed nodes passed explicitly
    Uc = extended_modes(U, lambda x: m * x, fixed_dofs=body.fixed_dofs)
    assert Uc.shape == Ue.shape and np.allclose(np.abs(Uc), np.abs(Ue), atol=1e-8)


def test_extended_modes_drops_dependent_vectors():
    rng = np.random.default_rng(1)
    n = 50
    m = rng.uniform(0.5, 2.0, 3 * n)
    phi = rng.normal(size=(n, 3))
    phi[:, 0] = 0.0  # no x-component: E_i0 phi = 0 for i = 0, 1, 2
    phi = phi.ravel()
    phi /= np.sqrt(phi @ (m * phi))
    assert extended_modes(phi[:, None], m).shape == (3 * n, 6)
    # a mode and a linear image of it span nothing new: 9, not 18
    psi = (phi.reshape(-1, 3) @ rng.normal(size=(3, 3)).T).ravel()
    assert extended_modes(np.column_stack([phi, psi]), m).shape[1] == 6
    full = rng.normal(size=3 * n)
    assert extended_modes(np.column_stack([full, 2.0 * full]), m).shape[1] == 9
    with pytest.raises(ValueError, match="node-major"):
        extended_modes(np.zeros((7, 1)), np.ones(7))


# ---- POD --------------------------------------------------------------------------------------


def _m_orthonormal(rng, n, k, m):
    X = rng.normal(size=(n, k))
    w = np.sqrt(m)
    Q, _ = np.linalg.qr(w[:, None] * X)
    return Q / w[:, None]


def test_pod_recovers_known_subspace():
    rng = np.random.default_rng(2)
    n = 300
    m = rng.uniform(0.1, 3.0, n)
    m[:6] = 0.0  # two fixed nodes: zero mass, zero snapshots
    m_safe = np.where(m > 0, m, 1.0)
    B = _m_orthonormal(rng, n, 3, m_safe)
    B[:6] = 0.0
    B = B / np.sqrt(np.einsum("ij,ij->j", B, m[:, None] * B))
    S = B @ (np.diag([10.0, 1.0, 0.1]) @ rng.normal(size=(3, 40)))
    U, s = pod_basis(S.T, m, energy_tol=1e-10)
    assert U.shape == (n, 3)
    assert mass_orthonormality_error(U, m) < 1e-12
    assert np.all(U[:6] == 0.0)
    for k in range(3):
        assert m_projection_residual(U, m, B[:, k]) < 1e-12
    assert s[3] < 1e-12 * s[0]
    # by count: sorted singular values, M-orthonormal, nested
    U2, s2 = pod_basis(S.T, m, r=2)
    assert U2.shape == (n, 2) and np.all(np.diff(s2) <= 0)
    assert mass_orthonormality_error(U2, m) < 1e-12
    assert np.allclose(s2, s)
    # energy_tol large enough to drop the weakest direction
    frac = s[2] ** 2 / np.sum(s**2)
    assert pod_basis(S.T, m, energy_tol=2 * frac)[0].shape[1] == 2
    assert pod_basis(S.T, m, energy_tol=0.5 * frac)[0].shape[1] == 3
    # a callable mass (method of snapshots) gives the same subspace
    Uc, sc = pod_basis(S.T, lambda x: m * x, energy_tol=1e-10)
    assert Uc.shape == (n, 3) and np.allclose(sc[:3], s[:3], rtol=1e-8)
    assert mass_orthonormality_error(Uc, m) < 1e-10
    for k in range(3):
        assert m_projection_residual(Uc, m, B[:, k]) < 1e-10


def test_pod_of_linear_modes_and_bad_input(stocky):
    body, U, lam = stocky
    m = body_mass(body)
    rng = np.random.default_rng(3)
    S = U[:, :4] @ rng.normal(size=(4, 12))
    Up, s = pod_basis(S.T, m, energy_tol=1e-12)
    assert Up.shape[1] == 4 and np.all(Up[fixed_rows(body)] == 0.0)
    for k in range(4):
        assert m_projection_residual(Up, m, U[:, k]) < 1e-10

    with pytest.raises(ValueError, match="exactly one of r"):
        pod_basis(S.T, m)
    with pytest.raises(ValueError, match="exactly one of r"):
        pod_basis(S.T, m, r=2, energy_tol=1e-3)
    for r in (0, -1):
        with pytest.raises(ValueError, match="positive integer"):
            pod_basis(S.T, m, r=r)
    with pytest.raises(ValueError, match="energy_tol"):
        pod_basis(S.T, m, energy_tol=1.5)
    with pytest.raises(ValueError, match="exceeds"):
        pod_basis(S.T, m, r=13)
    with pytest.raises(ValueError, match=r"snapshots are rows, one per snapshot"):
        pod_basis(S.T, m[:-3], r=2)
    with pytest.raises(ValueError, match=r"\(n_snapshots, dofs\) = \(\d+, 12\)"):
        pod_basis(S, m, r=2)  # columns: the other convention, refused
    with pytest.raises(ValueError, match="zero mass"):
        bad = S.copy()
        bad[fixed_rows(body)[0]] = 1.0
        pod_basis(bad.T, m, r=2)
    with pytest.raises(ValueError, match="all snapshots are zero"):
        pod_basis(np.zeros_like(S).T, m, r=1)


# ---- modal derivatives ------------------------------------------------------------------------


def _tangent_times(body, u, x):
    body.u.x.array[: u.size] = u
    body.u.x.scatter_forward()
    body.assemble(tangent=True, diag=1.0)
    K = body.K
    a, y = K.createVecs()
    a.array[:] = x
    K.mult(a, y)
    body.u.x.array[:] = 0.0
    return y.array_r.copy()


def test_modal_derivatives_solve_the_third_derivative_system():
    from artifem.reduction.bases import modal_derivatives

    body = cantilever(1.0, 0.1, (10, 2, 2))
    U, lam = linear_modes(body, 2)
    Psi = modal_derivatives(body, U)
    assert Psi.shape == (U.shape[0], 3)
    assert np.all(Psi[fixed_rows(body)] == 0.0)
    free = np.setdiff1d(np.arange(U.shape[0]), fixed_rows(body))
    eps = 1e-4
    for col, (i, j) in enumerate([(0, 0), (0, 1), (1, 1)]):
        # (dK/du . U_j) U_i by central differences of the tangent
        dK = (
            _tangent_times(body, eps * U[:, j], U[:, i])
            - _tangent_times(body, -eps * U[:, j], U[:, i])
        ) / (2 * eps)
        K0psi = _tangent_times(body, np.zeros_like(U[:, 0]), Psi[:, col])
        assert np.linalg.norm((K0psi + dK)[free]) < 1e-6 * np.linalg.norm(dK[free])
        assert np.linalg.norm(Psi[:, col]) > 0
    # a linear material has no modal derivatives
    lin = cantilever(1.0, 0.1, (10, 2, 2), LinearElastic.from_young_poisson(E, NU))
    Ul, _ = linear_modes(lin, 2)
    assert np.abs(modal_derivatives(lin, Ul)).max() < 1e-12 * np.abs(Ul).max()


def test_modal_derivative_basis_is_mass_orthonormal_and_spans_the_modes():
    from artifem.reduction.bases import modal_derivative_basis, modal_derivatives

    body = cantilever(1.0, 0.1, (10, 2, 2))
    B = modal_derivative_basis(body, 3)
    assert B.shape[1] == 3 + 6  # r modes + r (r + 1) / 2 derivatives
    mass = body_mass(body)
    assert mass_orthonormality_error(B, mass) < 1e-12
    assert np.all(B[fixed_rows(body)] == 0.0)
    U, _ = linear_modes(body, 3)
    Psi = modal_derivatives(body, U)
    for X in (U, Psi):  # both lie in span(B) (M-projection exact)
        P = B @ (B.T @ (mass[:, None] * X))
        assert np.linalg.norm(P - X) < 1e-8 * np.linalg.norm(X)
