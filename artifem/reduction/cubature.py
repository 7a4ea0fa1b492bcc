"""Integration points for reduced-coordinate models (Lloyd et al. 2019, section 2).

A reduced model evaluates its internal force from a small subset of the
elements (or quadrature points) of the full mesh, each with a weight:

    f~(q) = sum_k w_k U_e_k^T f_e_k(U q)

where ``U_e`` are the rows of the basis belonging to element ``e`` and
``f_e`` is that element's internal force.  With positive weights the reduced
force is the gradient of the weighted energy ``sum_k w_k Psi_e_k``, so the
reduced tangent is symmetric and the dynamics stay stable.

Two ways to choose the points:

* :func:`random_points` -- m distinct elements drawn uniformly at random, all
  scaled by the same weight so that the total volume is kept.
* :func:`trained_points` -- greedy energy-conserving sampling and weighting
  (ECSW, Farhat, Avery, Chapman & Cortial 2014, IJNME 98:625-662, Algorithm 1;
  the greedy "optimized cubature" of An, Kim & James 2008): elements are added
  one at a time and non-negative weights are fitted with NNLS
  (:func:`scipy.optimize.nnls`) to training snapshots of the reduced force.

This module is pure numpy/scipy; assembling the training matrix ``G`` from
the FEM model is done elsewhere.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls
from tqdm import tqdm

from artifem.errors import InputError

__all__ = ["IntegrationPoints", "random_points", "trained_points", "trained_points_path"]


@dataclass(frozen=True)
class IntegrationPoints:
    """A weighted subset of elements (or quadrature points) of the full mesh.

    The reduced internal force is ``f~(q) = sum_k w_k U_e_k^T f_e_k(q)`` with
    ``e_k = indices[k]`` and ``w_k = weights[k]``.

    Attributes
    ----------
    indices : (m,) int array
        Distinct element (or quadrature point) indices into the full mesh.
    weights : (m,) float array
        Strictly positive weights (positivity keeps f~ the gradient of an
        energy).
    method : str
        ``"random"`` or ``"trained"``.
    residual : float or None
        Relative training residual ``||b - G_S w|| / ||b||`` for trained
        points; ``None`` when there was no training (random points).
    """

    indices: np.ndarray
    weights: np.ndarray
    method: str
    residual: float | None = None

    def __post_init__(self):
        idx = np.asarray(self.indices)
        w = np.asarray(self.weights, dtype=float)
        if idx.ndim != 1 or w.ndim != 1:
            raise InputError("indices and weights must be 1-D arrays")
        if idx.shape != w.shape:
            raise InputError(
                f"indices ({idx.shape[0]}) and weights ({w.shape[0]}) differ in length"
            )
        if idx.size and not np.issubdtype(idx.dtype, np.integer):
            raise InputError("indices must be integers")
        idx = idx.astype(np.int64)
        if np.unique(idx).size != idx.size:
            raise InputError("indices must be distinct")
        if np.any(idx < 0):
            raise InputError("indices must be non-negative")
        if not np.all(np.isfinite(w)) or np.any(w <= 0.0):
            raise InputError("weights must be finite and > 0")
        idx = idx.copy()
        w = w.copy()
        idx.setflags(write=False)
        w.setflags(write=False)
        object.__setattr__(self, "indices", idx)
        object.__setattr__(self, "weights", w)
        if self.residual is not None:
            object.__setattr__(self, "residual", float(self.residual))

    @property
    def m(self) -> int:
        """Number of integration points."""
        return int(self.indices.size)


def random_points(volumes, m, rng=None, groups=None) -> IntegrationPoints:
    """Draw ``m`` distinct elements (or quadrature points) uniformly at random.

    The draw is *uniform* (not volume-weighted).  Every selected point gets
    the same weight ``w = V_total / sum_k V_k``, so that ``sum_k w V_k =
    V_total``: the sample keeps the total volume.  With ``groups`` (one label
    per point, e.g. the quadrature rule a point belongs to) the m points are
    shared among the groups in proportion to their sizes (at least one each
    when m allows) and each group keeps its own volume.

    Parameters
    ----------
    volumes : (n,) array of positive element (or quadrature point) volumes.
    m : number of points, ``1 <= m <= n``.
    rng : None, int seed or :class:`numpy.random.Generator`.
    groups : optional (n,) array of group labels.
    """
    V = np.asarray(volumes, dtype=float)
    if V.ndim != 1 or V.size == 0:
        raise InputError("volumes must be a non-empty 1-D array")
    if not np.all(np.isfinite(V)) or np.any(V <= 0.0):
        raise InputError("volumes must be finite and > 0")
    n = V.size
    if isinstance(m, bool) or not isinstance(m, (int, np.integer)):
        raise InputError(f"m must be an integer, got {m!r}")
    if not 1 <= m <= n:
        raise InputError(f"m must be in [1, {n}], got {m}")
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    labels = np.zeros(n, dtype=np.int64) if groups is None else np.asarray(groups)
    if labels.shape != (n,):
        raise InputError(f"groups must have one label per point ({n}), got shape {labels.shape}")
    names, sizes = np.unique(labels, return_counts=True)
    share = m * sizes / n
    counts = np.floor(share).astype(np.int64)
    if m >= names.size:
        counts = np.maximum(counts, 1)
    while counts.sum() > m:  # the minimum of one overshot
        counts[np.argmax(counts)] -= 1
    for g in np.argsort(counts - share)[: m - counts.sum()]:  # largest remainders
        counts[g] += 1
    idx, w = [], []
    for name, count in zip(names, counts):
        members = np.flatnonzero(labels == name)
        if count == 0:
            continue
        chosen = gen.choice(members, size=min(int(count), members.size), replace=False)
        idx.append(chosen)
        w.append(np.full(chosen.size, V[members].sum() / V[chosen].sum()))
    idx, w = np.concatenate(idx), np.concatenate(w)
    order = np.argsort(idx)
    return IntegrationPoints(indices=idx[order], weights=w[order], method="random", residual=None)


def _check_training(G, b, tol, max_points):
    G = np.asarray(G, dtype=float)
    if G.ndim != 2:
        raise InputError(f"G must be a 2-D (T, n) array, got ndim={G.ndim}")
    T, n = G.shape
    if T == 0 or n == 0:
        raise InputError(f"G must be non-empty, got shape {G.shape}")
    if not np.all(np.isfinite(G)):
        raise InputError("G contains NaN or inf")
    if b is None:
        b = G.sum(axis=1)  # G @ 1: full integration
    else:
        b = np.asarray(b, dtype=float)
        if b.ndim != 1 or b.size != T:
            raise InputError(
                f"b must be a 1-D array of length {T} (rows of G), got shape {b.shape}"
            )
        if not np.all(np.isfinite(b)):
            raise InputError("b contains NaN or inf")
    if not np.linalg.norm(b) > 0.0:
        raise InputError("b is zero: nothing to fit")
    tol = float(tol)
    if not 0.0 < tol < 1.0:
        raise InputError(f"tol must be in (0, 1), got {tol}")
    if max_points is None:
        max_points = n
    if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)):
        raise InputError(f"max_points must be an integer, got {max_points!r}")
    if max_points < 1:
        raise InputError(f"max_points must be >= 1, got {max_points}")
    return G, b, tol, min(int(max_points), n)


def trained_points(
    G, b=None, *, tol=1e-2, max_points=None, strict=False, growth: float = 0.0
) -> IntegrationPoints:
    """Greedy ECSW / optimized cubature: non-negative weights fitted to training data.

    Parameters
    ----------
    G : (T, n) array
        Training matrix.  Column ``e`` is element ``e``'s contribution to all
        training snapshots of the reduced force, stacked (``T = snapshots x r``).
    b : (T,) array, optional
        Target; defaults to ``G @ 1`` (full integration, all weights one).
    tol : float in (0, 1)
        Stop when ``||b - G w|| <= tol ||b||``.
    max_points : int >= 1, optional
        Maximum number of points (default and cap: n).
    strict : bool
        If True, raise :class:`ValueError` when ``tol`` is not reached within
        ``max_points``; otherwise return the best set found, with its relative
        residual recorded in ``residual``.
    growth : float >= 0
        0 (default) adds one point per NNLS solve, as in the papers; g > 0 adds
        the max(1, floor(g |S|)) best-correlated points at once, so a path to
        m points takes about log(m) / log(1 + g) solves instead of m.

    Algorithm (Farhat et al. 2014, Algorithm 1; An, Kim & James 2008)
    -----------------------------------------------------------------
    Start from an empty set S.  Repeat: residual ``r = b - G_S w``; among the
    elements not in S pick the one whose *normalized* column has the largest
    positive correlation ``G_e^T r / ||G_e||`` (columns are normalized by
    their norms, as An et al. do, so large elements are not favoured just for
    their size; zero columns are never picked); solve NNLS on the columns of S;
    drop elements whose weight became zero.  Stop when the tolerance is
    reached, when S holds ``max_points`` elements, or on a stall (no column
    correlates positively with the residual, the same element is chosen
    twice in a row, or the residual stops decreasing).  Each NNLS solve is over
    a superset of a feasible previous solution, so the residual never
    increases along the greedy path.
    """
    G, b, tol, max_points = _check_training(G, b, tol, max_points)
    bnorm = float(np.linalg.norm(b))
    last = deque(_greedy(G, b, tol, max_points, growth), maxlen=1)  # its last state
    S, w, rnorm = last[0] if last else (np.zeros(0, dtype=np.int64), np.zeros(0), bnorm)
    return _points(S, w, rnorm, bnorm, tol, max_points, strict)


def trained_points_path(
    G, b=None, *, sizes, tol=1e-2, growth: float = 0.0, progress: bool = False
) -> dict[int, IntegrationPoints]:
    """:func:`trained_points` for several ``max_points`` at once, from one greedy path.

    Returns {m: the points ``trained_points(G, b, tol=tol, max_points=m)`` gives}
    for each m in ``sizes``; the path is run once, up to the largest m. With
    ``growth`` > 0 a batch may step over an m; that m gets the first set larger
    than it, trimmed to its m largest weights and refitted by NNLS.
    """
    sizes = sorted({int(m) for m in sizes})
    G, b, tol, largest = _check_training(G, b, tol, sizes[-1] if sizes else None)
    bnorm = float(np.linalg.norm(b))
    found: dict[int, IntegrationPoints] = {}
    S, w, rnorm = np.zeros(0, dtype=np.int64), np.zeros(0), bnorm
    bar = tqdm(total=largest, desc="trained points", unit="point", disable=not progress)
    for S, w, rnorm in _greedy(G, b, tol, largest, growth):
        bar.update(S.size - bar.n)
        for m in sizes:
            if m not in found and S.size >= m:
                Sm, wm, rm = S, w, rnorm
                if S.size > m:  # a batch stepped over m
                    Sm = S[np.argsort(w)[::-1][:m]]
                    wm, _ = nnls(G[:, Sm], b, maxiter=50 * m + 100)
                    Sm, wm = Sm[wm > 0], wm[wm > 0]
                    rm = float(np.linalg.norm(b - G[:, Sm] @ wm))
                found[m] = _points(Sm, wm, rm, bnorm, tol, m, False)
    bar.close()
    for m in sizes:
        if m not in found:
            found[m] = _points(S, w, rnorm, bnorm, tol, m, False)
    return found


def _greedy(G: np.ndarray, b: np.ndarray, tol: float, max_points: int, growth: float = 0.0):
    """The greedy ECSW path: yields (S, w, ||b - G_S w||) after every accepted pick.

    Each iteration adds the best-correlated column, or with ``growth`` > 0 the
    max(1, floor(growth |S|)) best ones (fewer NNLS solves on large sets).
    """
    T, n = G.shape
    bnorm = float(np.linalg.norm(b))
    target = tol * bnorm

    col_norms = np.linalg.norm(G, axis=0)
    usable = col_norms > 0.0
    inv_norms = np.zeros(n)
    inv_norms[usable] = 1.0 / col_norms[usable]

    S = np.zeros(0, dtype=np.int64)
    w = np.zeros(0)
    r = b.copy()
    rnorm = bnorm
    last_pick = -1
    max_iter = 2 * n + 10  # guard: every pick strictly decreases the residual

    for _ in range(max_iter):
        if rnorm <= target or S.size >= max_points:
            break
        score = (G.T @ r) * inv_norms
        score[~usable] = -np.inf
        score[S] = -np.inf
        e = int(np.argmax(score))
        batch = min(max(1, int(growth * S.size)), max_points - S.size)
        picks = np.argpartition(-score, batch - 1)[:batch] if batch > 1 else np.array([e])
        picks = picks[score[picks] > 0.0]
        if not score[e] > 0.0:
            break  # no column correlates positively: NNLS optimum over all columns
        if e == last_pick:
            break  # stall: the same element chosen again
        last_pick = e
        S_try = np.append(S, picks)
        w_try, _ = nnls(G[:, S_try], b, maxiter=50 * S_try.size + 100)
        keep = w_try > 0.0
        S_try, w_try = S_try[keep], w_try[keep]
        r_try = b - G[:, S_try] @ w_try
        rnorm_try = float(np.linalg.norm(r_try))
        if not rnorm_try < rnorm * (1.0 - 1e-14):
            break  # stall: no progress
        S, w, r, rnorm = S_try, w_try, r_try, rnorm_try
        yield S, w, rnorm


def _points(S, w, rnorm, bnorm, tol, max_points, strict) -> IntegrationPoints:
    if S.size == 0:
        raise InputError(
            "trained_points: no element correlates positively with b; "
            "b is not in the cone of the columns of G"
        )
    if strict and rnorm > tol * bnorm:
        raise InputError(
            f"trained_points: tol={tol:g} not reached with max_points={max_points} "
            f"(relative residual {rnorm / bnorm:.3e} with {S.size} points)"
        )
    order = np.argsort(S)
    return IntegrationPoints(
        indices=S[order], weights=w[order], method="trained", residual=rnorm / bnorm
    )
