"""Hard incompressibility of a reduced body: the full body's volume constraint in a reduced
pressure space.

The full body (:mod:`artifem.incompressibility`) keeps g_i(u) = int q_i (J - 1) dX = 0
for every pressure dof i with multipliers p. A reduced body u = u_bar + U q keeps s
combinations of these rows, those of a reduced pressure space p = Pi lambda (Pi: n_p x s,
e.g. the constant pressure and the POD of training pressures, :func:`pressure_basis`):

    c(q) = Pi^T g(u_bar + U q)  ~=  sum_p w_p V_p pi_p (J_p - 1),     pi_p = Pi^T q(X_p),

evaluated at the body's own m integration points with cubature weights w_p (the energy's,
or weights fitted to the constraint's Jacobian on training states,
:func:`artifem.reduction.training.pressure_weights`; with every point at weight 1 and
Pi = I it is exactly the full g), with the full body's augmented energy in these
coordinates,

    W~(q; lambda) = -lambda^T c + kappa / 2 c^T N^-1 c,      N = Pi^T diag(V) Pi,

(V_i = int q_i dX; N = diag(V) for Pi = I), whose force is C^T pi~ with C = dc/dq and
pi~ = lambda - kappa N^-1 c, and whose tangent is kappa C^T N^-1 C - sum_k pi~_k d^2 c_k
(lambda in place of pi~ in a linearized step, as in the full body). The force and the
geometric term are per point (a pressure -pi~_p dJ_p / dF and its derivative added to the
material's stress and tangent at the point, so that the body's one D^T (.) D pass takes
them), the rank-s term apart: O(m r (r + s)) per evaluation, never O(n).

The multipliers are exact: a step's linear system A x = b with the linearized constraint
c + h C (base + x) = 0 is solved through the s x s Schur complement S = h^2 C A^-1 C^T
(dense, by least squares: dependent rows, e.g. the full nodal pressures of tetrahedra next
to fixed nodes, get the minimum-norm multipliers; a combination of modes the basis cannot
move gets none, and the step fails naming the modes if it is then violated). The constraint
holds when max_k |c_k| / n_k <= tol, with n_k = sum_i |Pi_ik| V_i (for Pi = I the full body's
max_i |g_i| / V_i).

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


def pressure_basis(
    pressures: np.ndarray, volumes: np.ndarray, modes: int, *, total_volume: bool = True
) -> np.ndarray:
    """The reduced pressure space of training pressures, Pi (n_p x modes), its columns
    orthonormal in the pressure mass N = diag(V):

    - with ``total_volume`` (the default), the first column is the constant pressure, whose
      constraint is the body's total volume (what a muscular hydrostat keeps, and what the
      other modes, fitted to snapshots, hold only approximately); the others are the POD
      of the snapshots' remainder, N-orthogonal to it;
    - without it, the first ``modes`` POD modes: the left singular vectors of the
      volume-weighted snapshots diag(V)^1/2 [p_1 ... p_S], mapped back by diag(V)^-1/2.

    ``pressures``: one snapshot per row (S, n_p), the convention of artifem.reduction.
    """
    P = np.asarray(pressures, dtype=float)
    V = np.asarray(volumes, dtype=float)
    if P.ndim != 2 or P.shape[1] != V.size:
        raise InputError(
            f"pressure_basis: pressures must be rows (n_snapshots, {V.size} "
            f"pressure dofs), got shape {P.shape}"
        )
    fitted = modes - 1 if total_volume else modes
    if not 0 <= fitted <= min(P.shape) or modes < 1:
        raise InputError(
            f"pressure_basis: modes must be in [1, {min(P.shape) + total_volume}] "
            f"for {P.shape[0]} snapshots, got {modes}"
        )
    constant = np.ones(V.size) / np.sqrt(V.sum())
    if total_volume:  # the snapshots without their constant part
        P = P - np.outer(P @ (V * constant), constant)
    W, sigma, _ = np.linalg.svd(np.sqrt(V)[:, None] * P.T, full_matrices=False)
    if fitted and not sigma[fitted - 1] > 1e-12 * max(sigma[0], np.finfo(float).tiny):
        raise InputError(
            f"pressure_basis: the snapshots span only "
            f"{int(np.sum(sigma > 1e-12 * sigma[0]))} pressure modes"
            f"{' besides the constant' if total_volume else ''}, {fitted} asked"
        )
    Pi = W[:, :fitted] / np.sqrt(V)[:, None]
    return np.column_stack([constant, Pi]) if total_volume else Pi


class ReducedVolumeConstraint:
    """The module docstring's constraint on one reduced body (``body.volume_constraint``).

    ``body`` (a ReducedFemBody) gives ``full`` (whose ``volume_constraint`` sets kappa, the
    tolerance and the pressure space), its points (``table``, ``point_index``, ``cells``,
    ``weights``) and their strain-displacement matrices ``D``.
    """

    def __init__(self, body, basis: np.ndarray, weights: np.ndarray | None = None):
        full = body.full.volume_constraint
        self.body, self.spec, self.kappa = body, full.spec, full.kappa
        Pi = np.asarray(basis, dtype=float)
        if (
            Pi.ndim != 2
            or Pi.shape[0] != full.n_owned
            or Pi.shape[1] < 1
            or not np.all(np.isfinite(Pi))
        ):
            raise InputError(
                f"ReducedFemBody {body.name!r}: pressure_basis must be finite, "
                f"of shape ({full.n_owned} pressure dofs of {body.full.name!r}, s "
                f">= 1), got {Pi.shape}"
            )
        if Pi.shape[1] >= body.r:
            raise InputError(
                f"ReducedFemBody {body.name!r}: {Pi.shape[1]} pressure modes for "
                f"{body.r} displacement modes would lock the body; take fewer "
                "pressure modes than displacement modes"
            )
        self.basis, self.s = Pi, Pi.shape[1]
        # The points of the constraint's rule (the material's degree) and pi_p there.
        self.at = np.flatnonzero(body.table.degree[body.point_index] == body.full.quadrature_degree)
        if self.at.size == 0:
            raise InputError(
                f"ReducedFemBody {body.name!r}: none of its integration points "
                "is a point of the material's rule, where the volume is measured"
            )
        dofs = full.Q.dofmap.list[body.cells[self.at]]  # (ma, kq)
        shape = (
            np.ones(dofs.shape) if dofs.shape[1] == 1 else body.table.N[body.point_index[self.at]]
        )
        #: pi_p V_p: the pressure modes at the points times the quadrature volumes
        self.point_values = (
            np.einsum("pa,pas->ps", shape, Pi[dofs])
            * body.table.volume[body.point_index[self.at], None]
        )
        if weights is None:
            weights = body.points.weights
        weights = np.asarray(weights, dtype=float)
        if weights.shape != (body.m,) or not np.all(np.isfinite(weights)) or weights.min() < 0:
            raise InputError(
                f"ReducedFemBody {body.name!r}: pressure_weights must be {body.m} "
                f"finite weights >= 0 (one per integration point)"
            )
        self.point_basis = self.point_values * weights[self.at, None]  # w_p V_p pi_p
        self.N = Pi.T @ (full.volume[:, None] * Pi)
        self.N_inv = np.linalg.inv(0.5 * (self.N + self.N.T))
        self.scale = np.abs(Pi).T @ full.volume  # n_k
        #: 1 / diag(N^-1): with kappa, the preconditioner kappa / volume of the island's
        #: pressure iteration (:func:`~artifem.incompressibility.hold_linearized`)
        self.volume = 1.0 / np.diag(self.N_inv)
        self.lam = np.zeros(self.s)  # multipliers
        self.updates = 0
        self._cache: dict = {}

    # ---- evaluation at the body's q ----------------------------------------

    def _kinematics(self):
        """(F, J, dJ/dF) at the constraint's points, cached until q changes."""
        key = self.body.q.tobytes()
        if self._cache.get("key") != key:
            F = (np.eye(3) + self.body._H[self.at]).reshape(-1, 9)
            f = [F[:, k] for k in range(9)]
            # cofactor rows: F_1 x F_2, F_2 x F_0, F_0 x F_1 (rows of F), elementwise
            cof = np.stack(
                [
                    f[4] * f[8] - f[5] * f[7],
                    f[5] * f[6] - f[3] * f[8],
                    f[3] * f[7] - f[4] * f[6],
                    f[7] * f[2] - f[8] * f[1],
                    f[8] * f[0] - f[6] * f[2],
                    f[6] * f[1] - f[7] * f[0],
                    f[1] * f[5] - f[2] * f[4],
                    f[2] * f[3] - f[0] * f[5],
                    f[0] * f[4] - f[1] * f[3],
                ],
                axis=1,
            )  # dJ/dF_iJ
            J = f[0] * cof[:, 0] + f[1] * cof[:, 1] + f[2] * cof[:, 2]
            self._cache = {"key": key, "F": F, "J": J, "dJ": cof}
        return self._cache

    def point_jacobians(self) -> np.ndarray:
        """Each point's V_p pi_p dJ_p^T D_p (ma, s, r) at weight 1: C = sum_p w_p (row p); the
        training matrix of the constraint's own cubature weights (training.pressure_weights)."""
        k = self._kinematics()
        dJdq = np.einsum("pi,pir->pr", k["dJ"], self.body.D[self.at])
        return self.point_values[:, :, None] * dJdq[:, None, :]

    def values(self) -> np.ndarray:
        """c(q) (s,)."""
        return self.point_basis.T @ (self._kinematics()["J"] - 1.0)

    def jacobian(self) -> np.ndarray:
        """C = dc/dq (s, r): one product, sum_p (pi_p dJ_p^T) D_p."""
        k = self._kinematics()
        if "C" not in k:
            D = self.body.D[self.at]
            weighted = self.point_basis[:, :, None] * k["dJ"][:, None, :]  # (ma, s, 9)
            k["C"] = weighted.transpose(1, 0, 2).reshape(self.s, -1) @ D.reshape(-1, D.shape[2])
        return k["C"]

    def augmented(self) -> np.ndarray:
        """pi~ = lambda - kappa N^-1 c."""
        return self.lam - self.kappa * (self.N_inv @ self.values())

    def at_current_state(self, rows: bool = False) -> None:
        """Nothing to do: c and C are evaluated at the current q when asked."""

    def violation(self, c: np.ndarray | None = None) -> float:
        """max_k |c_k| / n_k (of c(q), or of ``c``)."""
        c = self.values() if c is None else c
        return float(np.abs(c / self.scale).max())

    def add_point_stress(self, weighted_stress: np.ndarray) -> None:
        """Add -pi~_p dJ_p to the body's weighted point stresses w_p V_p P_p (m, 9): the
        constraint's residual -C^T pi~ is then part of the body's D^T (w P), pi~_p =
        pi_p . pi~ (w_p V_p in pi_p)."""
        k = self._kinematics()
        weighted_stress[self.at] -= (self.point_basis @ self.augmented())[:, None] * k["dJ"]

    def add_point_tangent(self, weighted_blocks: np.ndarray, linearized: bool = False) -> None:
        """Add -pi_p d^2 J_p / dF^2 to the body's weighted point tangents w_p V_p A_p
        (m, 9, 9): the geometric term -sum_k pi_k d^2 c_k, pi = lambda (``linearized``)
        or pi~. The rank-s term :meth:`augmentation` is added to K~ apart."""
        pi = self.point_basis @ (self.lam if linearized else self.augmented())
        d2J = (self._kinematics()["F"] @ _D2J.T).reshape(-1, 9, 9)
        weighted_blocks[self.at] -= pi[:, None, None] * d2J

    def augmentation(self) -> np.ndarray:
        """kappa C^T N^-1 C (r, r)."""
        C = self.jacobian()
        return self.kappa * (C.T @ (self.N_inv @ C))

    def energy(self) -> float:
        """W~(q; lambda)."""
        c = self.values()
        return float(-self.lam @ c + 0.5 * self.kappa * c @ self.N_inv @ c)

    # ---- the multipliers ---------------------------------------------------

    def hold_linearized(
        self,
        A: np.ndarray,
        x: np.ndarray,
        h: float,
        base: np.ndarray | None = None,
        exact: bool = True,
    ) -> np.ndarray:
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
            raise StepFailed(
                f"ReducedFemBody {self.body.name!r}: singular step matrix ({exc})"
            ) from exc
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

    def step_failure(self) -> str | None:
        """After a step: None while max_k |c_k| / n_k <= ``step_tol``, else where it is not
        (the full body's :meth:`~artifem.incompressibility.VolumeConstraint.step_failure`)."""
        if self.violation() <= self.spec.step_tol:
            return None
        return self.describe().replace(
            f"more than {self.spec.tol:g}", f"more than the step's {self.spec.step_tol:g}"
        )

    def describe(self, c: np.ndarray | None = None) -> str:
        """Which pressure modes miss the tolerance, by how much."""
        c = self.values() if c is None else c
        ratio = np.abs(c / self.scale)
        worst = np.argsort(-ratio)[:3]
        shown = ", ".join(f"{k} ({ratio[k]:.1e})" for k in worst)
        return (
            f"ReducedFemBody {self.body.name!r}: volumes off by more than "
            f"{self.spec.tol:g} in pressure mode(s) (index, relative volume change) {shown}"
        )

    def pressures(self) -> np.ndarray:
        """The pressure field p = Pi lambda on the full body's pressure dofs (O(n s))."""
        return self.basis @ self.lam
