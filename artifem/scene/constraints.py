"""Velocities under constraint rows with bounded impulses: the step's and statics' solve.

Every constraint gives its rows as :class:`~artifem.multibody.constraint_rows.RowBlock`
(bilateral rows: lambda free; limits: lambda >= 0); the layout maps them onto the
solve's coordinates as :class:`StepRows` (G P and the right-hand side c). The step's
KKT system (artifem.scene.scene docstring; ArtiSynth's constrained backward Euler),

    [ A   -G^T ] [ z      ]   [ b ]
    [ G    0   ] [ lambda ] = [ c ],      lambda the constraint impulses,

holds on the active rows; a row with a finite bound is either active (G z = c, lambda
within its bounds) or held at a bound (lambda = lo with G z >= c, or lambda = hi with
G z <= c). Compliant rows (``StepRows.compliance`` = C / h^2,
:mod:`~artifem.multibody.constraint_rows`) put + C / h^2 on the multiplier block's
diagonal: G z + (C / h^2) lambda = c where active, and their slack G z - c + (C / h^2)
lambda where held; both paths and statics take it. The active set is found by a
primal-dual active set (:func:`_active_set`: release the multiplier furthest out of its
bounds, else activate the most violated row, repeat; once a set comes back, the first row
out (Murty's least index) on the multiplier block regularized by PROXIMAL_REGULARIZATION,
positive definite where redundant rows make it singular, so that the pivots cannot
circle); rows with lo = -inf and hi = inf are always active.
Friction rows (``RowBlock.friction``: |lambda_t| <= mu lambda_n) are first a fixed point
around it: the active set again with the bounds of its last impulses (the normal impulses
extrapolated over the last passes by Anderson's mixing), until they settle;
where the passes circle instead (a reduced body under many more friction rows than
coordinates: its impulses are far from unique, and the normal ones jump as the active set
changes), the sliding rows are held at s lambda_n of the same solve (s = +-mu; a row of
the multiplier block, lambda_t - s lambda_n = 0, that is not symmetric) from the last
pass's active set.

:func:`solve_constrained` (the step) solves each trial by one of two paths, chosen by
:func:`use_kkt` (at least KKT_ROWS = 64 rows on a sparse A of more than DENSE_MAX
unknowns: the sparse KKT; else the Schur complement):

- the Schur complement (:class:`_Schur`): with a = A^-1 b and W = A^-1 G^T (one
  factorization of A, 1 + rows solves),

      S lambda = c - G a,   S = G W,   z = a + W lambda,

  by least squares on the active rows, so redundant rows (closed loops, a joint
  doubled, a rigid box's corners) get the minimum-norm impulses of the active rows
  instead of a singular matrix; no new factorization per trial; the active set changes
  one row per trial. Where the rows far outnumber the coordinates (a rigid body on a
  fine contact grid) S is not formed: only its active block and S lambda = G (W lambda);
- the sparse KKT (:class:`_KKT`): the matrix above over all rows, the held rows
  lambda = held, factored by MUMPS with one pattern for every active set (its analysis
  reused), a tiny regularization -eps of the active multipliers removed by iterative
  refinement (redundant rows solve; rows that disagree fall back to the Schur path); the
  active set changes many rows per trial (Hintermueller-Ito-Kunisch, one row per trial
  after BATCH_TRIALS or a repeated set), and a trial on the last factorization's active
  set only solves (the friction passes); an active set that differs from the last
  factored one by at most KKT_UPDATE_ROWS rows corrects that factorization by
  Sherman-Morrison-Woodbury (one blocked solve of as many columns) instead of a new one.

Both start from the last solve's active set and impulses when given an
:class:`ActiveSetMemory` (the scene's: rows named by ``RowBlock.keys``, a contact's point
and direction), so a body at rest takes one trial per step. :func:`solve_saddle` (statics,
where A may be singular until the rows fix it) factors the KKT matrix of the active rows
for each trial, starting from the active set of the Schur complement when A factors
alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy import sparse

from artifem.errors import StepFailed
from artifem.multibody.constraint_rows import RowBlock

__all__ = [
    "ActiveSetMemory",
    "StepRows",
    "impulses_by_constraint",
    "solve_constrained",
    "solve_saddle",
    "use_kkt",
]


@dataclass(frozen=True, eq=False)
class StepRows:
    """A constraint's :class:`RowBlock` on the solve's coordinates: G (rows on the
    masters, G P; dense or sparse), c (the right-hand side, the known velocities'
    G z_k taken off) and ``compliance``: None (hard rows) or the diagonal the rows add
    to the multiplier block, the block's compliance C over h^2 (statics: h = 1)."""

    block: RowBlock
    G: object
    c: np.ndarray
    compliance: np.ndarray | None = None


def _vstack(blocks: list):
    return (
        sparse.vstack(blocks).tocsr()
        if any(sparse.issparse(x) for x in blocks)
        else np.vstack(blocks)
    )


#: passes of the active set with bounds that depend on the impulses (friction), at most
BOUND_PASSES = 50
#: ... the bounds of the passes after this many take the mean of the last impulses
RELAX_PASSES = 8


