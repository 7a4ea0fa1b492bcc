"""The solve of constraint rows with bounded impulses (artifem.scene.constraints):
``solve_constrained`` (Schur complement) and ``solve_saddle`` (one KKT matrix per
trial) agree and meet the complementarity conditions with general bounds
lo <= lambda <= hi, checked against every active set of a small problem."""

import itertools

import numpy as np
import pytest

import artifem as af  # noqa: F401  (must precede dolfinx / petsc4py)

from artifem.multibody.constraint_rows import Friction, RowBlock
from artifem.scene import constraints
from artifem.scene.constraints import StepRows, solve_constrained, solve_saddle
from artifem.scene.direct_solver import DirectSolver


class _Owner:
    name = "rows"


def test_bounded_rows_solve_meets_complementarity_for_any_bounds(rng):
    """Random SPD A, 2 free rows and 4 bounded ones ([0, inf), [-0.2, 0.3], (-inf, 0.1],
    [0, 0]): both solves give the same z and lambda, and that is the one active set of all
    3^4 whose equality solution keeps every multiplier within its bounds and every held row
    on its side (the complementarity conditions of the bounded rows)."""
    n = 8
    X = rng.standard_normal((n, n))
    A = X @ X.T + n * np.eye(n)
    b = 3.0 * rng.standard_normal(n)
    G = rng.standard_normal((6, n))
    c = rng.standard_normal(6)
    lo = np.array([-np.inf, -np.inf, 0.0, -0.2, -np.inf, 0.0])
    hi = np.array([np.inf, np.inf, np.inf, 0.3, 0.1, 0.0])
    block = RowBlock(_Owner(), np.zeros(6), ((None, G),), lo, hi, lambda lam: None)
    rows = [StepRows(block, G, c)]
    z1, lam1, _ = solve_constrained(DirectSolver(), A, b, rows, "test")
    # the case meant: a multiplier held at a non-zero bound
    assert np.any(((lam1 == lo) | (lam1 == hi)) & (lo != hi) & (lam1 != 0.0))
    z2, lam2, _ = solve_saddle(
        DirectSolver(),
        lambda K, Ga: np.block([[K, Ga.T], [Ga, np.zeros((len(Ga), len(Ga)))]]) if len(Ga) else K,
        A,
        b,
        rows,
        "test",
    )
    np.testing.assert_allclose(z1, z2, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(lam1, lam2, rtol=1e-10, atol=1e-12)
    # every state of the bounded rows: 0 active (equality), 1 held at lo, 2 held at hi
    found = []
    for states in itertools.product(range(3), repeat=4):
        state = np.array([0, 0, *states])
        if np.any((state == 1) & ~np.isfinite(lo)) or np.any((state == 2) & ~np.isfinite(hi)):
            continue
        lam = np.where(state == 1, lo, np.where(state == 2, hi, 0.0))
        on = state == 0
        # A z - G^T lam = b, G_on z = c_on
        KKT = np.block([[A, -G[on].T], [G[on], np.zeros((on.sum(), on.sum()))]])
        x = np.linalg.solve(KKT, np.concatenate([b + G[~on].T @ lam[~on], c[on]]))
        z, lam[on] = x[:n], x[n:]
        slack = G @ z - c
        tol = 1e-9
        ok = (
            np.all(lam >= lo - tol)
            and np.all(lam <= hi + tol)
            and np.all(slack[state == 1] >= -tol)
            and np.all(slack[state == 2] <= tol)
        )
        if ok:
            found.append((z, lam))
    assert found, "no complementary solution"
    for z, lam in found:  # the solution is unique (A SPD, G full rank)
        np.testing.assert_allclose(z, z1, rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(lam, lam1, rtol=1e-9, atol=1e-10)


@pytest.mark.parametrize("path", ["schur", "kkt"])
def test_friction_rows_take_the_normal_impulses_of_the_same_solve(path):
    """A point of mass m on a table (z = [v_x, v_z], rows v_z >= 0 and v_x = 0 with
    |lambda_t| <= mu lambda_n from the same solve), pressed down by m g and pushed along x
    by F: it sticks (lambda_t = -h F, v_x = 0) while F < mu m g and slides at
    v_x = h (F - mu m g) / m otherwise, both solves alike; the friction row's own bounds
    [0, 0] are not used (it would slide frictionless)."""
    m, g, h, mu = 2.0, 9.81, 0.01, 0.5
    A = m * np.eye(2)
    G = np.eye(2)[[1, 0]]
    lo, hi = np.array([0.0, 0.0]), np.array([np.inf, 0.0])
    block = RowBlock(
        _Owner(),
        np.zeros(2),
        ((None, G),),
        lo,
        hi,
        lambda lam: None,
        friction=Friction(np.array([-1, 0]), np.array([0.0, mu])),
    )
    rows = [StepRows(block, G, np.zeros(2))]
    for F, v_x in ((0.8 * mu * m * g, 0.0), (1.5 * mu * m * g, h * 0.5 * mu * g)):
        b = h * np.array([F, -m * g])
        z, lam, _ = solve_constrained(DirectSolver(), A, b, rows, "test", path=path)
        np.testing.assert_allclose(lam[0], h * m * g, rtol=1e-12)
        np.testing.assert_allclose(z, [v_x, 0.0], atol=1e-14)
        np.testing.assert_allclose(lam[1], -h * min(F, mu * m * g), rtol=1e-12)
        z2, lam2, _ = solve_saddle(DirectSolver(), _kkt, A, b, rows, "test")
        np.testing.assert_allclose(z2, z, atol=1e-14)
        np.testing.assert_allclose(lam2, lam, rtol=1e-12)


def test_anderson_mixing_finds_an_affine_maps_fixed_point_in_a_few_passes():
    """The friction passes' map from the normal impulses the bounds are of to those of
    the solve is affine while the active set stays, x -> T x + d: plain passes converge
    as the largest |eigenvalue| of T (0.9 here: error still 0.4 of the first after 8),
    Anderson's mixing over ANDERSON_DEPTH passes (the history the solve keeps) reaches
    the fixed point to round-off in 5, on a 3-dimensional map."""
    Q = np.linalg.qr(np.arange(1.0, 10.0).reshape(3, 3) + np.eye(3))[0]
    T = Q @ np.diag([0.9, -0.8, 0.5]) @ Q.T
    d = np.array([1.0, -2.0, 0.5])
    fixed = np.linalg.solve(np.eye(3) - T, d)
    x, plain, history = np.zeros(3), np.zeros(3), []
    for _ in range(5):
        history.append((T @ x + d, x))
        del history[: -constraints.ANDERSON_DEPTH]
        x = constraints._anderson(history)
    for _ in range(8):
        plain = T @ plain + d
    assert np.linalg.norm(x - fixed) <= 1e-12 * np.linalg.norm(fixed)
    assert np.linalg.norm(plain - fixed) >= 0.3 * np.linalg.norm(fixed)


def _kkt(K, Ga):
    return np.block([[K, Ga.T], [Ga, np.zeros((len(Ga), len(Ga)))]]) if len(Ga) else K


@pytest.mark.parametrize("F", [0.2, 0.45, 1.5])
def test_sliding_rows_held_at_mu_lambda_n_of_the_same_solve(monkeypatch, F):
    """A planar box (z = [v_x, v_z, w], mass 2, inertia 0.1) on a table through its two
    bottom corners (x = -+0.2, 0.1 below its centre: normal rows [0, 1, x], friction rows
    [1, 0, 0.1], mu = 0.5), pushed along x by F m g: the friction's torque shifts the
    normal impulses between the corners, so they depend on the friction impulses. One
    pass of the bounds' fixed point does not settle (its bounds were the rows' own
    [0, 0]); the sliding rows then held at +-mu lambda_n of the same solve (a row of the
    multiplier block that is not symmetric) give the fixed point's answer, on the Schur
    complement, the sparse KKT matrix and the statics' KKT matrix alike: the velocities,
    the normal impulses and the sum of the friction impulses (the two friction rows are
    the same row: while the box sticks, only their sum is determined), each friction
    impulse within its cone."""
    m, g, h, mu = 2.0, 9.81, 0.01, 0.5
    A = np.diag([m, m, 0.1])
    G = np.array([[0.0, 1.0, -0.2], [0.0, 1.0, 0.2], [1.0, 0.0, 0.1], [1.0, 0.0, 0.1]])
    lo, hi = np.array([0.0, 0.0, 0.0, 0.0]), np.array([np.inf, np.inf, 0.0, 0.0])
    block = RowBlock(
        _Owner(),
        np.zeros(4),
        ((None, G),),
        lo,
        hi,
        lambda lam: None,
        friction=Friction(np.array([-1, -1, 0, 1]), np.array([0, 0, mu, mu])),
    )
    rows = [StepRows(block, G, np.zeros(4))]
    b = h * np.array([F * m * g, -m * g, 0.0])
    reference = solve_constrained(DirectSolver(), A, b, rows, "test", path="schur")
    monkeypatch.setattr(constraints, "BOUND_PASSES", 1)
    z_ref, lam_ref = reference[:2]
    assert np.all(lam_ref[:2] > 0) and lam_ref[0] != pytest.approx(lam_ref[1])
    np.testing.assert_allclose(np.abs(lam_ref[2:]).sum(), h * min(F, mu) * m * g, rtol=1e-9)
    solves = [
        solve_constrained(DirectSolver(), A, b, rows, "test", path=path)[:2]
        for path in ("schur", "kkt")
    ]
    # the statics' trials on their own (not from the Schur complement's active set)
    monkeypatch.setattr(constraints, "_schur_start", lambda *args: None)
    solves.append(solve_saddle(DirectSolver(), _kkt, A, b, rows, "test")[:2])
    for z, lam in solves:
        np.testing.assert_allclose(z, z_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(lam[:2], lam_ref[:2], rtol=0, atol=1e-12)
        np.testing.assert_allclose(lam[2] + lam[3], lam_ref[2] + lam_ref[3], rtol=0, atol=1e-12)
        assert np.all(np.abs(lam[2:]) <= mu * lam[:2] + 1e-15)


def _counting_kkt():
    calls = []

    def kkt(K, Ga):
        calls.append(len(Ga))
        return np.block([[K, Ga.T], [Ga, np.zeros((len(Ga), len(Ga)))]]) if len(Ga) else K

    return kkt, calls


def test_saddle_starts_from_the_schur_complement_active_set(rng):
    """30 rows lambda >= 0 on an SPD K (a contact of many points): solve_saddle's KKT trials
    start from the active set of the Schur complement and confirm it with one KKT
    factorization (one per row activated before), giving solve_constrained's z and lambda;
    with a K singular until a bilateral row fixes it, the trials go the old way (no start)
    and still meet the conditions."""
    n, m = 40, 30
    X = rng.standard_normal((n, n))
    K = X @ X.T + n * np.eye(n)
    b = 5.0 * rng.standard_normal(n)
    G = rng.standard_normal((m, n))
    c = rng.standard_normal(m)
    lo, hi = np.zeros(m), np.full(m, np.inf)
    rows = [StepRows(RowBlock(_Owner(), np.zeros(m), ((None, G),), lo, hi, lambda lam: None), G, c)]
    z1, lam1, _ = solve_constrained(DirectSolver(), K, b, rows, "test")
    assert 3 < np.count_nonzero(lam1) < m - 3  # the case meant: some rows active
    kkt, calls = _counting_kkt()
    z2, lam2, active = solve_saddle(DirectSolver(), kkt, K, b, rows, "test")
    assert len(calls) == 1 and calls[0] == np.count_nonzero(active)
    np.testing.assert_allclose(z2, z1, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(lam2, lam1, rtol=1e-9, atol=1e-10)
    # K singular along e_0, fixed by a bilateral row z_0 = 0.1, and a bounded row z_0 + z_1 >= 1
    K = np.diag([0.0, 2.0, 3.0])
    b = np.array([0.0, 1.0, 1.0])
    G = np.array([[1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    rows = [
        StepRows(
            RowBlock(
                _Owner(),
                np.zeros(2),
                ((None, G),),
                np.array([-np.inf, 0.0]),
                np.array([np.inf, np.inf]),
                lambda lam: None,
            ),
            G,
            np.array([0.1, 1.0]),
        )
    ]
    kkt, calls = _counting_kkt()
    z, lam, active = solve_saddle(DirectSolver(), kkt, K, b, rows, "test")
    assert len(calls) == 2  # held at 0 first, then active
    np.testing.assert_allclose(z, [0.1, 0.9, 1.0 / 3.0], atol=1e-12)
    assert active.all() and lam[1] > 0
    np.testing.assert_allclose(K @ z - G.T @ lam, b, atol=1e-12)


def test_circling_pivots_from_the_last_steps_set_start_again_cold(monkeypatch):
    """The sliding rows' pivots from a warm start that circle (made to fail here on their
    first call) are tried again from no warm start: the planar box of the test above,
    pushed to slide, gives the fixed point's answer."""
    m, g, h, mu = 2.0, 9.81, 0.01, 0.5
    A = np.diag([m, m, 0.1])
    G = np.array([[0.0, 1.0, -0.2], [0.0, 1.0, 0.2], [1.0, 0.0, 0.1], [1.0, 0.0, 0.1]])
    lo, hi = np.zeros(4), np.array([np.inf, np.inf, 0.0, 0.0])
    friction = (np.array([-1, -1, 0, 1]), np.array([0, 0, mu, mu]))
    b = h * np.array([1.5 * m * g, -m * g, 0.0])
    system = constraints._Schur(DirectSolver(), A, b, G, G, np.zeros(4), lo, hi, "test")
    reference = constraints._active_set(lo, hi, 1e-10, system.trial, "test", friction)
    monkeypatch.setattr(constraints, "BOUND_PASSES", 1)
    pivots, calls = constraints._pivots, []

    def circling(*args):
        calls.append(args[5] is not None)
        if args[5] is not None and calls.count(True) == 1:
            raise af.StepFailed("circling")
        return pivots(*args)

    monkeypatch.setattr(constraints, "_pivots", circling)
    warm = (
        np.array([True, True, True, True]),
        np.zeros(4, bool),
        np.ones(4, bool),
        np.array([0.1, 0.1, 0.0, 0.0]),
    )
    lam, *_ = constraints._active_set(lo, hi, 1e-10, system.trial, "test", friction, warm)
    assert calls == [False, True, False, True]  # warm: a pass, the pivots; cold: again
    np.testing.assert_allclose(lam[:2], reference[0][:2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(lam[2] + lam[3], reference[0][2] + reference[0][3], atol=1e-12)


@pytest.mark.parametrize(
    "seed", [77, 317, 331, 370, 570, 849, 973, 1631, 1682, 1947, 2122, 2529, 2753]
)
def test_pivots_that_come_back_settle_on_the_regularized_block(seed):
    """Feasible contact-like problems (lambda >= 0 on every row, G z >= c) whose rows
    outnumber the coordinates and are parallel to 1e-9 in bunches (a fine surface's points
    over a coarse mesh's facets): S is singular to round-off, and one row per trial on its
    least-squares blocks came back to a set forever in each of these (measured at the
    commit before this test). Once a set comes back, the trials take the regularized block
    (PROXIMAL_REGULARIZATION): a P-matrix, where the least-index rule settles; the answer
    meets the complementarity conditions to that regularization."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 6))
    m = int(rng.integers(n + 1, 3 * n + 3))
    base = rng.normal(size=(n + 1, n))
    G = base[rng.integers(0, n + 1, m)] * rng.uniform(0.5, 2, (m, 1)) + 1e-9 * rng.normal(
        size=(m, n)
    )
    A = np.eye(n) * rng.uniform(1, 3, n)
    b = rng.normal(size=n)
    c = G @ rng.normal(size=n) - np.abs(rng.normal(size=m)) * (rng.random(m) < 0.5)
    lo, hi = np.zeros(m), np.full(m, np.inf)
    system = constraints._Schur(DirectSolver(), A, b, G, G, c, lo, hi, "test")
    lam, active, _, z = constraints._active_set(
        lo, hi, 1e-10, system.trial, "test", proximal=system.proximal
    )
    slack = G @ z - c
    scale = 1e-6 * max(1.0, np.abs(lam).max())
    assert lam.min() >= 0.0 and slack.min() > -scale
    assert np.abs(lam * slack).max() < scale * np.abs(slack).max()
    np.testing.assert_allclose(A @ z - G.T @ lam, b, atol=1e-9 * np.abs(b).max())
