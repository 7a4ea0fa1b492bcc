"""Points attached to deformable bodies (Lloyd et al. 2019, section 3.1).

An attached point follows its masters, x_a = f(x_m). For FEM masters f is
linear in the nodal positions,

    x_a = sum_j w_j x_j,   x_j = X_j + u_j,   G = d x_a / d u = [w_1 I, ..., w_k I],

with weights that sum to one and reproduce the point at rest,
sum_j w_j X_j = X_a. Two ways to choose them:

- :func:`shape_function_weights`: the shape functions of the element that
  contains the point (located with DOLFINx's bounding-box tree, pulled back to
  reference coordinates, tabulated with basix): 8 nodes on a hexahedron;
- :func:`support_weights`: any k >= 4 support nodes (the paper's Fig. 9: 4
  versus 24), with the minimum-norm weights under the two conditions above,
  w = A^T (A A^T)^-1 [X_a; 1] with A = [X_j; 1] (4 x k), or, with
  ``nonnegative=True``, the minimum-norm weights with w >= 0 as well
  (:func:`nonnegative_weights`, a small QP; they exist iff X_a is in the
  convex hull of the support nodes).

On a reduced body u = u_bar + U q the same weights give
x_a = sum_j w_j (X_j + u_bar_j) + (sum_j w_j U_j) q, so G = sum_j w_j U_j (3 x r).

Forces on the point come back to the masters by virtual work, f_m = G^T f_a,
so that f_a . v_a = f_m . v_m. Serial (local dofs) for now.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from artifem.errors import InputError, SolverError
from artifem.embedding.embedded_mesh import locate_points
from artifem.fem_body import FemBody

__all__ = [
    "FemPointWeights",
    "shape_function_weights",
    "support_weights",
    "nonnegative_weights",
    "nearest_nodes",
    "FemPointAttachment",
    "ReducedPointAttachment",
]


@dataclass(frozen=True)
class FemPointWeights:
    """x_a = sum_j weights[j] x_{dofs[j]} on a FEM body (local block dofs)."""

    dofs: np.ndarray
    weights: np.ndarray
    rest_position: np.ndarray  # X_a as reproduced by the weights
    distance: float = 0.0  # how far the requested point was from the mesh
    cell: int = -1  # the containing element (local), -1 for a node support

    def __post_init__(self):
        if self.dofs.shape != self.weights.shape or self.dofs.ndim != 1 or self.dofs.size == 0:
            raise InputError("an attached point needs one weight per support dof, and at least one")
        if abs(float(self.weights.sum()) - 1.0) > 1e-10:
            raise InputError(f"attachment weights must sum to 1, got {self.weights.sum():.12g}")


def _node_positions(body: FemBody) -> np.ndarray:
    """Rest positions of the body's local block dofs (P1: the mesh nodes)."""
    return body.V.tabulate_dof_coordinates()


def shape_function_weights(
    body: FemBody, point, *, snap: bool = False, tol: float = 1e-10
) -> FemPointWeights:
    """Weights of the element containing ``point`` (its shape functions at the point), from
    :func:`~artifem.embedding.embedded_mesh.locate_points`. Serial.

    A point outside the mesh is an error naming its distance to the mesh, or,
    with ``snap=True``, is moved to the closest point of the nearest element
    (weights in [0, 1]; the distance is kept in the result).
    """
    if body.mesh.comm.size != 1:
        raise NotImplementedError(
            f"point attachments to FEM body {body.name!r} are serial "
            f"for now (use EmbeddedMesh in parallel)"
        )
    X = np.asarray(point, dtype=float).reshape(1, 3)
    loc = locate_points(body, X, snap=True, tol=tol)
    cell, w, distance = int(loc.cells[0]), loc.weights[0], float(loc.distance[0])
    if distance > tol and not snap:
        raise InputError(
            f"point {X[0].tolist()} is outside FEM body {body.name!r} "
            f"(distance {distance:.4g} to element "
            f"{int(body.input_cell_index([cell])[0])}); pass snap=True to "
            f"attach it to the closest point of that element"
        )
    dofs = body.V.dofmap.list[cell].astype(np.int64)
    return FemPointWeights(dofs, w, w @ _node_positions(body)[dofs], distance, cell)