def _active_set(
    lo: np.ndarray,
    hi: np.ndarray,
    tol: float,
    trial,
    what: str,
    friction=None,
    warm=None,
    batch: bool = False,
    precision=None,
    proximal=None,
):
    """(lambda, active mask, held at hi, what ``trial`` gave last) of the primal-dual
    active set on rows with bounds lo <= lambda <= hi (module docstring; :func:`_pivots`,
    whose ``trial`` it takes). ``friction`` = (normal, mu) over the rows: the friction
    rows' bounds are +-mu lambda_n. First as a fixed point: the active set at fixed bounds
    (a convex problem: the pivots settle), found again with the bounds of its last
    impulses until they change by at most 1e-10 of the largest impulse (each pass starts
    from the last pass's active set; the normal impulses the bounds take are mixed over
    the last ANDERSON_DEPTH passes by :func:`_anderson`; after RELAX_PASSES, the mean of
    those the bounds were of and the new ones); after BOUND_PASSES passes (the passes
    circling a change of the active set: a reduced body under many more friction rows
    than coordinates), the sliding rows held at +-mu lambda_n of the same solve, from the last
    pass's active set; where those pivots circle too, all again without ``warm``.
    ``warm`` = (active, held at hi, known, lambda) of the previous step
    (:class:`ActiveSetMemory`): the first pass takes the bounds of those impulses (0 on
    rows it does not know), and the rows it knows start from it, in the first pass where
    their bounds differ and, where the last pass's bounds were equal, in the next.
    ``precision(exact) -> changed`` (:meth:`_KKT.precision`): the sets are searched by
    trials to a looser residual, and the set that ends the search is confirmed by a
    trial refined to round-off, whose answer is returned (the last pass's, as it is
    then)."""
    if precision is None:
        confirm = None
    else:
        precision(False)

        def confirm():
            return precision(True)

    if friction is None:
        return _pivots(
            lo,
            hi,
            tol,
            trial,
            what,
            None,
            None if warm is None else warm[:3],
            batch,
            confirm,
            proximal,
        )
    fric = friction[0] >= 0
    of = np.maximum(friction[0], 0)

    def bounds(lam):
        cap = friction[1] * np.maximum(lam[of], 0.0)
        return np.where(fric, -cap, lo), np.where(fric, cap, hi)

    own = (lo, hi)
    if warm is not None:
        lo, hi = bounds(warm[3])  # the bounds of the last solve's impulses
    start = None if warm is None else (warm[0], warm[1], warm[2] & (lo != hi))
    # the impulses the current bounds are of (None: the rows' own bounds)
    basis = None if warm is None else warm[3]
    normals = np.unique(of[fric])  # the normal rows the bounds depend on
    history = []  # (g(x), x) of the last passes on those rows
    for k in range(BOUND_PASSES):
        lam, active, at_high, extra = _pivots(
            lo, hi, tol, trial, what, None, start, batch, None, proximal
        )
        use = lo != hi
        start = (active, at_high, use)
        if warm is not None:
            take = ~use & warm[2]
            start = (np.where(take, warm[0], active), np.where(take, warm[1], at_high), use | take)
        lo_new, hi_new = bounds(lam)
        change = max(_bound_change(lo, lo_new), _bound_change(hi, hi_new))
        if change <= 1e-10 * float(np.abs(lam).max(initial=0.0)) and confirm is not None:
            # the pass settled on searched trials: its set again, refined, and where that
            # moved the bounds at all, a refined pass with the bounds of its impulses
            for _ in range(2):
                lam, active, at_high, extra = _pivots(
                    lo,
                    hi,
                    tol,
                    trial,
                    what,
                    None,
                    (active, at_high, np.ones(lo.size, dtype=bool)),
                    batch,
                    confirm,
                    proximal,
                )
                lo_new, hi_new = bounds(lam)
                change = max(_bound_change(lo, lo_new), _bound_change(hi, hi_new))
                if change == 0.0:
                    break
                lo, hi = lo_new, hi_new
            precision(False)
        if change <= 1e-10 * float(np.abs(lam).max(initial=0.0)):
            if precision is not None:
                precision(True)
            return lam, active, at_high, extra
        # the next bounds: of the normal impulses extrapolated by Anderson's mixing of the
        # last passes (an affine map while the active set stays: the passes converge
        # linearly, the mixing in a few); after RELAX_PASSES the mean of the impulses they
        # were of and the new ones: the passes can cycle (a pad draping over a ball with
        # friction: rows that slide in one pass stick in the next), and the mean damps it
        if k < RELAX_PASSES:
            if basis is not None:
                history.append((lam[normals].copy(), basis[normals]))
                del history[:-ANDERSON_DEPTH]
            basis = lam.copy()
            if history:
                basis[normals] = np.maximum(_anderson(history), 0.0)
        else:
            basis = 0.5 * (basis + lam)
        lo, hi = bounds(basis)
    try:
        return _pivots(
            lo,
            hi,
            tol,
            trial,
            what,
            friction,
            (active, at_high, np.ones(lo.size, dtype=bool)),
            batch,
            confirm,
            proximal,
        )
    except StepFailed:
        if warm is None:
            raise
    # the last step's active set may start the passes inside a cycle: all again, cold
    return _active_set(*own, tol, trial, what, friction, None, batch, precision, proximal)


#: passes the friction bounds' Anderson mixing remembers
ANDERSON_DEPTH = 4


def _anderson(history: list) -> np.ndarray:
    """Anderson's mixing (type II, Walker and Ni 2011) of a fixed point x = g(x) from
    ``history`` [(g(x_j), x_j)], oldest first: g(x_k) - dG gamma, gamma the least-squares
    solution of dF gamma = f_k (f = g(x) - x, dF and dG the differences of consecutive
    f and g); g(x_k) alone with one pass."""
    gk = history[-1][0]
    if len(history) < 2:
        return gk
    g = np.column_stack([h[0] for h in history])
    f = g - np.column_stack([h[1] for h in history])
    dF, dG = np.diff(f, axis=1), np.diff(g, axis=1)
    gamma = np.linalg.lstsq(dF, f[:, -1], rcond=1e-10)[0]
    return gk - dG @ gamma


def _bound_change(old: np.ndarray, new: np.ndarray) -> float:
    finite = np.isfinite(old) | np.isfinite(new)
    return float(np.abs(new[finite] - old[finite]).max(initial=0.0))


#: many-at-once trials of the active set before it changes one row per trial
BATCH_TRIALS = 12
#: one row per trial (Bland's rule) comes back to the same set at most this many times
#: before the pivots are taken to circle (they are deterministic: each comeback repeats
#: the circle; the foot's refused full load spent most of its 45 s in such circles)
BLAND_VISITS = 2


