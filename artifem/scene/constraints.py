"""Velocities under constraint rows with bounded impulses: the step's and statics' solve.

Every constraint gives its rows as :class:`~artifem.multibody.constraint_rows.RowBlock`
(bilateral rows: lambda free; limits: lambda >= 0); the layout maps them onto the
solve's coordinates as :class:`StepRows` (G P and the right-hand side c). The step's
KKT system (artifem.scene.scene docstring; ArtiSynth's constrained backward Euler),

    [ A   -G^T ] [ z      ]   [ b ]
    [ G    0   ] [ lambda ] = [ c ],      lambda the constraint impulses,

holds on the active rows; a row with a finite bound is either active (G z = c, lambda
within its bounds) or held at a bound (lambda = lo with G z >= c, or lambda = hi with
G z <= c). The active set is found by a primal-dual active set
(:func:`_active_set`: release the multiplier furthest out of its bounds, else activate
the most violated row, repeat); rows with lo = -inf and hi = inf are always active.
Bounds that depend on the impulses (friction, ``RowBlock.bounds_from``) are a fixed
point around it: the active set again with the bounds of its last impulses, until they
settle.

:func:`solve_constrained` (the step) solves each trial through the Schur complement:
with a = A^-1 b and W = A^-1 G^T (one factorization of A, 1 + rows solves),

    S lambda = c - G a,   S = G W,   z = a + W lambda,

by least squares on the active rows, so redundant rows (closed loops, a joint doubled)
get the minimum-norm impulses instead of a singular matrix; no new factorization per
trial. :func:`solve_saddle` (statics, where A may be singular until the rows fix it)
factors the KKT matrix of the active rows for each trial, starting from the active set
of the Schur complement when A factors alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from artifem.errors import StepFailed
from artifem.multibody.constraint_rows import RowBlock

__all__ = ["StepRows", "impulses_by_constraint", "solve_constrained", "solve_saddle"]


@dataclass(frozen=True, eq=False)
class StepRows:
    """A constraint's :class:`RowBlock` on the solve's coordinates: G (rows on the
    masters, G P; dense or sparse) and c (the right-hand side, the known velocities'
    G z_k taken off)."""

    block: RowBlock
    G: object
    c: np.ndarray


def _vstack(blocks: list):
    return sparse.vstack(blocks).tocsr() if any(sparse.issparse(x) for x in blocks) else \
        np.vstack(blocks)


#: passes of the active set with bounds that depend on the impulses (friction), at most
BOUND_PASSES = 50


def _active_set(lo: np.ndarray, hi: np.ndarray, tol: float, trial, what: str,
                bounds=None, start=None):
    """(lambda, active mask, what ``trial`` gave last) of the primal-dual active set on
    rows with bounds lo <= lambda <= hi (module docstring). ``trial(active, held)`` solves
    with the active rows as equalities and the others at their ``held`` impulses, and
    returns (lambda, slack of the bounded rows G z - c, extra). ``bounds(lambda) -> (lo,
    hi)``, for bounds that depend on the impulses (Coulomb friction on the normal
    impulses): the active set is found again with the bounds of its last impulses until
    they change by at most 1e-10 of the largest impulse (a fixed point; each pass reuses
    ``trial``'s factorization and starts from the last pass's active set). ``start``:
    the first pass's starting active set, as :func:`_active_set_at` takes it."""
    for _ in range(BOUND_PASSES):
        lam, active, held, extra = _active_set_at(lo, hi, tol, trial, what, start)
        if bounds is None:
            return lam, active, extra
        start = (active, ~active & (held == hi) & (lo < hi), lo == hi)
        lo_new, hi_new = bounds(lam)
        change = max(_bound_change(lo, lo_new), _bound_change(hi, hi_new))
        lo, hi = lo_new, hi_new
        if change <= 1e-10 * float(np.abs(lam).max(initial=0.0)):
            return lam, active, extra
    raise StepFailed(f"{what}: the bounds that depend on the impulses (friction) did not "
                     f"settle in {BOUND_PASSES} passes of the active set")


def _bound_change(old: np.ndarray, new: np.ndarray) -> float:
    finite = np.isfinite(old) | np.isfinite(new)
    return float(np.abs(new[finite] - old[finite]).max(initial=0.0))


