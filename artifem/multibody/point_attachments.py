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
  w = A^T (A A^T)^-1 [X_a; 1] with A = [X_j; 1] (4 x k).

On a reduced body u = u_bar + U q the same weights give
x_a = sum_j w_j (X_j + u_bar_j) + (sum_j w_j U_j) q, so G = sum_j w_j U_j (3 x r).

Forces on the point come back to the masters by virtual work, f_m = G^T f_a,
so that f_a . v_a = f_m . v_m. Serial (local dofs) for now.
"""

from __future__ import annotations

from dataclasses import dataclass

import basix
import numpy as np
from dolfinx import geometry
from scipy import sparse

from artifem.fem_body import FemBody

__all__ = ["FemPointWeights", "shape_function_weights", "support_weights", "nearest_nodes",
           "FemPointAttachment", "ReducedPointAttachment"]


@dataclass(frozen=True)
class FemPointWeights:
    """x_a = sum_j weights[j] x_{dofs[j]} on a FEM body (local block dofs)."""

    dofs: np.ndarray
    weights: np.ndarray
    rest_position: np.ndarray        # X_a as reproduced by the weights
    distance: float = 0.0            # how far the requested point was from the mesh
    cell: int = -1                   # the containing element (local), -1 for a node support

    def __post_init__(self):
        if self.dofs.shape != self.weights.shape or self.dofs.ndim != 1 or self.dofs.size == 0:
            raise ValueError("an attached point needs one weight per support dof, and at "
                             "least one")
        if abs(float(self.weights.sum()) - 1.0) > 1e-10:
            raise ValueError(f"attachment weights must sum to 1, got {self.weights.sum():.12g}")


def _node_positions(body: FemBody) -> np.ndarray:
    """Rest positions of the body's local block dofs (P1: the mesh nodes)."""
    return body.V.tabulate_dof_coordinates()


def shape_function_weights(body: FemBody, point, *, snap: bool = False,
                           tol: float = 1e-10) -> FemPointWeights:
    """Weights of the element containing ``point`` (its shape functions at the point).

    A point outside the mesh is an error naming its distance to the mesh, or,
    with ``snap=True``, is moved to the closest point of the nearest element
    (the distance is kept in the result).
    """
    X = np.asarray(point, dtype=float).reshape(3)
    msh = body.mesh
    tdim = msh.topology.dim
    n_cells = msh.topology.index_map(tdim).size_local
    tree = geometry.bb_tree(msh, tdim, padding=tol)
    candidates = geometry.compute_collisions_points(tree, X.reshape(1, 3))
    colliding = geometry.compute_colliding_cells(msh, candidates, X.reshape(1, 3))
    cells = colliding.links(0)
    distance = 0.0
    if cells.size == 0:
        midpoints = geometry.create_midpoint_tree(msh, tdim, np.arange(n_cells, dtype=np.int32))
        cell = int(geometry.compute_closest_entity(tree, midpoints, msh, X.reshape(1, 3))[0])
        closest = _closest_point_in_cell(body, cell, X)
        distance = float(np.linalg.norm(closest - X))
        if not snap:
            raise ValueError(f"point {X.tolist()} is outside FEM body {body.name!r} "
                             f"(distance {distance:.4g} to element "
                             f"{int(body.input_cell_index([cell])[0])}); pass snap=True to "
                             f"attach it to the closest point of that element")
        X = closest
    else:
        cell = int(cells[0])
    nodes = msh.geometry.x[msh.geometry.dofmaps[0][cell]]
    ref = msh.geometry.cmaps[0].pull_back(X.reshape(1, 3), nodes)
    element = basix.create_element(basix.ElementFamily.P,
                                   getattr(basix.CellType, body.cell_name), 1)
    w = element.tabulate(0, ref)[0, 0, :, 0]
    dofs = body.V.dofmap.list[cell].astype(np.int64)
    return FemPointWeights(dofs, w, w @ _node_positions(body)[dofs], distance, cell)


def _closest_point_in_cell(body: FemBody, cell: int, X: np.ndarray) -> np.ndarray:
    """Closest point of a cell to X (GJK on the cell's vertices: the cells are convex)."""
    msh = body.mesh
    nodes = msh.geometry.x[msh.geometry.dofmaps[0][cell]]
    return X + geometry.compute_distance_gjk(nodes, X.reshape(1, 3))


def nearest_nodes(body: FemBody, point, k: int) -> np.ndarray:
    """Input indices of k nodes near ``point``: the nearest 4 that are not coplanar, then the
    nearest others (a support for :func:`support_weights`)."""
    if k < 4:
        raise ValueError(f"a support needs at least 4 nodes to reproduce a 3-D point, got {k}")
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
    rest = [d for d in order if d not in spanning][:k - len(spanning)]
    local = np.array(sorted(spanning + rest, key=lambda d: np.linalg.norm(x[d] - X)))
    inverse = {d: n for n, d in body._input_node_to_dof().items()}
    return np.array([inverse[int(d)] for d in local], dtype=np.int64)


def support_weights(body: FemBody, point, nodes) -> FemPointWeights:
    """Minimum-norm weights on the given support nodes (input indices) that sum to one and
    reproduce ``point`` at rest (see the module docstring)."""
    X = np.asarray(point, dtype=float).reshape(3)
    nodes = np.asarray(nodes, dtype=np.int64).ravel()
    dofs = body.local_dofs(nodes).astype(np.int64)
    if dofs.size != nodes.size:
        missing = [int(n) for n in nodes if n not in body._input_node_to_dof()]
        raise ValueError(f"support nodes {missing[:10]} are not nodes of FEM body {body.name!r}")
    Xj = _node_positions(body)[dofs]
    A = np.vstack([Xj.T, np.ones(len(dofs))])                          # (4, k)
    if np.linalg.matrix_rank(A) < 4:
        raise ValueError(f"support nodes {[int(n) for n in nodes[:10]]} are coplanar: they "
                         f"cannot reproduce an arbitrary point")
    w = A.T @ np.linalg.solve(A @ A.T, np.append(X, 1.0))
    return FemPointWeights(dofs, w, w @ Xj)


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