def _pivots(
    lo: np.ndarray,
    hi: np.ndarray,
    tol: float,
    trial,
    what: str,
    friction=None,
    start=None,
    batch: bool = False,
    confirm=None,
    proximal=None,
):
    """(lambda, active mask, held at hi, what ``trial`` gave last) of the primal-dual
    active set on rows with bounds lo <= lambda <= hi (module docstring).

    ``trial(active, held, coupled)`` solves with the active rows as equalities, the other
    rows at their ``held`` impulses except the ``coupled`` ones = (rows, their normal rows,
    s): held friction rows whose normal is active, at lambda_row = s lambda_normal of the
    same solve (s = +-mu: sliding); it returns (lambda, slack of the bounded rows G z - c,
    extra). ``friction`` = (normal, mu) over the rows (:class:`~artifem.multibody.
    constraint_rows.Friction`, stacked): the friction rows' bounds are +-mu lambda_n of
    the trial (their lo, hi are not used); a friction row whose normal is held is held at
    s times the normal's held impulse. Rows start active where lo < 0 < hi, bounded rows
    held at lo (where finite), friction rows sliding at -mu; ``start`` = (active, held at
    hi, use): the rows of ``use`` start from it instead. One row per trial: release the
    multiplier furthest outside its bounds, else activate the most violated row (once a
    set comes back, the first row out, released or activated: Murty's least-index rule).
    ``batch`` (Hintermueller, Ito and Kunisch's primal-dual active set): release every
    multiplier outside its bounds and activate every violated row in one trial; after
    ``BATCH_TRIALS`` such trials, or when a set comes back (cycling), one row per trial
    from there. ``confirm()``: called when a
    set holds; True (the trial was a search's, looser than round-off: :meth:`_KKT.
    precision`) tries it once more, refined, and goes on from that. ``proximal()``: called
    when Bland's rule starts; the trials from then on solve with the multiplier block
    regularized (:meth:`_Schur.proximal`, :meth:`_KKT.proximal`), so that the pivots are
    those of a P-matrix, where Murty's least-index rule cannot cycle."""
    m = lo.size
    normal, mu = (np.full(m, -1), np.zeros(m)) if friction is None else friction
    fric = normal >= 0
    of = np.maximum(normal, 0)  # each row's normal (itself elsewhere)
    bounded = np.flatnonzero(np.isfinite(lo) | np.isfinite(hi) | fric)
    active = np.ones(m, dtype=bool)
    active[bounded] = (lo[bounded] < 0) & (hi[bounded] > 0) & ~fric[bounded]
    at_high = np.zeros(m, dtype=bool)
    if start is not None:
        was_active, was_high, known = start
        kept = bounded[known[bounded]]
        active[kept] = was_active[kept]
        at_high[kept] = was_high[kept]
    held = np.zeros(m)
    held[bounded] = np.where(np.isfinite(lo[bounded]) & ~at_high[bounded], lo[bounded], hi[bounded])
    side = np.where(at_high, mu, -mu)  # a held friction row: side lambda_n
    batches = BATCH_TRIALS if batch else 0
    seen, bland, cycled = set(), False, {}
    for _ in range(2 * bounded.size + 10 + batches):
        sliding = fric & ~active
        couple = sliding & active[of]
        held[couple] = 0.0
        loose = sliding & ~active[of]  # its normal held (at 0: no friction)
        held[loose] = side[loose] * np.maximum(held[of[loose]], 0.0)
        rows = np.flatnonzero(couple)
        lam, slack, extra = trial(active, held, (rows, normal[rows], side[rows]))
        if bounded.size:
            cap = mu * np.maximum(lam[of], 0.0)
            low = np.where(fric, -cap, lo)[bounded]
            high = np.where(fric, cap, hi)[bounded]
            on, l, f = active[bounded], lam[bounded], fric[bounded]
            outside = np.where(on, np.maximum(low - l, l - high), -np.inf)
            at_low = np.where(f, side[bounded] < 0, held[bounded] == low)
            # a held row whose relation fails (G z < c at lo, G z > c at hi), unless lo = hi
            violated = np.where(on | (low == high), -np.inf, np.where(at_low, -slack, slack))
        if not bounded.size or max(outside.max(), violated.max()) <= tol:  # the set holds
            if confirm is not None and confirm():
                continue
            break
        state = (
            np.packbits(active).tobytes()
            + np.packbits(np.where(fric, side > 0, held == hi)).tobytes()
        )
        if batches > 0:
            out, bad = outside > tol, violated > tol
            rel = bounded[out]
            active[rel] = False
            below = l[out] < low[out]
            held[rel] = np.where(below, low[out], high[out])
            side[rel] = np.where(below, -mu[rel], mu[rel])
            active[bounded[bad]] = True
            batches = batches - 1 if state not in seen else 0
            seen.add(state)
            continue
        # one row per trial: the furthest out; once a set comes back (the sliding rows'
        # coupling is not symmetric, and redundant rows make the multiplier block singular:
        # the pivots can cycle), the first row out, released or activated (Murty's least
        # index, Bland's rule of the LCP), on the regularized block (``proximal``)
        if state in seen and not bland:
            bland = True
            if proximal is not None:
                proximal()
        seen.add(state)
        if bland:  # Bland's pivots are deterministic: a set seen twice is a cycle
            cycled[state] = cycled.get(state, 0) + 1
            if cycled[state] > BLAND_VISITS:
                raise StepFailed(
                    f"{what}: the constraints' active set did not settle (its pivots circle)"
                )
        if bland:  # the first row out, released or activated (Murty's least index)
            k = int(np.flatnonzero(np.maximum(outside, violated) > tol)[0])
            release = outside[k] > tol
        else:  # release the furthest out, else activate the most violated
            release = outside.max() > tol
            k = int(np.argmax(outside if release else violated))
        j = bounded[k]
        if release:  # hold at the crossed bound
            active[j] = False
            held[j] = low[k] if l[k] < low[k] else high[k]
            side[j] = -mu[j] if l[k] < low[k] else mu[j]
        else:
            active[j] = True
    else:
        raise StepFailed(f"{what}: the constraints' active set did not settle")
    high_side = np.where(fric, side > 0, (held == hi) & (lo < hi))
    return lam, active, ~active & high_side, extra


def _compliance(rows: list) -> np.ndarray | None:
    """The stacked ``StepRows.compliance`` (C / h^2), or None when every row is hard."""
    if all(g.compliance is None or not np.any(g.compliance) for g in rows):
        return None
    return np.concatenate(
        [
            np.zeros(len(g.c)) if g.compliance is None else np.asarray(g.compliance, dtype=float)
            for g in rows
        ]
    )


