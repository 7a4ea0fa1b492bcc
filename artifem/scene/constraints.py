"""Velocities under joint rows: bilateral equalities and unilateral limits.

The step's KKT system (artifem.scene.scene docstring; ArtiSynth's constrained
backward Euler),

    [ A   -G^T ] [ z      ]   [ b ]
    [ G    0   ] [ lambda ] = [ c ],      lambda the constraint impulses,

is solved through its Schur complement: with a = A^-1 b and W = A^-1 G^T (one
factorization of A, 1 + rows solves),

    S lambda = c - G a,   S = G W,   z = a + W lambda.

S is small and dense (a few rows per joint). It is solved by least squares on
the active rows, so redundant rows (closed loops, a joint doubled) get the
minimum-norm impulses instead of a singular matrix. Limits are unilateral rows
G_l z >= c_l with lambda_l >= 0 and complementarity, solved by a primal-dual
active set on the same S (add the most violated row, drop the most negative
multiplier, repeat): no new factorization per trial.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from artifem.errors import StepFailed

__all__ = ["solve_constrained"]


def solve_constrained(solver, A, b: np.ndarray, bilateral: list, unilateral: list,
                      what: str, resolver: bool = False, force_rows: list | None = None):
    """(z, lambda, active rows) of the system above.

    ``solver`` factors A (``factor(A, what).apply(B)``, e.g. DirectSolver);
    ``bilateral`` and ``unilateral`` are lists of (..., G_rows, c_rows) whose last two
    entries are the rows on z (sparse or dense) and their right-hand sides; lambda
    is returned in that order (bilateral first). With ``resolver``, a fourth item:
    ``resolve(b) -> (z, lambda)``, the same system for another right-hand side with
    c = 0 and the active rows kept (the factorization reused; the pressure iterations
    of :func:`artifem.incompressibility.hold_linearized`). ``force_rows`` (one block per
    group, bilateral first; default the groups' own rows) are the rows F of the first
    block row, A z - F^T lambda = b, when they differ from the constraint rows G (Newton
    on a residual whose constraint forces and constraint values have different
    derivatives: :mod:`artifem.scene.implicit_step`); W = A^-1 F^T, S = G W.
    """
    groups = bilateral + unilateral
    n = A.shape[0]
    solver.factor(A, what)
    if not groups:
        z = solver.apply(b)

        def resolve(rhs):
            return solver.apply(rhs), np.zeros(0)

        return (z, np.zeros(0), 0, resolve) if resolver else (z, np.zeros(0), 0)
    blocks = [g[-2] for g in groups]
    G = sparse.vstack(blocks).tocsr() if any(sparse.issparse(x) for x in blocks) else \
        np.vstack(blocks)
    c = np.concatenate([g[-1] for g in groups])
    F = G
    if force_rows is not None:
        F = sparse.vstack(force_rows).tocsr() if any(sparse.issparse(x) for x in force_rows) \
            else np.vstack(force_rows)
    X = solver.apply(np.column_stack([b, F.T.toarray() if sparse.issparse(F) else F.T]))
    a, W = X[:, 0], X[:, 1:]
    S = np.asarray(G @ W)
    r = c - G @ a
    n_bi = sum(len(g[-1]) for g in bilateral)
    limit = np.arange(n_bi, len(c))
    active = np.zeros(len(c), dtype=bool)
    active[:n_bi] = True
    lam = np.zeros(len(c))
    tol = 1e-10 * max(1.0, np.abs(c).max())
    for _ in range(2 * limit.size + 10):
        on = np.flatnonzero(active)
        lam[:] = 0.0
        if on.size:
            lam[on] = np.linalg.lstsq(S[np.ix_(on, on)], r[on], rcond=1e-12)[0]
        if not limit.size:
            break
        slack = S[limit] @ lam - r[limit]           # G_l z - c_l >= 0 wanted
        negative = active[limit] & (lam[limit] < -tol)
        violated = ~active[limit] & (slack < -tol)
        if negative.any():
            active[limit[np.argmin(np.where(negative, lam[limit], np.inf))]] = False
        elif violated.any():
            active[limit[np.argmin(np.where(violated, slack, np.inf))]] = True
        else:
            break
    else:
        raise StepFailed(f"{what}: the joint-limit active set did not settle")
    z = a + W @ lam
    if not np.all(np.isfinite(z)):
        raise StepFailed(f"{what}: non-finite velocities")
    assert z.shape == (n,)
    if not resolver:
        return z, lam, int(active.sum())
    on = np.flatnonzero(active)

    def resolve(rhs):
        a = solver.apply(rhs)
        mu = np.zeros(len(c))
        if on.size:
            mu[on] = np.linalg.lstsq(S[np.ix_(on, on)], -(G @ a)[on], rcond=1e-12)[0]
        return a + W @ mu, mu

    return z, lam, int(active.sum()), resolve


def impulses_by_joint(bilateral: list, unilateral: list, lam: np.ndarray) -> dict:
    """joint -> [(rows, impulses)]: lambda of :func:`solve_constrained` split by the
    (joint, rows, G, c) groups it was solved with (bilateral first)."""
    out: dict = {}
    start = 0
    for joint, rows, _, c in bilateral + unilateral:
        out.setdefault(joint, []).append((rows, lam[start:start + len(c)]))
        start += len(c)
    return out
