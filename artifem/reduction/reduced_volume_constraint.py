"""Hard incompressibility of a reduced body: the full body's volume constraint in a reduced
pressure space.

The full body (:mod:`artifem.incompressibility`) keeps g_i(u) = int q_i (J - 1) dX = 0
for every pressure dof i with multipliers p. A reduced body u = u_bar + U q keeps s
combinations of these rows, those of a reduced pressure space p = Pi lambda (Pi: n_p x s,
e.g. the POD of training pressures, :func:`pressure_basis`):

    c(q) = Pi^T g(u_bar + U q)  ~=  sum_p w_p V_p pi_p (J_p - 1),     pi_p = Pi^T q(X_p),

evaluated at the body's own m integration points with their cubature weights (with every
point at weight 1 and Pi = I it is exactly the full g), with the full body's augmented
energy in these coordinates,

    W~(q; lambda) = -lambda^T c + kappa / 2 c^T N^-1 c,      N = Pi^T diag(V) Pi,

(V_i = int q_i dX; N = diag(V) for Pi = I), whose force is C^T pi~ with C = dc/dq and
pi~ = lambda - kappa N^-1 c, and whose tangent is kappa C^T N^-1 C - sum_k pi~_k d^2 c_k
(lambda in place of pi~ in a linearized step, as in the full body). O(m r (r + s)) per
evaluation, never O(n).

The multipliers are exact: a step's linear system A x = b with the linearized constraint
c + h C (base + x) = 0 is solved through the s x s Schur complement S = h^2 C A^-1 C^T
(dense, by least squares: dependent rows, e.g. the full nodal pressures of tetrahedra next
to fixed nodes, get the minimum-norm multipliers; a combination of modes the basis cannot
move gets none, and the step fails naming the modes if it is then violated). The constraint holds when max_k |c_k| / n_k <= tol, with
n_k = sum_i |Pi_ik| V_i (for Pi = I the full body's max_i |g_i| / V_i).

J, its cofactor and its second derivative are written out here (det F and
d^2 det F / dF dF = eps_ikm eps_JLN F_mN are identities of the kinematics, not a
material law that UFL should derive).
"""

from __future__ import annotations

import numpy as np

from artifem.errors import InputError, StepFailed

__all__ = ["ReducedVolumeConstraint", "pressure_basis"]

_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0
#: d^2 J / dF_iJ dF_kL = eps_ikm eps_JLn F_mn, linear in F: (81, 9) acting on vec(F)
_D2J = np.einsum("ikm,JLn->iJkLmn", _EPS, _EPS).reshape(81, 9)


def pressure_basis(pressures: np.ndarray, volumes: np.ndarray, modes: int) -> np.ndarray:
    """The reduced pressure space of training pressures: the first ``modes`` left singular
    vectors of the volume-weighted snapshots diag(V)^1/2 [p_1 ... p_S] mapped back,
    Pi = diag(V)^-1/2 W (columns orthonormal in the pressure mass N = diag(V)).

    ``pressures``: one snapshot per row (S, n_p), the convention of artifem.reduction.
    """
    P = np.asarray(pressures, dtype=float)
    V = np.asarray(volumes, dtype=float)
    if P.ndim != 2 or P.shape[1] != V.size:
        raise InputError(f"pressure_basis: pressures must be rows (n_snapshots, {V.size} "
                         f"pressure dofs), got shape {P.shape}")
    if not 1 <= modes <= min(P.shape):
        raise InputError(f"pressure_basis: modes must be in [1, {min(P.shape)}] for "
                         f"{P.shape[0]} snapshots, got {modes}")
    W, sigma, _ = np.linalg.svd(np.sqrt(V)[:, None] * P.T, full_matrices=False)
    if not sigma[modes - 1] > 1e-12 * sigma[0]:
        raise InputError(f"pressure_basis: the snapshots span only "
                         f"{int(np.sum(sigma > 1e-12 * sigma[0]))} pressure modes, "
                         f"{modes} asked")
    return W[:, :modes] / np.sqrt(V)[:, None]