def _stacked(rows: list):
    """(G, c, lo, hi, friction) of a list of :class:`StepRows`: friction is None when no
    block has any, else (normal, mu) over the stacked rows (normal -1 on rows that are not
    friction rows)."""
    G = _vstack([g.G for g in rows])
    c = np.concatenate([g.c for g in rows])
    lo = np.concatenate([g.block.lo for g in rows])
    hi = np.concatenate([g.block.hi for g in rows])
    if all(g.block.friction is None for g in rows):
        return G, c, lo, hi, None
    normal, mu, start = [], [], 0
    for g in rows:
        m = len(g.c)
        f = g.block.friction
        normal.append(
            np.full(m, -1) if f is None else np.where(f.normal >= 0, f.normal + start, -1)
        )
        mu.append(np.zeros(m) if f is None else f.mu)
        start += m
    return G, c, lo, hi, (np.concatenate(normal), np.concatenate(mu))


#: the sparse KKT path (:func:`solve_constrained`) from this many rows on, where A is sparse
#: and larger than the dense limit; below, the Schur complement
KKT_ROWS = 64
#: the KKT's multiplier block on an active row: -KKT_REGULARIZATION times an estimate of
#: the row's diagonal of S (sum_j G_ij^2 / |A_jj|), removed by iterative refinement
KKT_REGULARIZATION = 1e-10
#: ... and of the trials after the pivots came back to a set (``proximal`` of
#: :func:`_pivots`), kept in their answer: large enough that a block of near-parallel rows
#: stays positive definite in round-off (measured on random feasible problems with rows
#: parallel to 1e-9, where the unregularized pivots circle: at 1e-10 two of 26 still
#: circle, at 1e-8 none, their constraints met to 1e-7 of the right-hand side; at 1e-6
#: to 1e-4), small enough to be a compliance of 1e-8 of the rows' own.
PROXIMAL_REGULARIZATION = 1e-8
#: iterative refinement steps of the regularized KKT solve, at most
KKT_REFINEMENT = 4
#: the residual (relative) at which a trial of the KKT's active set stops refining while
#: the set is searched: one solve, the regularization's error (about 1e-10) left in; the
#: set found is then confirmed by a trial refined to round-off (``precision`` of
#: :func:`_active_set`)
KKT_TRIAL_RESIDUAL = 1e-9
#: rows of the KKT's multiplier block that may differ from the last factored matrix's
#: (an active set changed by a few rows): a low-rank correction of it, not a new one
KKT_UPDATE_ROWS = 96
#: the path of :func:`solve_constrained` when its caller does not choose: "auto"
#: (:func:`use_kkt`), "kkt" or "schur" (set by benchmarks and tests to compare them)
DEFAULT_PATH = "auto"


def use_kkt(A, rows: int) -> bool:
    """Whether :func:`solve_constrained` takes the sparse KKT path: ``rows`` at least
    KKT_ROWS and A sparse and larger than the dense solver's limit (DENSE_MAX). The
    Schur complement's cost grows with one back-substitution per row and a dense S; the
    KKT's is a factorization of n + rows unknowns per change of the active set. Small
    dense A (rigid and reduced bodies) keep the Schur complement at any number of rows."""
    from artifem.scene.direct_solver import DENSE_MAX

    return rows >= KKT_ROWS and sparse.issparse(A) and A.shape[0] > DENSE_MAX


def row_keys(block: RowBlock):
    """A block's row keys (``RowBlock.keys``) as one comparable value per row (None when
    the block has none)."""
    keys = block.keys
    if keys is None:
        return None
    keys = np.ascontiguousarray(np.asarray(keys, dtype=np.int64).reshape(len(block), -1))
    return keys.view(np.dtype((np.void, keys.dtype.itemsize * keys.shape[1]))).ravel()


def find_keys(known, keys):
    """(index into ``known`` of each of ``keys``, found mask): rows looked up by their
    :func:`row_keys`."""
    if known.size == 0:
        return np.zeros(len(keys), dtype=int), np.zeros(len(keys), dtype=bool)
    order = np.argsort(known)
    where = np.minimum(np.searchsorted(known, keys, sorter=order), len(order) - 1)
    found = order[where]
    return found, known[found] == keys


class ActiveSetMemory:
    """The active set and impulses of the last solve by row keys (``RowBlock.keys``), per
    constraint: the next solve's first trial starts from them (a warm start; the bounds
    that depend on the impulses from the last impulses). Rows whose block has no keys,
    and rows it has not seen, start as without it."""

    def __init__(self):
        self._sets: dict = {}

    def save(self) -> dict:
        """What :meth:`restore` goes back to (a failed load increment's solves forgotten)."""
        return self._sets

    def restore(self, saved: dict) -> None:
        self._sets = saved

    def start(self, rows: list):
        """(active, held at hi, known, lambda) over the stacked rows (False and 0 where
        not known), or None when no row is known."""
        parts, any_known = [], False
        for g in rows:
            m = len(g.c)
            keys = row_keys(g.block)
            mem = self._sets.get(id(g.block.owner))
            if keys is None or mem is None or mem[0].dtype != keys.dtype:
                parts.append((*(np.zeros(m, bool),) * 3, np.zeros(m)))
                continue
            found, known = find_keys(mem[0], keys)
            any_known |= bool(known.any())
            parts.append(
                (
                    known & mem[1][found],
                    known & mem[2][found],
                    known,
                    np.where(known, mem[3][found], 0.0),
                )
            )
        if not any_known:
            return None
        return tuple(np.concatenate([p[i] for p in parts]) for i in range(4))

    def keep(self, rows: list, active: np.ndarray, at_high: np.ndarray, lam: np.ndarray) -> None:
        """Remember the solve's active set, rows held at hi and impulses under their keys."""
        self._sets = {}
        start = 0
        by_owner: dict = {}
        for g in rows:
            m = len(g.c)
            keys = row_keys(g.block)
            if keys is not None:
                sl = slice(start, start + m)
                by_owner.setdefault(id(g.block.owner), []).append(
                    (keys, active[sl], at_high[sl], lam[sl])
                )
            start += m
        for owner, parts in by_owner.items():
            self._sets[owner] = tuple(np.concatenate([p[i] for p in parts]) for i in range(4))


