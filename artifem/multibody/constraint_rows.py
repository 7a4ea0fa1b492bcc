"""The constraint protocol: rows on the bodies' coordinates, with bounds on their impulses.

A constraint (a joint, its limits, a contact) names the bodies it touches
(``bodies``) and gives, at the current state, its rows as blocks
(``row_blocks() -> list[RowBlock]``), ``constraint_failure() -> str | None``, what is
wrong with the state after a step (a contact point deeper than its tolerance), which
fails the step like an inverted element, and ``hold_pairs(hold: bool)``: statics asks a
contact to keep (True) or find again (False) the features its points are paired with
(a mesh contact's triangles, edges and vertices; nothing to hold for a joint or a
plane). A block of m rows holds

    phi (m,)             the constraint values: phi = 0 wanted on a free row,
                         phi >= 0 on a bounded one;
    G_k (m x n_k)        the rows on the coordinates of each touched body k (a rigid
                         body's twist [v; w], a reduced body's q', FEM nodal
                         velocities; dense or sparse): phi' = sum_k G_k z_k;
    lo <= lambda <= hi   bounds on the rows' impulses lambda (force times h), which act
                         on body k as G_k^T lambda: bilateral rows (-inf, inf), limits
                         and contact normals [0, inf), friction [-mu lambda_n, mu lambda_n];
    friction             optional (:class:`Friction`): rows whose bounds are the block's
                         own normal impulses times mu, |lambda_t| <= mu lambda_n (Coulomb
                         friction on a pyramid); the solve holds a sliding row at
                         +-mu lambda_n of the same solve (lo, hi are ignored there);
    K(lambda)            d(sum_k G_k^T lambda)/dq at fixed lambda: the rows' geometric
                         stiffness (their levers and axes turn with the bodies).

The step asks of each row, with z+ the velocities at the end of the step,

    free row (lo = -inf, hi = inf):   G z+ = c,   c = -beta phi / h
    bounded row:                      G z+ >= c,  c = -phi / h while phi > 0 (reach
                                      phi = 0, never cross it), -beta phi / h once crossed,

with complementarity on the bounded rows (lambda at lo where G z+ > c, at hi where
G z+ < c: a friction row slides against the slip);
Baumgarte's beta (``Scene.stabilization``) removes the drift of the free rows. Statics
asks phi + G dq = 0 (free) or >= 0 (bounded): the same right-hand side at h = beta = 1,
a friction row's phi its slip since the load increment began
(:mod:`~artifem.scene.increment_slip`).

Compliant rows (``compliance`` C (m,) >= 0, m/N; an elastic foundation's contact rows,
:mod:`artifem.multibody.foundation`): a bounded row with C > 0 is a spring that pushes
only in compression, its force f = -phi_end / C >= 0 with phi_end = phi + h G z+ the
value at the end of the step. With lambda = h f, an active compliant row asks

    G z+ + (C / h^2) lambda = c,     c = -phi / h  (at any sign of phi: no Baumgarte,
                                     the penetration is the law's),

and complementarity lambda >= 0, G z+ - c + (C / h^2) lambda >= 0, their product 0: the
multiplier block of the KKT gains + C / h^2 on its diagonal. The scene turns C into
C / h^2 where it maps the rows onto the step (:class:`~artifem.scene.constraints.StepRows`
``compliance``, :meth:`~artifem.scene.constraint_map.ConstraintMap.rows`); statics takes
h = 1 (phi + G dq = -C lambda, lambda the force). C = 0 (the default) is a hard row.
Friction rows stay hard; their bounds take the compliant normal impulses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from artifem.errors import InputError

__all__ = ["Friction", "RowBlock"]


@dataclass(frozen=True, eq=False)
class Friction:
    """Coulomb friction on some rows of a block: row j with ``normal[j] >= 0`` obeys

        -mu_j lambda_n <= lambda_j <= mu_j lambda_n,   lambda_n = max(lambda_{normal[j]}, 0),

    (box rows along tangents: a friction pyramid); rows with ``normal[j] = -1`` are not
    friction rows."""

    normal: np.ndarray
    mu: np.ndarray

    @classmethod
    def tangents(cls, k: int, mu: float, per_point: int = 2) -> Friction:
        """Rows [k normals; per_point blocks of k tangent rows], tangent row j of point
        j mod k, all with friction coefficient mu."""
        normal = np.concatenate([np.full(k, -1), np.tile(np.arange(k), per_point)])
        return cls(normal, np.where(normal >= 0, float(mu), 0.0))

    @property
    def rows(self) -> np.ndarray:
        """(m,) bool: the friction rows."""
        return self.normal >= 0


@dataclass(frozen=True, eq=False)
class RowBlock:
    """m rows of one constraint at the current state (module docstring).

    Args:
        owner: the constraint that gave the rows (its impulses are recorded under it).
        phi: (m,) constraint values.
        jacobians: ((body, G_body), ...): the rows on each touched body's coordinates,
            in the order of ``owner.bodies``; a body None is the world (no coordinates;
            its G_body is the reaction on the world).
        lo, hi: (m,) bounds on the impulses.
        stiffness: lambda -> d(sum_k G_k^T lambda)/dq, square over the concatenated
            columns of ``jacobians`` (the world's included, zero; dense or sparse).
        friction: None, or a :class:`Friction` on some of the rows (module docstring).
        keys: None, or (m, d) integers naming each row stably from step to step (a
            contact's point and direction): the next step's active set starts from the
            last one's rows of the same keys (a warm start,
            :class:`~artifem.scene.constraints.ActiveSetMemory`).
        compliance: None (hard rows), or (m,) C >= 0 (m/N) on bounded rows (module
            docstring); zero on free rows.
    """

    owner: object
    phi: np.ndarray
    jacobians: tuple
    lo: np.ndarray
    hi: np.ndarray
    stiffness: Callable[[np.ndarray], np.ndarray]
    friction: Friction | None = None
    keys: np.ndarray | None = None
    compliance: np.ndarray | None = None

    def __post_init__(self):
        m = self.phi.shape[0]
        what = f"constraint {getattr(self.owner, 'name', self.owner)!r}"
        _check_bounds(self.lo, self.hi, m, what)
        for _, G in self.jacobians:
            if G.shape[0] != m:
                raise InputError(f"{what}: a Jacobian with {G.shape[0]} rows for {m} values")
        if self.keys is not None and len(self.keys) != m:
            raise InputError(f"{what}: {len(self.keys)} row keys for {m} rows")
        if self.friction is not None and (
            self.friction.normal.shape != (m,)
            or self.friction.mu.shape != (m,)
            or np.any(self.friction.normal >= m)
            or np.any(self.friction.rows[np.maximum(self.friction.normal, 0)] & self.friction.rows)
        ):
            raise InputError(
                f"{what}: friction needs {m} normal indices and coefficients, "
                "each friction row's normal a row of the block that is not one"
            )
        if self.compliance is not None:
            C = np.asarray(self.compliance, dtype=float)
            if C.shape != (m,) or not np.all(np.isfinite(C)) or np.any(C < 0):
                raise InputError(f"{what}: the compliance must be {m} finite values >= 0")
            if np.any(C[~self.bounded] > 0):
                raise InputError(f"{what}: a compliance on a free (bilateral) row")

    @classmethod
    def bilateral(cls, owner, phi, jacobians, stiffness) -> RowBlock:
        """Equality rows phi = 0, lambda free."""
        m = len(phi)
        return cls(
            owner,
            np.asarray(phi, dtype=float),
            tuple(jacobians),
            np.full(m, -np.inf),
            np.full(m, np.inf),
            stiffness,
        )

    @classmethod
    def unilateral(cls, owner, phi, jacobians, stiffness) -> RowBlock:
        """Inequality rows phi >= 0, lambda >= 0 (limits, contact normals)."""
        m = len(phi)
        return cls(
            owner,
            np.asarray(phi, dtype=float),
            tuple(jacobians),
            np.zeros(m),
            np.full(m, np.inf),
            stiffness,
        )

    def __len__(self) -> int:
        return self.phi.shape[0]

    @property
    def bounded(self) -> np.ndarray:
        """(m,) bool: rows with a finite bound on lambda (inequalities phi >= 0)."""
        return np.isfinite(self.lo) | np.isfinite(self.hi)

    @property
    def compliant(self) -> np.ndarray:
        """(m,) bool: rows with a compliance C > 0 (module docstring)."""
        if self.compliance is None:
            return np.zeros(len(self), dtype=bool)
        return np.asarray(self.compliance) > 0

    def rhs(self, h: float, beta: float) -> np.ndarray:
        """c of the rows G z+ (= or >=) c (module docstring): -phi / h on compliant rows
        at any sign of phi."""
        gain = np.where(self.bounded & ((self.phi > 0) | self.compliant), 1.0, beta)
        return -gain * self.phi / h

    def gap(self) -> np.ndarray:
        """The part of phi the rows forbid: phi on free rows, min(phi, 0) on bounded ones,
        0 on compliant ones (their penetration is the law's)."""
        return np.where(
            self.bounded, np.where(self.compliant, 0.0, np.minimum(self.phi, 0.0)), self.phi
        )


def _check_bounds(lo: np.ndarray, hi: np.ndarray, m: int, what: str) -> None:
    if lo.shape != (m,) or hi.shape != (m,):
        raise InputError(f"{what}: {m} rows need {m} lower and upper bounds")
    if np.any(lo > hi) or np.any(lo == np.inf) or np.any(hi == -np.inf):
        raise InputError(f"{what}: bounds need lo <= hi, lo < inf and hi > -inf")