def nearest_nodes(body: FemBody, point, k: int) -> np.ndarray:
    """Input indices of k nodes near ``point``: the nearest 4 that are not coplanar, then the
    nearest others (a support for :func:`support_weights`)."""
    if k < 4:
        raise InputError(f"a support needs at least 4 nodes to reproduce a 3-D point, got {k}")
    X = np.asarray(point, dtype=float).reshape(3)
    x = _node_positions(body)
    order = np.argsort(np.linalg.norm(x - X, axis=1))
    # The nearest nodes that span 3-D (affinely independent), then the nearest others.
    spanning = []
    for d in order:
        trial = spanning + [d]
        if np.linalg.matrix_rank(np.vstack([x[trial].T, np.ones(len(trial))])) == len(trial):
            spanning = trial
        if len(spanning) == 4:
            break
    rest = [d for d in order if d not in spanning][: k - len(spanning)]
    local = np.array(sorted(spanning + rest, key=lambda d: np.linalg.norm(x[d] - X)))
    inverse = {d: n for n, d in body._input_node_to_dof().items()}
    return np.array([inverse[int(d)] for d in local], dtype=np.int64)


def support_weights(body: FemBody, point, nodes, *, nonnegative: bool = False) -> FemPointWeights:
    """Minimum-norm weights on the given support nodes (input indices) that sum to one and
    reproduce ``point`` at rest (see the module docstring).

    ``nonnegative=True``: the minimum-norm weights with w >= 0 as well
    (:func:`nonnegative_weights`); the point must lie in the convex hull of the nodes.
    """
    X = np.asarray(point, dtype=float).reshape(3)
    nodes = np.asarray(nodes, dtype=np.int64).ravel()
    dofs = body.local_dofs(nodes).astype(np.int64)
    if dofs.size != nodes.size:
        missing = [int(n) for n in nodes if n not in body._input_node_to_dof()]
        raise InputError(f"support nodes {missing[:10]} are not nodes of FEM body {body.name!r}")
    Xj = _node_positions(body)[dofs]
    if nonnegative:
        try:
            w = nonnegative_weights(Xj, X)
        except ValueError as e:
            raise InputError(
                f"FEM body {body.name!r}, support nodes "
                f"{[int(n) for n in nodes[:10]]}{'...' if nodes.size > 10 else ''}:"
                f" {e}"
            ) from None
        return FemPointWeights(dofs, w, w @ Xj)
    A = np.vstack([Xj.T, np.ones(len(dofs))])  # (4, k)
    if np.linalg.matrix_rank(A) < 4:
        raise InputError(
            f"support nodes {[int(n) for n in nodes[:10]]} are coplanar: they "
            f"cannot reproduce an arbitrary point"
        )
    w = A.T @ np.linalg.solve(A @ A.T, np.append(X, 1.0))
    return FemPointWeights(dofs, w, w @ Xj)