def solve_constrained(
    solver,
    A,
    b: np.ndarray,
    rows: list,
    what: str,
    resolver: bool = False,
    force_rows: list | None = None,
    memory: ActiveSetMemory | None = None,
    path: str | None = None,
    info: dict | None = None,
):
    """(z, lambda, number of active rows) of the system above, by the Schur complement
    or, for many rows on a large sparse A (:func:`use_kkt`), the sparse KKT matrix.

    ``solver`` factors A (``factor(A, what).apply(B)``, e.g. DirectSolver); ``rows`` a
    list of :class:`StepRows` (lambda in their order). With ``resolver``, a fourth item:
    ``resolve(b) -> (z, lambda)``, the same system for another right-hand side with c = 0,
    the active rows kept and the others' impulses unchanged (the factorization reused;
    the pressure iterations of :func:`artifem.incompressibility.hold_linearized`).
    ``force_rows`` (one block per entry of ``rows``; default their own G) are the rows F
    of the first block row, A z - F^T lambda = b, when they differ from the constraint
    rows G (Newton on a residual whose constraint forces and constraint values have
    different derivatives: :mod:`artifem.scene.implicit_step`); W = A^-1 F^T, S = G W.
    ``memory``: an :class:`ActiveSetMemory`, the warm start (read, then updated).
    ``path``: "auto" (:func:`use_kkt`), "schur" or "kkt" (default DEFAULT_PATH).
    ``info``: a dict, filled with the path, the trials of the active set and the
    factorizations.
    """
    n = A.shape[0]
    if not rows:
        solver.factor(A, what)
        z = solver.apply(b)
        if info is not None:
            info.update(path="none", trials=1, factorizations=1)

        def resolve(rhs):
            return solver.apply(rhs), np.zeros(0)

        return (z, np.zeros(0), 0, resolve) if resolver else (z, np.zeros(0), 0)
    G, c, lo, hi, friction = _stacked(rows)
    F = G if force_rows is None else _vstack(force_rows)
    path = path or DEFAULT_PATH
    if path == "auto":
        path = "kkt" if use_kkt(A, len(c)) else "schur"
    warm = memory.start(rows) if memory is not None else None
    tol = 1e-10 * max(1.0, np.abs(c).max())
    system = None
    C = _compliance(rows)
    if path == "kkt":
        system = _KKT(solver, A, b, G, F, c, lo, hi, what, C)
        try:
            lam, active, at_high, z = _active_set(
                lo,
                hi,
                tol,
                system.trial,
                what,
                friction,
                warm,
                batch=True,
                precision=system.precision,
                proximal=system.proximal,
            )
        except _Inconsistent:  # redundant active rows that disagree: least squares
            path, system = "schur", None
    if system is None:
        system = _Schur(solver, A, b, G, F, c, lo, hi, what, C)
        lam, active, at_high, z = _active_set(
            lo, hi, tol, system.trial, what, friction, warm, proximal=system.proximal
        )
    if not np.all(np.isfinite(z)):
        raise StepFailed(f"{what}: non-finite velocities")
    assert z.shape == (n,)
    if memory is not None:
        memory.keep(rows, active, at_high, lam)
    if info is not None:
        info.update(
            path=path,
            trials=system.trials,
            factorizations=system.factorizations,
            updates=getattr(system, "updates", 0),
        )
    if not resolver:
        return z, lam, int(active.sum())
    return z, lam, int(active.sum()), system.resolver(active)