class ReducedVolumeConstraint:
    """The module docstring's constraint on one reduced body (``body.volume_constraint``).

    ``body`` (a ReducedFemBody) gives ``full`` (whose ``volume_constraint`` sets kappa, the
    tolerance and the pressure space), its points (``table``, ``point_index``, ``cells``,
    ``weights``) and their strain-displacement matrices ``D``.
    """

    def __init__(self, body, basis: np.ndarray):
        full = body.full.volume_constraint
        self.body, self.spec, self.kappa = body, full.spec, full.kappa
        Pi = np.asarray(basis, dtype=float)
        if Pi.ndim != 2 or Pi.shape[0] != full.n_owned or Pi.shape[1] < 1 \
                or not np.all(np.isfinite(Pi)):
            raise InputError(f"ReducedFemBody {body.name!r}: pressure_basis must be finite, "
                             f"of shape ({full.n_owned} pressure dofs of {body.full.name!r}, s "
                             f">= 1), got {Pi.shape}")
        if Pi.shape[1] >= body.r:
            raise InputError(f"ReducedFemBody {body.name!r}: {Pi.shape[1]} pressure modes for "
                             f"{body.r} displacement modes would lock the body; take fewer "
                             "pressure modes than displacement modes")
        self.basis, self.s = Pi, Pi.shape[1]
        # The points of the constraint's rule (the material's degree) and pi_p there.
        self.at = np.flatnonzero(body.table.degree[body.point_index]
                                 == body.full.quadrature_degree)
        if self.at.size == 0:
            raise InputError(f"ReducedFemBody {body.name!r}: none of its integration points "
                             "is a point of the material's rule, where the volume is measured")
        dofs = full.Q.dofmap.list[body.cells[self.at]]                 # (ma, kq)
        shape = np.ones(dofs.shape) if dofs.shape[1] == 1 else \
            body.table.N[body.point_index[self.at]]
        self.point_basis = np.einsum("pa,pas->ps", shape, Pi[dofs]) \
            * body.weights[self.at, None]                               # w_p V_p pi_p
        self.N = Pi.T @ (full.volume[:, None] * Pi)
        self.N_inv = np.linalg.inv(0.5 * (self.N + self.N.T))
        self.scale = np.abs(Pi).T @ full.volume                         # n_k
        #: 1 / diag(N^-1): with kappa, the preconditioner kappa / volume of the island's
        #: pressure iteration (:func:`~artifem.incompressibility.hold_linearized`)
        self.volume = 1.0 / np.diag(self.N_inv)
        self.lam = np.zeros(self.s)                                     # multipliers
        self.updates = 0
        self._cache: dict = {}

    # ---- evaluation at the body's q ----------------------------------------

    def _kinematics(self):
        """(F, J, dJ/dF) at the constraint's points, cached until q changes."""
        key = self.body.q.tobytes()
        if self._cache.get("key") != key:
            F = np.eye(3) + self.body._H[self.at]
            cof = np.stack([np.cross(F[:, 1], F[:, 2]), np.cross(F[:, 2], F[:, 0]),
                            np.cross(F[:, 0], F[:, 1])], axis=1)      # dJ/dF_iJ
            J = np.einsum("pj,pj->p", F[:, 0], cof[:, 0])
            self._cache = {"key": key, "F": F, "J": J, "dJ": cof.reshape(-1, 9)}
        return self._cache

    def values(self) -> np.ndarray:
        """c(q) (s,)."""
        return self.point_basis.T @ (self._kinematics()["J"] - 1.0)

    def jacobian(self) -> np.ndarray:
        """C = dc/dq (s, r)."""
        k = self._kinematics()
        if "C" not in k:
            dJdq = np.einsum("pi,pir->pr", k["dJ"], self.body.D[self.at])
            k["C"] = self.point_basis.T @ dJdq
        return k["C"]

    def augmented(self) -> np.ndarray:
        """pi~ = lambda - kappa N^-1 c."""
        return self.lam - self.kappa * (self.N_inv @ self.values())

    def violation(self, c: np.ndarray | None = None) -> float:
        """max_k |c_k| / n_k (of c(q), or of ``c``)."""
        c = self.values() if c is None else c
        return float(np.abs(c / self.scale).max())

    def force(self) -> np.ndarray:
        """C^T pi~ (added to the body's force)."""
        return self.jacobian().T @ self.augmented()

    def tangent(self, linearized: bool = False) -> np.ndarray:
        """kappa C^T N^-1 C - sum_k pi_k d^2 c_k, pi = lambda (``linearized``) or pi~."""
        C = self.jacobian()
        pi = self.lam if linearized else self.augmented()
        weight = self.point_basis @ pi                                  # sum_k pi_k w_p pi_pk
        F, D = self._kinematics()["F"], self.body.D[self.at]
        d2J = (F.reshape(-1, 9) @ _D2J.T).reshape(-1, 9, 9) * weight[:, None, None]
        r = D.shape[2]
        geometric = D.reshape(-1, r).T @ np.matmul(d2J, D).reshape(-1, r)
        return self.kappa * (C.T @ self.N_inv @ C) - geometric

    def energy(self) -> float:
        """W~(q; lambda)."""
        c = self.values()
        return float(-self.lam @ c + 0.5 * self.kappa * c @ self.N_inv @ c)

    # ---- the multipliers ---------------------------------------------------

    def hold_linearized(self, A: np.ndarray, x: np.ndarray, h: float,
                        base: np.ndarray | None = None, exact: bool = True) -> np.ndarray:
        """x corrected, and lambda updated, so that c + h C (base + x) = 0 for a linear
        system A x = b (the force change h C^T dlambda: x += A^-1 h C^T dlambda, the s x s
        Schur complement solved by least squares). Raises StepFailed when the result still
        misses the tolerance (``exact``; a Newton iteration passes False and leaves it to
        the pressure updates around Newton)."""
        C = self.jacobian()
        c0 = self.values() + h * (C @ (x if base is None else base + x))
        try:
            Y = np.linalg.solve(A, h * C.T)
        except np.linalg.LinAlgError as exc:
            raise StepFailed(f"ReducedFemBody {self.body.name!r}: singular step matrix "
                             f"({exc})") from exc
        S = h * (C @ Y)
        dlam = np.linalg.lstsq(S, -c0, rcond=1e-12)[0]
        x = x + Y @ dlam
        self.lam = self.lam + dlam
        self.updates = 1
        if exact:
            left = c0 + S @ dlam
            if not self.violation(left) <= self.spec.tol:
                raise StepFailed(self.describe(left) + " (the basis cannot hold it)")
        return x

    # ---- in the coupled island (artifem.scene.layout.Layout.hold_volumes) -------------

    def linearized_rows(self, v: np.ndarray, h: float) -> np.ndarray:
        """c + h C v: the constraint at the end of a step with velocity v."""
        return self.values() + h * (self.jacobian() @ v)

    def force_rows(self, dlam: np.ndarray, h: float) -> np.ndarray:
        """h C^T dlambda: the change of h f when the multipliers change by dlambda."""
        return h * (self.jacobian().T @ dlam)

    def rate_rows(self, y: np.ndarray, h: float) -> np.ndarray:
        """h C y: the change of c when the velocity changes by y."""
        return h * (self.jacobian() @ y)

    def add_to_pressures(self, dlam: np.ndarray) -> None:
        self.lam = self.lam + dlam

    def update(self) -> float:
        """Uzawa on the nonlinear constraint: the violation at q, then lambda <- pi~."""
        violation = self.violation()
        self.lam = self.augmented()
        return violation

    def describe(self, c: np.ndarray | None = None) -> str:
        """Which pressure modes miss the tolerance, by how much."""
        c = self.values() if c is None else c
        ratio = np.abs(c / self.scale)
        worst = np.argsort(-ratio)[:3]
        shown = ", ".join(f"{k} ({ratio[k]:.1e})" for k in worst)
        return (f"ReducedFemBody {self.body.name!r}: volumes off by more than "
                f"{self.spec.tol:g} in pressure mode(s) (index, relative volume change) {shown}")

    def pressures(self) -> np.ndarray:
        """The pressure field p = Pi lambda on the full body's pressure dofs (O(n s))."""
        return self.basis @ self.lam
