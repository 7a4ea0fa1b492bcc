"""Integration points for reduced models: random and trained (ECSW / NNLS)."""

import numpy as np
import pytest

from artifem.reduction.cubature import (
    IntegrationPoints,
    random_points,
    trained_points,
    trained_points_path,
)


# ---------------------------------------------------------------- random


def test_random_points_keep_volume_and_are_reproducible():
    rng = np.random.default_rng(0)
    V = rng.uniform(0.1, 3.0, size=200)
    pts = random_points(V, 17, rng=42)
    assert isinstance(pts, IntegrationPoints)
    assert pts.method == "random" and pts.residual is None
    assert pts.indices.shape == (17,) and pts.weights.shape == (17,)
    assert np.unique(pts.indices).size == 17
    assert np.all((pts.indices >= 0) & (pts.indices < 200))
    assert np.all(pts.weights > 0)
    assert abs(np.sum(pts.weights * V[pts.indices]) - V.sum()) <= 1e-12 * V.sum()
    again = random_points(V, 17, rng=42)
    np.testing.assert_array_equal(pts.indices, again.indices)
    np.testing.assert_array_equal(pts.weights, again.weights)
    other = random_points(V, 17, rng=43)
    assert not np.array_equal(pts.indices, other.indices)
    # m = n: every element, weight one
    full = random_points(V, 200, rng=1)
    np.testing.assert_array_equal(full.indices, np.arange(200))
    np.testing.assert_allclose(full.weights, 1.0, rtol=1e-14)


@pytest.mark.parametrize("m", [0, -1, 11, 2.5])
def test_random_points_m_out_of_range(m):
    with pytest.raises(ValueError, match="m"):
        random_points(np.ones(10), m, rng=0)


def test_random_points_bad_volumes():
    with pytest.raises(ValueError, match="volumes"):
        random_points(np.array([1.0, -1.0, 2.0]), 2)
    with pytest.raises(ValueError, match="volumes"):
        random_points(np.ones((3, 2)), 2)


# ---------------------------------------------------------------- trained


def test_trained_recovers_exact_sparse_weights():
    rng = np.random.default_rng(1)
    T, n = 80, 50
    G = rng.standard_normal((T, n))
    support = np.array([3, 11, 20, 34, 47])
    w_true = np.zeros(n)
    w_true[support] = [0.5, 1.7, 2.3, 0.9, 3.1]
    b = G @ w_true
    pts = trained_points(G, b, tol=1e-12)
    np.testing.assert_array_equal(pts.indices, support)
    np.testing.assert_allclose(pts.weights, w_true[support], rtol=0, atol=1e-8)
    assert pts.method == "trained"
    assert pts.residual <= 1e-12
    assert np.all(pts.weights > 0)