def nonnegative_weights(nodes, point, *, tol: float = 1e-9) -> np.ndarray:
    """Minimum-norm non-negative weights of ``point`` on ``nodes`` (k, 3): the quadratic program

        min |w|^2 / 2   s.t.   sum_j w_j = 1,   sum_j w_j X_j = X_a,   w >= 0,

    solved in the scaled coordinates Y_j = (X_j - X_a) / h, h = max_j |X_j - X_a|, by scipy's
    SLSQP from a feasible start (HiGHS linear program), then made exact on its support S
    (w_j > 0): w_S = pinv([Y_S; 1]) [0; 1], the minimum-norm solution there (the QP's KKT
    conditions on S). Such weights exist iff X_a is in the convex hull of the X_j; otherwise a
    ValueError gives the distance min_{w >= 0, sum w = 1} |sum_j w_j X_j - X_a| (``tol`` * h
    is the tolerance of "in the hull"). Coplanar nodes are fine if the point is in their hull.
    """
    from scipy.optimize import linprog, minimize

    Xj = np.asarray(nodes, dtype=float).reshape(-1, 3)
    X = np.asarray(point, dtype=float).reshape(3)
    h = float(np.linalg.norm(Xj - X, axis=1).max())
    if h == 0.0:
        return np.full(len(Xj), 1.0 / len(Xj))
    A = np.vstack([((Xj - X) / h).T, np.ones(len(Xj))])  # (4, k)
    b = np.array([0.0, 0.0, 0.0, 1.0])
    k = len(Xj)
    feasible = linprog(np.zeros(k), A_eq=A, b_eq=b, bounds=(0.0, None), method="highs")
    if feasible.status not in (0, 2):
        raise SolverError(
            f"nonnegative_weights: feasibility LP failed for point {X.tolist()} "
            f"on {k} nodes: {feasible.message}"
        )
    if feasible.status == 2:  # infeasible
        # distance of the point to the hull: min |Y^T w| over the simplex
        Y = A[:3]
        near = minimize(
            lambda w: 0.5 * np.sum((Y @ w) ** 2),
            np.full(k, 1.0 / k),
            jac=lambda w: Y.T @ (Y @ w),
            bounds=[(0.0, None)] * k,
            constraints=[
                {"type": "eq", "fun": lambda w: w.sum() - 1.0, "jac": lambda w: np.ones(k)}
            ],
            method="SLSQP",
            options={"ftol": 1e-15},
        )
        distance = h * float(np.linalg.norm(Y @ np.clip(near.x, 0.0, None)))
        raise InputError(
            f"point {X.tolist()} is not in the convex hull of its {k} support "
            f"nodes (distance {distance:.4g}): no non-negative weights reproduce "
            f"it; use more or other nodes, or signed weights"
        )
    # independent rows of A w = b (coplanar nodes make A rank 3; SLSQP needs full rank)
    left, sigma, right = np.linalg.svd(A, full_matrices=False)
    rank = int(np.count_nonzero(sigma > 1e-12 * sigma[0]))
    A_eq, b_eq = sigma[:rank, None] * right[:rank], left[:, :rank].T @ b
    qp = minimize(
        lambda w: 0.5 * w @ w,
        feasible.x,
        jac=lambda w: w,
        bounds=[(0.0, None)] * k,
        method="SLSQP",
        options={"ftol": 1e-15},
        constraints=[{"type": "eq", "fun": lambda w: A_eq @ w - b_eq, "jac": lambda w: A_eq}],
    )
    w = np.zeros(k)
    support = qp.x > tol * max(float(qp.x.max()), 1.0 / k)
    w[support] = np.linalg.pinv(A[:, support]) @ b
    # KKT certificate: w_S = A_S^T lambda and A_j^T lambda <= 0 off the support
    lam = np.linalg.lstsq(A[:, support].T, w[support], rcond=None)[0]
    dual = float((A[:, ~support].T @ lam).max(initial=0.0))
    if w.min() < -tol or np.linalg.norm(A @ w - b) > tol or dual > tol:
        raise SolverError(
            f"nonnegative_weights: no optimal weights found for point "
            f"{X.tolist()} on {k} nodes ({qp.message}; min w {w.min():.3g}, "
            f"residual {np.linalg.norm(A @ w - b):.3g}, dual {dual:.3g})"
        )
    return np.clip(w, 0.0, None) / np.clip(w, 0.0, None).sum()


class FemPointAttachment:
    """A point on a full FEM body: x_a = sum_j w_j (X_j + u_j), G = [w_j I] (3 x 3n)."""

    def __init__(self, body: FemBody, weights: FemPointWeights):
        self.body, self.weights = body, weights
        n = 3 * body.V.dofmap.index_map.size_local
        rows = np.tile(np.arange(3), weights.dofs.size)
        cols = (3 * weights.dofs[:, None] + np.arange(3)).ravel()
        self.G = sparse.csr_matrix((np.repeat(weights.weights, 3), (rows, cols)), shape=(3, n))

    def position(self) -> np.ndarray:
        u = self.body.u.x.array.reshape(-1, 3)[self.weights.dofs]
        return self.weights.rest_position + self.weights.weights @ u

    def velocity(self) -> np.ndarray:
        return self.weights.weights @ self.body.v.x.array.reshape(-1, 3)[self.weights.dofs]

    def master_force(self, f) -> np.ndarray:
        """G^T f: the nodal forces (owned dofs, blocked) equivalent to a force f on the point."""
        return self.G.T @ np.asarray(f, dtype=float).reshape(3)


class ReducedPointAttachment:
    """A point on a reduced body: x_a = x_bar + G q with G = sum_j w_j U_j (3 x r)."""

    def __init__(self, reduced, weights: FemPointWeights):
        self.body, self.weights = reduced, weights
        w, dofs = weights.weights, weights.dofs
        U = reduced.U.reshape(-1, 3, reduced.r)
        self.G = np.einsum("j,jir->ir", w, U[dofs])
        self.x_bar = weights.rest_position + w @ reduced.u_bar.reshape(-1, 3)[dofs]

    def position(self) -> np.ndarray:
        return self.x_bar + self.G @ self.body.q

    def velocity(self) -> np.ndarray:
        return self.G @ self.body.qdot

    def master_force(self, f) -> np.ndarray:
        """G^T f: the reduced generalized force of a force f on the point."""
        return self.G.T @ np.asarray(f, dtype=float).reshape(3)