def _active_set_at(lo: np.ndarray, hi: np.ndarray, tol: float, trial, what: str,
                   start=None):
    """(lambda, active mask, held impulses, extra) of :func:`_active_set` at fixed bounds.
    Rows with lo < 0 < hi (friction) start active, the other bounded rows held at lo
    (where finite); ``start`` = (active, held at hi, lo = hi) of a previous pass with other
    bounds begins from that pass's active set instead, its rows held at the same side of
    the new bounds (rows whose bounds were equal start as without it)."""
    bounded = np.flatnonzero(np.isfinite(lo) | np.isfinite(hi))
    active = np.ones(lo.size, dtype=bool)
    active[bounded] = (lo[bounded] < 0) & (hi[bounded] > 0)
    at_high = np.zeros(lo.size, dtype=bool)
    if start is not None:
        was_active, was_high, was_pinned = start
        kept = bounded[~was_pinned[bounded]]
        active[kept] = was_active[kept]
        at_high[kept] = was_high[kept]
    held = np.zeros(lo.size)
    held[bounded] = np.where(np.isfinite(lo[bounded]) & ~at_high[bounded], lo[bounded],
                             hi[bounded])
    for _ in range(2 * bounded.size + 10):
        lam, slack, extra = trial(active, held)
        if not bounded.size:
            break
        on, l, low, high = active[bounded], lam[bounded], lo[bounded], hi[bounded]
        outside = np.where(on, np.maximum(low - l, l - high), -np.inf)
        at_low = held[bounded] == low
        # a held row whose relation fails (G z < c at lo, G z > c at hi), unless lo = hi
        violated = np.where(on | (low == high), -np.inf, np.where(at_low, -slack, slack))
        if outside.max() > tol:                     # release: hold at the crossed bound
            k = int(np.argmax(outside))
            active[bounded[k]] = False
            held[bounded[k]] = low[k] if l[k] < low[k] else high[k]
        elif violated.max() > tol:                  # activate the most violated row
            active[bounded[int(np.argmax(violated))]] = True
        else:
            break
    else:
        raise StepFailed(f"{what}: the constraints' active set did not settle")
    return lam, active, held, extra


def _stacked(rows: list):
    """(G, c, lo, hi, bounds) of a list of :class:`StepRows`: bounds is None when every
    block's bounds are fixed, else lambda -> (lo, hi) of the stacked rows."""
    G = _vstack([g.G for g in rows])
    c = np.concatenate([g.c for g in rows])
    lo = np.concatenate([g.block.lo for g in rows])
    hi = np.concatenate([g.block.hi for g in rows])
    if all(g.block.bounds_from is None for g in rows):
        return G, c, lo, hi, None
    ends = np.cumsum([len(g.c) for g in rows])

    def bounds(lam):
        parts = [g.block.bounds(lam[end - len(g.c):end]) for g, end in zip(rows, ends)]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    return G, c, lo, hi, bounds


def _schur_trial(S: np.ndarray, r: np.ndarray, bounded: np.ndarray):
    """The active set's ``trial`` on the Schur complement S = G A^-1 F^T, r = c - G A^-1 b:
    S_aa lambda_a = r_a - S_ah lambda_h by least squares (module docstring)."""
    def trial(active, held):
        on = np.flatnonzero(active)
        lam = np.where(active, 0.0, held)
        if on.size:
            rhs = r[on]
            if np.any(lam):                         # rows held at a non-zero bound
                rhs = rhs - S[np.ix_(on, ~active)] @ lam[~active]
            lam[on] = np.linalg.lstsq(S[np.ix_(on, on)], rhs, rcond=1e-12)[0]
        return lam, S[bounded] @ lam - r[bounded], None

    return trial


def solve_constrained(solver, A, b: np.ndarray, rows: list, what: str,
                      resolver: bool = False, force_rows: list | None = None):
    """(z, lambda, number of active rows) of the system above, by the Schur complement.

    ``solver`` factors A (``factor(A, what).apply(B)``, e.g. DirectSolver); ``rows`` a
    list of :class:`StepRows` (lambda in their order). With ``resolver``, a fourth item:
    ``resolve(b) -> (z, lambda)``, the same system for another right-hand side with c = 0,
    the active rows kept and the others' impulses unchanged (the factorization reused;
    the pressure iterations of :func:`artifem.incompressibility.hold_linearized`).
    ``force_rows`` (one block per entry of ``rows``; default their own G) are the rows F
    of the first block row, A z - F^T lambda = b, when they differ from the constraint
    rows G (Newton on a residual whose constraint forces and constraint values have
    different derivatives: :mod:`artifem.scene.implicit_step`); W = A^-1 F^T, S = G W.
    """
    n = A.shape[0]
    solver.factor(A, what)
    if not rows:
        z = solver.apply(b)

        def resolve(rhs):
            return solver.apply(rhs), np.zeros(0)

        return (z, np.zeros(0), 0, resolve) if resolver else (z, np.zeros(0), 0)
    G, c, lo, hi, bounds = _stacked(rows)
    F = G if force_rows is None else _vstack(force_rows)
    X = solver.apply(np.column_stack([b, F.T.toarray() if sparse.issparse(F) else F.T]))
    a, W = X[:, 0], X[:, 1:]
    S = np.asarray(G @ W)
    r = c - G @ a
    trial = _schur_trial(S, r, np.flatnonzero(np.isfinite(lo) | np.isfinite(hi)))
    lam, active, _ = _active_set(lo, hi, 1e-10 * max(1.0, np.abs(c).max()), trial, what,
                                 bounds)
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