def _least_squares(M: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """The minimum-norm least-squares solution of M x = rhs, singular values below 1e-12
    of the largest dropped: LAPACK's complete orthogonal factorization (gelsy: QR with
    column pivoting), 3-4x faster than the SVD (gelsd) on the active blocks of a reduced
    body's contacts (60-150 rows, rank at most its coordinates), with the same answer."""
    return scipy.linalg.lstsq(M, rhs, cond=1e-12, lapack_driver="gelsy", check_finite=False)[0]


class _Schur:
    """Trials of the active set by the Schur complement (module docstring): A factored
    once, W = A^-1 F^T, S = G W, least squares on the active rows. Many more rows than
    coordinates (rigid bodies on fine contact grids: S of rank n at most, m x m): S is
    not formed, only its active block G_a W_a, and S lambda as G (W lambda). ``C``: None
    or the rows' compliance over h^2, added to S's diagonal."""

    def __init__(self, solver, A, b, G, F, c, lo, hi, what, C=None):
        solver.factor(A, what)
        X = solver.apply(np.column_stack([b, F.T.toarray() if sparse.issparse(F) else F.T]))
        self.solver, self.G = solver, G
        self.a, self.W = X[:, 0], X[:, 1:]
        m, n = self.W.shape[1], self.W.shape[0]
        self.S = None if m >= KKT_ROWS and m > 4 * n else np.asarray(G @ self.W)
        self.r = c - G @ self.a
        self.bounded = np.flatnonzero(np.isfinite(lo) | np.isfinite(hi))
        self.C = C
        self.trials, self.factorizations = 0, 1
        self._regularization = None  # :meth:`proximal`

    def proximal(self) -> None:
        """The active blocks from now on regularized, S + eps I with eps
        PROXIMAL_REGULARIZATION times S's diagonal (compliant rows: at least their C / h^2):
        positive definite, so that the pivots are a P-matrix's (:func:`_pivots`); redundant
        rows that disagree then part by their bounds instead of a least-squares
        compromise."""
        diag = np.abs(
            np.asarray(self.G.multiply(self.W.T).sum(axis=1)).ravel()
            if sparse.issparse(self.G)
            else np.einsum("ij,ji->i", self.G, self.W)
        )
        eps = PROXIMAL_REGULARIZATION * np.where(diag > 0, diag, max(diag.max(initial=0.0), 1e-300))
        self._regularization = eps if self.C is None else np.maximum(eps - self.C, 0.0)

    def _block(self, on, cols):
        """S[on, cols]."""
        if self.S is not None:
            return self.S[np.ix_(on, cols)]
        return np.asarray(self.G[on] @ self.W[:, cols])

    def _active_block(self, on):
        """S[on, on] + diag(C[on]) (+ the :meth:`proximal` regularization)."""
        S = self._block(on, on)
        if self.C is not None:
            S = S + np.diag(self.C[on])
        if self._regularization is not None:
            S = S + np.diag(self._regularization[on])
        return S

    def _coupled_block(self, on, coupled):
        """S[on, on] + diag(C[on]) + S[on, h] P: the held friction rows h at s times their
        normals' impulses (P: h x on, s at each row's normal)."""
        M = self._active_block(on)
        rows, normals, s = coupled
        if rows.size:
            P = np.zeros((rows.size, on.size))
            P[np.arange(rows.size), np.searchsorted(on, normals)] = s
            M = M + self._block(on, rows) @ P
        return M

    def trial(self, active, held, coupled):
        self.trials += 1
        r = self.r
        on = np.flatnonzero(active)
        lam = np.where(active, 0.0, held)
        if on.size:
            rhs = r[on]
            if np.any(lam):  # rows held at a non-zero bound
                off = np.flatnonzero(~active)
                rhs = rhs - (
                    self._block(on, off) @ lam[off]
                    if self.S is not None
                    else np.asarray(self.G[on] @ (self.W[:, off] @ lam[off])).ravel()
                )
            lam[on] = _least_squares(self._coupled_block(on, coupled), rhs)
            lam[coupled[0]] = coupled[2] * lam[coupled[1]]
        self._coupled = coupled
        Wl = self.W @ lam
        if self.S is not None:
            slack = self.S[self.bounded] @ lam - r[self.bounded]
        else:
            slack = np.asarray(self.G[self.bounded] @ Wl).ravel() - r[self.bounded]
        if self.C is not None:
            slack = slack + self.C[self.bounded] * lam[self.bounded]
        return lam, slack, self.a + Wl

    def resolver(self, active):
        on = np.flatnonzero(active)
        G, W, solver = self.G, self.W, self.solver
        rows, normals, s = self._coupled
        S_on = self._coupled_block(on, self._coupled) if on.size else None

        def resolve(rhs):
            a = solver.apply(rhs)
            mu = np.zeros(W.shape[1])
            if on.size:
                mu[on] = _least_squares(S_on, -(G @ a)[on])
                mu[rows] = s * mu[normals]
            return a + W @ mu, mu

        return resolve


class _Inconsistent(Exception):
    """The KKT's refinement did not converge: redundant active rows whose right-hand
    sides disagree (no z meets them all), which the Schur complement's least squares
    takes."""


class _KKT:
    """Trials of the active set on the sparse KKT matrix of all rows,

        [ A   -F^T ] [ z      ]   [ b           ]
        [ D G  E   ] [ lambda ] = [ c or held   ],

    D = 1, E = -eps on the active rows (G z - eps lambda = c), D = 0, E = 1 on the others
    (lambda = held): one pattern for every active set, so each factorization after the
    first reuses MUMPS' analysis, and a trial whose active set is that of the last
    factorization only solves. eps (KKT_REGULARIZATION times the row's diagonal of S
    estimated from diag A) lets redundant active rows solve, and iterative refinement on
    the matrix with eps = 0 removes it (a proximal point iteration: the redundant rows'
    impulses stay near the minimum-norm ones). Redundant active rows that disagree
    (no z meets them all) leave a residual the refinement cannot remove: the solve then
    falls back to the Schur complement (:class:`_Inconsistent`). Compliant active rows
    (``C`` = C / h^2 > 0) have E = C in the refinement's matrix and max(C, eps) in the
    factored one (E > 0: S + E is positive definite). Sliding friction rows held at
    s lambda_n (:func:`_pivots`' ``coupled``) have E = [1 at the row, -s at its normal]: a
    pattern of their own, analysed anew."""

    def __init__(self, solver, A, b, G, F, c, lo, hi, what, C=None):
        n, m = A.shape[0], len(c)
        Gs, Fs = sparse.csr_matrix(G), sparse.csr_matrix(F)
        K = sparse.bmat([[sparse.csr_matrix(A), -Fs.T], [Gs, sparse.identity(m)]], format="csr")
        K.sort_indices()
        self.K, self.n, self.m = K, n, m
        start = K.indptr[n]
        row = np.repeat(np.arange(m), np.diff(K.indptr[n:]))
        self._bottom = (start, row, K.indices[start:] == n + row, K.data[start:].copy())
        diag = np.abs(sparse.csr_matrix(A).diagonal())
        diag = np.where(diag > 0, diag, max(diag.max(initial=0.0), 1e-300))
        s = np.asarray(Gs.multiply(Gs) @ (1.0 / diag)).ravel()
        self._diag_S = np.where(s > 0, s, 1.0)
        self.C = np.zeros(m) if C is None else C
        self._regularize(KKT_REGULARIZATION)
        self.solver, self.b, self.c, self.G, self.what = solver, b, c, Gs, what
        self._abs_A = abs(sparse.csr_matrix(A))
        self.bounded = np.flatnonzero(np.isfinite(lo) | np.isfinite(hi))
        self.trials, self.factorizations, self.updates = 0, 0, 0
        self._factored = self._base = None
        self._Z = {}  # the update's columns K_f^-1 e_row (:meth:`_columns`)
        #: trials stop refining at KKT_TRIAL_RESIDUAL (:meth:`precision`)
        self.searching = False
        self._last, self._reused = None, False  # (key, rhs, x) of the last solve
        self._proximal = False

    def _regularize(self, relative: float) -> None:
        """eps: ``relative`` times the rows' diagonal of S; compliant rows: E = C (S + C
        positive definite), at least the regularization (a C below it is restored by the
        refinement, as eps is on hard rows)."""
        eps = relative * self._diag_S
        self.eps = np.where(self.C > 0, -np.maximum(self.C, eps), eps)

    def proximal(self) -> None:
        """The trials from now on solve the matrix regularized by PROXIMAL_REGULARIZATION
        itself (no refinement to eps = 0): positive definite multiplier blocks
        (:func:`_pivots`), and redundant rows that disagree part by their bounds (no
        :class:`_Inconsistent`)."""
        self._proximal = True
        self._regularize(PROXIMAL_REGULARIZATION)
        self.forget()

    def _matrices(self, active, coupled):
        """(regularized K, K with eps = 0) of an active set; the ``coupled`` sliding rows'
        lambda_t - s lambda_n = 0 (entries outside the usual pattern: a new analysis)."""
        start, row, diag, data = self._bottom
        on = active[row]
        K, K0 = self.K.copy(), self.K.copy()
        K.data[start:] = np.where(diag, np.where(on, -self.eps[row], 1.0), data * on)
        K0.data[start:] = np.where(
            diag, np.where(on, -self.eps[row] if self._proximal else self.C[row], 1.0), data * on
        )
        rows, normals, s = coupled
        if rows.size:
            n = self.n
            E = sparse.csr_matrix((-s, (n + rows, n + normals)), shape=K.shape)
            K, K0 = (K + E).tocsr(), (K0 + E).tocsr()
        return K, K0

    def _solve(self, active, coupled, rhs):
        s = np.zeros(self.m)
        s[coupled[0]] = coupled[2]
        key = active.tobytes() + s.tobytes()
        if self._factored is None or self._factored[0] != key:
            self._prepare(key, active, coupled, s)
        K0, apply = self._factored[1], self._factored[2]
        last = self._last  # the same system solved last (a search's trial)
        self._reused = last is not None and last[0] == key and np.array_equal(last[1], rhs)
        x = last[2] if self._reused else apply(rhs)
        # the residual against the rhs and |A| |z| (not the multipliers' columns: those of
        # disagreeing redundant rows grow as 1 / eps)
        scale = max(
            np.abs(rhs).max(initial=0.0),
            float((self._abs_A @ np.abs(x[: self.n])).max(initial=0.0)),
            1e-300,
        )
        enough = (KKT_TRIAL_RESIDUAL if self.searching else 1e-15) * scale
        for k in range(KKT_REFINEMENT + 1):
            res = rhs - K0 @ x
            if np.abs(res).max(initial=0.0) <= enough:
                break
            if k == KKT_REFINEMENT:
                if np.abs(res).max() > 1e-9 * scale:
                    if self._factored[3]:  # an update: the exact factorization first
                        self._prepare(key, active, coupled, s, update=False)
                        self._last = None
                        return self._solve(active, coupled, rhs)
                    raise _Inconsistent
                break
            x = x + apply(res)
        self._last = (key, rhs, x)
        return x

    def _prepare(self, key, active, coupled, s, update: bool = True):
        """The matrices of an active set and how to solve with them: a new factorization,
        or, where at most KKT_UPDATE_ROWS rows of the multiplier block differ from the
        last factored matrix K_f, K_f corrected by Sherman-Morrison-Woodbury,
        K^-1 b = x - Z (I + D Z)^-1 D x with x = K_f^-1 b, D the rows' change (rows
        n + i), Z = K_f^-1 [e_{n+i}]."""
        K, K0 = self._matrices(active, coupled)
        base = self._base
        if update and base is not None:
            changed = np.flatnonzero((active != base[1]) | (s != base[2]))
            if not changed.size:  # back to the factored set
                self._factored = (key, K0, self.solver.apply, False)
                return
            if changed.size <= KKT_UPDATE_ROWS:
                rows = self.n + changed
                D = (K[rows] - base[0][rows]).tocsr()
                Z = self._columns(rows)
                cap = np.eye(rows.size) + np.asarray(D @ Z)
                lu = scipy.linalg.lu_factor(cap, check_finite=False)
                pivots = np.abs(np.diag(lu[0]))
                if np.all(np.isfinite(lu[0])) and pivots.min(initial=1.0) > 1e-10 * max(
                    pivots.max(initial=1.0), 1.0
                ):
                    solver = self.solver

                    def apply(b):
                        x = solver.apply(b)
                        return x - Z @ scipy.linalg.lu_solve(lu, D @ x, check_finite=False)

                    self.updates += 1
                    self._factored = (key, K0, apply, True)
                    return
        self.solver.factor(K, self.what)
        self.factorizations += 1
        self._base = (K, active.copy(), s.copy())
        self._factored = (key, K0, self.solver.apply, False)
        self._Z = {}

    def _columns(self, rows: np.ndarray) -> np.ndarray:
        """Z = K_f^-1 [e_row for row in rows] of the factored K_f, each column solved once
        per factorization (the trials' sets differ from its set by overlapping rows)."""
        new = [r for r in rows if r not in self._Z]
        if new:
            U = np.zeros((self.K.shape[0], len(new)))
            U[new, np.arange(len(new))] = 1.0
            X = self.solver.apply(U).reshape(U.shape)
            self._Z.update(zip(new, X.T))
        return np.column_stack([self._Z[r] for r in rows])

    def forget(self) -> None:
        """The solver factored something else: the next trial factors again."""
        self._factored = self._base = self._last = None
        self._Z = {}

    def precision(self, exact: bool) -> bool:
        """Trials refined to round-off (``exact``), or stopped at KKT_TRIAL_RESIDUAL while
        an active set is searched (one solve each instead of two: the regularization's
        error, about 1e-10, is far below what decides a row); whether that changed. A
        trial of the last solve's set and right-hand side refines its answer (one solve)
        and is not counted again (:func:`_pivots`' ``confirm``)."""
        changed = self.searching == exact
        self.searching = not exact
        return changed

    def trial(self, active, held, coupled):
        n = self.n
        x = self._solve(active, coupled, np.concatenate([self.b, np.where(active, self.c, held)]))
        self.trials += not self._reused
        z, lam = x[:n], x[n:]
        lam = np.where(active, lam, held)
        lam[coupled[0]] = coupled[2] * lam[coupled[1]]
        self._coupled = coupled
        slack = (
            np.asarray(self.G[self.bounded] @ z).ravel()
            - self.c[self.bounded]
            + self.C[self.bounded] * lam[self.bounded]
        )
        return lam, slack, z

    def resolver(self, active):
        n, m, coupled = self.n, self.m, self._coupled
        rows, normals, s = coupled

        def resolve(rhs):
            x = self._solve(active, coupled, np.concatenate([rhs, np.zeros(m)]))
            mu = np.where(active, x[n:], 0.0)
            mu[rows] = s * mu[normals]
            return x[:n], mu

        return resolve


def solve_saddle(
    solver, kkt, K, b: np.ndarray, rows: list, what: str, memory: ActiveSetMemory | None = None
):
    """(z, lambda, active mask) of K z - G^T lambda = b under ``rows`` (:class:`StepRows`)
    as in :func:`solve_constrained` (statics: K may be singular where the rows fix it).
    A sparse K's trials solve the sparse KKT matrix of all rows (:class:`_KKT`: one
    factorization, low-rank updates while a few rows change); a dense K's, or where
    redundant active rows disagree, each trial factors ``kkt(K, G_active)`` =
    [[K, G_a^T], [G_a, 0]] (``solver.solve(M, rhs, what)``), the held rows' forces
    G^T lambda on the right-hand side.

    When K alone factors (the body held without the bounded rows: a clamp, joints), the
    active set is first found on the Schur complement of K (one factorization, the trials
    dense and small) and the KKT trials start from it, so they confirm it in one
    factorization instead of one per row activated (a contact of hundreds of nodes); their
    result is the answer either way. Else compliant rows that touch or cross (c >= 0) start
    active (a body held by an elastic foundation alone)."""
    n = K.shape[0]
    if not rows:
        return solver.solve(K, b, what), np.zeros(0), np.zeros(0, dtype=bool)
    G, c, lo, hi, friction = _stacked(rows)
    C = _compliance(rows)
    bounded = np.flatnonzero(np.isfinite(lo) | np.isfinite(hi))
    tol = 1e-10 * max(1.0, np.abs(c).max())
    if sparse.issparse(K):
        # the sparse KKT of all rows: one pattern, MUMPS' analysis reused, a few rows'
        # change of the active set a low-rank update (the loaded foot's refused full load:
        # 4 s against 45 s of one factorization per trial)
        system = _KKT(solver, K, b, G, G, c, lo, hi, what, C)
        try:
            return _saddle_trials(
                lambda warm: _active_set(
                    lo,
                    hi,
                    tol,
                    system.trial,
                    what,
                    friction,
                    warm=warm,
                    precision=system.precision,
                    proximal=system.proximal,
                ),
                system.forget,
                solver,
                K,
                b,
                G,
                c,
                lo,
                hi,
                C,
                bounded,
                friction,
                what,
                memory,
                rows,
            )
        except _Inconsistent:  # redundant rows that disagree: each trial factored
            pass

    def trial(active, held, coupled):
        on = np.flatnonzero(active)
        lam = np.where(active, 0.0, held)
        force = b if not np.any(lam) else b + np.asarray(G.T @ lam).ravel()
        G_on = G if on.size == len(c) else G[on]
        M = kkt(K, G_on)
        if C is not None and on.size:  # G dq + C lambda = c, lambda = -mu
            M = _minus_diagonal(M, n, C[on])
        rows_h, normals, s = coupled
        if rows_h.size:  # sliding rows: G_h^T s lambda_n with the G_a^T
            P = sparse.csr_matrix(
                (s, (np.arange(rows_h.size), np.searchsorted(on, normals))),
                shape=(rows_h.size, on.size),
            )
            M = _plus_upper_right(M, n, (P.T @ G[rows_h]).T)
        x = solver.solve(M, np.concatenate([force, c[on]]), what)
        z = x[:n]
        lam[on] = -x[n:]  # K z + G_a^T mu = b: lambda = -mu
        lam[rows_h] = s * lam[normals]
        slack = np.asarray(G[bounded] @ z).ravel() - c[bounded]
        if C is not None:
            slack = slack + C[bounded] * lam[bounded]
        return lam, slack, z

    return _saddle_trials(
        lambda warm: _active_set(lo, hi, tol, trial, what, friction, warm=warm),
        lambda: None,
        solver,
        K,
        b,
        G,
        c,
        lo,
        hi,
        C,
        bounded,
        friction,
        what,
        memory,
        rows,
    )


def _saddle_trials(
    find, forget, solver, K, b, G, c, lo, hi, C, bounded, friction, what, memory, rows
):
    """:func:`solve_saddle`'s active set by ``find(warm)`` (:func:`_active_set` on its
    trials), from the last solve's set, else from the Schur complement's (``forget()``:
    the trials' factorization in ``solver`` is gone), else from the compliant rows that
    touch."""
    tol = 1e-10 * max(1.0, np.abs(c).max())

    def solved(lam, active, at_high, z):
        if memory is not None:
            memory.keep(rows, active, at_high, lam)
        return z, lam, active

    warm = memory.start(rows) if memory is not None and bounded.size else None
    if warm is not None:
        try:
            return solved(*find(warm))
        except StepFailed:  # the last solve's set may start inside a cycle
            pass
    start = (
        _schur_start(solver, K, b, G, c, lo, hi, tol, what, friction, C) if bounded.size else None
    )
    forget()
    if start is not None:
        try:
            return solved(*find(start))
        except StepFailed:  # a nearly singular K's start: the trials from none
            pass
    if C is not None:
        # compliant rows touching or crossed (c >= 0) start active: their springs hold a
        # body that only they support (K singular without them)
        touch = (C > 0) & (c >= 0)
        start = (touch, np.zeros(len(c), dtype=bool), C > 0, np.zeros(len(c)))
        return solved(*find(start))
    return solved(*find(None))


def _minus_diagonal(M, n: int, d: np.ndarray):
    """M with -d added on the diagonal of its rows and columns from n on (dense or
    sparse)."""
    if sparse.issparse(M):
        return (M - sparse.diags(np.concatenate([np.zeros(n), d]))).tocsr()
    M = np.array(M, dtype=float)
    M[n:, n:] -= np.diag(d)
    return M


def _plus_upper_right(M, n: int, Q):
    """M with Q (n x columns of M from n on; dense or sparse) added to its upper right
    block."""
    if sparse.issparse(M):
        Q = sparse.coo_matrix(Q)
        return (M + sparse.csr_matrix((Q.data, (Q.row, Q.col + n)), shape=M.shape)).tocsr()
    M = np.array(M, dtype=float)
    M[:n, n:] += Q.toarray() if sparse.issparse(Q) else Q
    return M


def _schur_start(solver, K, b, G, c, lo, hi, tol, what, friction, C=None):
    """The starting active set of :func:`solve_saddle` (``warm`` of :func:`_active_set`)
    from the Schur complement of K (:class:`_Schur`: one factorization, small dense
    trials), or None when K is singular or the active set there does not settle."""
    try:
        schur = _Schur(solver, K, b, G, G, c, lo, hi, what, C)
        lam, active, at_high, _ = _active_set(
            lo, hi, tol, schur.trial, what, friction, proximal=schur.proximal
        )
    except (StepFailed, np.linalg.LinAlgError):
        return None
    return active, at_high, np.ones(lo.size, dtype=bool), lam


def impulses_by_constraint(rows: list, lam: np.ndarray) -> dict:
    """constraint -> [(RowBlock, impulses)]: lambda of :func:`solve_constrained` split by
    the :class:`StepRows` it was solved with, under each block's owner."""
    out: dict = {}
    start = 0
    for g in rows:
        out.setdefault(g.block.owner, []).append((g.block, lam[start : start + len(g.c)]))
        start += len(g.c)
    return out