def _smooth_training_matrix(n=400, seed=2):
    """Columns = element contributions of smooth 'force' functions over a 2-D domain."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.0, 1.0, size=(n, 2))
    vol = rng.uniform(0.5, 1.5, size=n) / n
    rows = []
    for k in range(4):
        for l in range(4):
            rows.append(
                np.cos(np.pi * k * x[:, 0]) * np.cos(np.pi * l * x[:, 1]) * (1.0 + 0.3 * x[:, 0])
            )
    return np.array(rows) * vol  # (16, n)


def test_trained_smooth_reaches_tol_with_few_points():
    G = _smooth_training_matrix()
    n = G.shape[1]
    pts = trained_points(G, tol=1e-6)
    assert pts.residual <= 1e-6
    assert pts.m <= 20 < n  # m << n
    assert np.all(pts.weights > 0)
    b = G.sum(axis=1)
    res = np.linalg.norm(b - G[:, pts.indices] @ pts.weights) / np.linalg.norm(b)
    assert res == pytest.approx(pts.residual, rel=1e-6, abs=1e-14)

    residuals = [trained_points(G, tol=1e-12, max_points=k).residual for k in (1, 2, 4, 8, 16)]
    assert all(r2 <= r1 + 1e-15 for r1, r2 in zip(residuals, residuals[1:])), residuals
    assert residuals[-1] < 1e-3 * residuals[0]
    assert residuals[0] < 1.0


def test_trained_strict_raises_when_tol_not_reached():
    G = _smooth_training_matrix()
    loose = trained_points(G, tol=1e-10, max_points=2)
    assert loose.m <= 2 and loose.residual > 1e-10
    with pytest.raises(ValueError, match="tol"):
        trained_points(G, tol=1e-10, max_points=2, strict=True)


@pytest.mark.parametrize("seed", range(5))
def test_trained_full_integration_is_always_reachable(seed):
    rng = np.random.default_rng(seed)
    T, n = 30, 60
    G = rng.standard_normal((T, n))
    pts = trained_points(G, tol=1e-8, max_points=n)  # b = G @ 1 is feasible with w = 1
    assert np.all(pts.weights > 0)
    assert pts.residual <= 1e-8
    assert pts.m <= T  # Caratheodory: a basic NNLS solution


# ---------------------------------------------------------------- bad input


def test_trained_bad_inputs_name_the_argument():
    G = np.random.default_rng(3).standard_normal((10, 6))
    with pytest.raises(ValueError, match="G"):
        trained_points(G[0])
    with pytest.raises(ValueError, match="b"):
        trained_points(G, np.ones(9))
    for tol in (0.0, 1.0, -0.1, 2.0):
        with pytest.raises(ValueError, match="tol"):
            trained_points(G, tol=tol)
    with pytest.raises(ValueError, match="max_points"):
        trained_points(G, max_points=0)
    bad = G.copy()
    bad[2, 3] = np.nan
    with pytest.raises(ValueError, match="G"):
        trained_points(bad)


def test_integration_points_validates():
    with pytest.raises(ValueError, match="weights"):
        IntegrationPoints(np.array([0, 1]), np.array([1.0, 0.0]), "random", None)
    with pytest.raises(ValueError, match="distinct"):
        IntegrationPoints(np.array([1, 1]), np.array([1.0, 1.0]), "random", None)
    with pytest.raises(ValueError, match="integers"):
        IntegrationPoints(np.array([0.0, 1.5]), np.array([1.0, 1.0]), "random", None)
    empty = IntegrationPoints(np.array([]), np.array([]), "random", None)  # float, but none
    assert empty.indices.size == 0 and empty.indices.dtype == np.int64


def test_random_points_by_group_share_m_and_keep_each_group_volume():
    rng = np.random.default_rng(3)
    V = rng.uniform(0.5, 2.0, 90)
    groups = np.repeat([2, 1], [80, 10])  # e.g. 8 Gauss points and 1 centre per cell
    pts = random_points(V, 27, rng=1, groups=groups)
    assert pts.m == 27
    chosen = groups[pts.indices]
    assert np.sum(chosen == 2) == 24 and np.sum(chosen == 1) == 3
    for g in (1, 2):
        at = chosen == g
        assert np.sum(pts.weights[at] * V[pts.indices[at]]) == pytest.approx(V[groups == g].sum())
    tiny = random_points(V, 3, rng=2, groups=np.repeat([0, 1, 2], [88, 1, 1]))
    assert tiny.m == 3 and set(np.repeat([0, 1, 2], [88, 1, 1])[tiny.indices]) == {0, 1, 2}


def test_trained_points_path_equals_separate_greedy_runs():
    rng = np.random.default_rng(11)
    G = rng.uniform(0.0, 1.0, (40, 120))
    b = G @ rng.uniform(0.5, 1.5, 120)
    path = trained_points_path(G, b, sizes=[5, 12, 20], tol=1e-9)
    for m in (5, 12, 20):
        alone = trained_points(G, b, tol=1e-9, max_points=m)
        np.testing.assert_array_equal(path[m].indices, alone.indices)
        np.testing.assert_allclose(path[m].weights, alone.weights, rtol=1e-12)
    assert path[5].residual > path[12].residual > path[20].residual


def test_batched_greedy_growth_reaches_the_tolerance_with_fewer_solves():
    rng = np.random.default_rng(12)
    G = rng.uniform(0.0, 1.0, (60, 400))
    b = G @ rng.uniform(0.5, 1.5, 400)
    one = trained_points(G, b, tol=1e-12, max_points=80)
    batched = trained_points(G, b, tol=1e-12, max_points=80, growth=0.2)
    assert batched.m <= 80 and batched.residual < 2 * one.residual + 1e-12
    path = trained_points_path(G, b, sizes=[25, 50, 80], tol=1e-12, growth=0.2)
    assert [path[m].m <= m for m in (25, 50, 80)] == [True] * 3
    assert path[25].residual >= path[50].residual >= path[80].residual