def solve_saddle(solver, kkt, K, b: np.ndarray, rows: list, what: str):
    """(z, lambda, active mask) of K z - G^T lambda = b under ``rows`` (:class:`StepRows`)
    as in :func:`solve_constrained`, each trial one solve of the KKT matrix
    ``kkt(K, G_active)`` = [[K, G_a^T], [G_a, 0]] (statics: K may be singular where the
    rows fix it; ``solver.solve(M, rhs, what)``), the held rows' forces G^T lambda on the
    right-hand side.

    When K alone factors (the body held without the bounded rows: a clamp, joints), the
    active set is first found on the Schur complement of K (:func:`_schur_trial`: one
    factorization, the trials dense and small) and the KKT trials start from it, so they
    confirm it in one factorization instead of one per row activated (a contact of
    hundreds of nodes); their result is the answer either way."""
    n = K.shape[0]
    if not rows:
        return solver.solve(K, b, what), np.zeros(0), np.zeros(0, dtype=bool)
    G, c, lo, hi, bounds = _stacked(rows)
    bounded = np.flatnonzero(np.isfinite(lo) | np.isfinite(hi))
    tol = 1e-10 * max(1.0, np.abs(c).max())
    start = _schur_start(solver, K, b, G, c, lo, hi, bounded, tol, what, bounds) \
        if bounded.size else None

    def trial(active, held):
        on = np.flatnonzero(active)
        lam = np.where(active, 0.0, held)
        force = b if not np.any(lam) else b + np.asarray(G.T @ lam).ravel()
        G_on = G if on.size == len(c) else G[on]
        x = solver.solve(kkt(K, G_on), np.concatenate([force, c[on]]), what)
        z = x[:n]
        lam[on] = -x[n:]                            # K z + G_a^T mu = b: lambda = -mu
        return lam, np.asarray(G[bounded] @ z).ravel() - c[bounded], z

    if start is not None:
        try:
            lam, active, z = _active_set(lo, hi, tol, trial, what, bounds, start)
            return z, lam, active
        except StepFailed:          # a nearly singular K's start: the trials from none
            pass
    lam, active, z = _active_set(lo, hi, tol, trial, what, bounds)
    return z, lam, active


def _schur_start(solver, K, b, G, c, lo, hi, bounded, tol, what, bounds):
    """The starting active set of :func:`solve_saddle` from the Schur complement of K
    (``start`` of :func:`_active_set_at`), or None when K is singular or the active set
    there does not settle."""
    try:
        solver.factor(K, what)
        X = solver.apply(np.column_stack([b, G.T.toarray() if sparse.issparse(G) else G.T]))
    except StepFailed:
        return None
    S = np.asarray(G @ X[:, 1:])
    r = c - G @ X[:, 0]
    try:
        lam, active, _ = _active_set(lo, hi, tol, _schur_trial(S, r, bounded), what, bounds)
    except (StepFailed, np.linalg.LinAlgError):
        return None
    # rows whose given bounds are equal (friction before the normal impulses) start as
    # without a start, the others as the Schur complement's last pass left them
    last_lo, last_hi = bounds(lam) if bounds is not None else (lo, hi)
    at_high = ~active & np.isfinite(last_hi) & (lam >= last_hi) & (last_lo < last_hi)
    return active, at_high, lo == hi


def impulses_by_constraint(rows: list, lam: np.ndarray) -> dict:
    """constraint -> [(RowBlock, impulses)]: lambda of :func:`solve_constrained` split by
    the :class:`StepRows` it was solved with, under each block's owner."""
    out: dict = {}
    start = 0
    for g in rows:
        out.setdefault(g.block.owner, []).append((g.block, lam[start:start + len(g.c)]))
        start += len(g.c)
    return out
