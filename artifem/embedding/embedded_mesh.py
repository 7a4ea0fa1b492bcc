"""Meshes embedded in an FEM body (Lloyd et al. 2019, section 4).

A passive point set, polyline or triangle surface follows a deformable body
through the body's own shape functions: each embedded vertex p lies in an
element e(p) of the body at reference coordinates xi_p, and

    x_p = sum_j N_j(xi_p) (X_j + u_j),     i.e.   x = x_rest + G u,

with G (3 p x 3 n, scipy CSR, n the body's owned block dofs) holding the
weights N_j(xi_p) on the block diagonals, and x_rest = G X the rest
positions the weights reproduce. The weights sum to one and reproduce any
affine field exactly, so an affine displacement of the body moves the
embedded mesh by the same affine map.

Forces on the embedded vertices come back to the body by virtual work,
f_nodes = G^T f (:meth:`EmbeddedMesh.force_to_nodes`), so f . (G v) =
(G^T f) . v. On a :class:`~artifem.reduction.reduced_body.ReducedFemBody`
(u = u_bar + U q) the same weights give x = (x_rest + G u_bar) + (G U) q and
the generalized force (G U)^T f.

Location is vectorized: DOLFINx's bounding-box tree and colliding cells for
all points at once, then a Newton pull-back vectorized over all points (one
basix tabulation of the coordinate element per iteration; one iteration is
exact on affine tetrahedra). Points outside the body are an error that
states how many there are and the worst distance, or, with ``snap=True``,
move to the closest point of the nearest element (GJK); the per-point
distances are kept in :attr:`EmbeddedMesh.distance`.

Positions are not stored: :meth:`EmbeddedMesh.positions` evaluates
x_rest + G u from the body's current state each time it is called (a sparse
product of 3 p x 8 entries), so an embedded mesh costs nothing until something
observes it (rendering, output, a force that needs the current geometry).

Serial for now (the body's local dofs; a ReducedFemBody is serial anyway).
In parallel each rank would locate its points with
``dolfinx.geometry.determine_point_ownership`` and G would need global
columns for ghost dofs; this raises NotImplementedError instead.
"""

from __future__ import annotations

import basix
import numpy as np
from dolfinx import geometry
from scipy import sparse

__all__ = ["EmbeddedMesh", "locate_points", "PointLocation", "OutsideMeshError"]

CELL_TYPES = {"vertex": 1, "line": 2, "triangle": 3}


class OutsideMeshError(ValueError):
    """Embedded points lie outside the body (and ``snap`` was not requested)."""

    def __init__(self, name: str, outside: np.ndarray, distance: np.ndarray):
        self.outside, self.distance = outside, distance
        worst = int(outside[np.argmax(distance[outside])])
        super().__init__(
            f"{outside.size} embedded point(s) lie outside FEM body {name!r}; the worst is "
            f"point {worst} at distance {distance[worst]:.4g}; pass snap=True to move them to "
            f"the closest point of the nearest element")


class PointLocation:
    """Result of :func:`locate_points` (local cells, reference coordinates, weights)."""

    def __init__(self, cells, reference, weights, points, distance):
        self.cells = cells              # (p,) local cell of each point
        self.reference = reference      # (p, 3) reference coordinates
        self.weights = weights          # (p, k) shape-function values (k nodes per cell)
        self.points = points            # (p, 3) located (possibly snapped) points
        self.distance = distance        # (p,) distance from the requested point (0 inside)


def _full_body(body):
    """(FemBody, ReducedFemBody or None) of a full or reduced body."""
    if hasattr(body, "full") and hasattr(body, "U"):
        return body.full, body
    return body, None


def _pull_back(element, nodes: np.ndarray, x: np.ndarray, centre: np.ndarray,
               tol: float = 1e-12, max_iterations: int = 30) -> np.ndarray:
    """Reference coordinates of points x (p, 3) in cells with node coordinates (p, k, 3).

    Newton on x(xi) = sum_j N_j(xi) X_j, vectorized over the points.
    """
    xi = np.tile(centre, (x.shape[0], 1))
    scale = np.maximum(np.ptp(nodes, axis=1).max(axis=1), np.finfo(float).tiny)
    for _ in range(max_iterations):
        tab = element.tabulate(1, xi)[..., 0]                     # (4, p, k)
        phi = np.einsum("ipk,pkd->ipd", tab, nodes)                # x and its derivatives
        residual = x - phi[0]                                      # (p, 3)
        J = np.transpose(phi[1:4], (1, 2, 0))                      # (p, d, reference dir)
        dxi = np.linalg.solve(J, residual[..., None])[..., 0]
        xi = xi + dxi
        # Reference coordinates are O(1); round-off in x amplified by J^-1 limits dxi to
        # about 1e-14 (x / h), so converge on 1e-12.
        if np.abs(dxi).max() <= tol and np.all(np.abs(residual).max(axis=1) <= 1e-8 * scale):
            break
    else:
        raise RuntimeError("pull-back of embedded points to reference coordinates did not "
                           "converge (degenerate or badly distorted element?)")
    return xi


def locate_points(body, points, *, snap: bool = False, tol: float = 1e-10) -> PointLocation:
    """Locate all ``points`` (p, 3) in a FEM body's mesh at once (see the module docstring)."""
    body, _ = _full_body(body)
    msh = body.mesh
    if msh.comm.size != 1:
        raise NotImplementedError("embedded meshes are serial for now (see artifem.embedding."
                                  "embedded_mesh)")
    X = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3))
    p = X.shape[0]
    tdim = msh.topology.dim
    n_cells = msh.topology.index_map(tdim).size_local
    tree = geometry.bb_tree(msh, tdim, padding=tol)
    candidates = geometry.compute_collisions_points(tree, X)
    colliding = geometry.compute_colliding_cells(msh, candidates, X)
    offsets = np.asarray(colliding.offsets)
    counts = np.diff(offsets)
    cells = np.full(p, -1, dtype=np.int32)
    found = counts > 0
    cells[found] = np.asarray(colliding.array)[offsets[:-1][found]]
    distance = np.zeros(p)
    located = X.copy()
    outside = np.flatnonzero(~found)
    if outside.size:
        midpoints = geometry.create_midpoint_tree(msh, tdim, np.arange(n_cells, dtype=np.int32))
        nearest = np.asarray(geometry.compute_closest_entity(tree, midpoints, msh, X[outside]),
                             dtype=np.int32)
        x_geom, dofmap = msh.geometry.x, msh.geometry.dofmaps[0]
        for i, c in zip(outside.tolist(), nearest.tolist()):
            d = geometry.compute_distance_gjk(x_geom[dofmap[c]], X[i:i + 1])
            located[i] = X[i] + d
            distance[i] = float(np.linalg.norm(d))
        cells[outside] = nearest
        if not snap:
            raise OutsideMeshError(body.name, outside, distance)

    cmap = msh.geometry.cmaps[0]
    if cmap.degree != 1:
        raise NotImplementedError(f"embedding needs a degree-1 geometry, got {cmap.degree}")
    element = basix.create_element(basix.ElementFamily.P,
                                   getattr(basix.CellType, body.cell_name), 1)
    nodes = msh.geometry.x[msh.geometry.dofmaps[0][cells]]        # (p, k, 3)
    centre = basix.geometry(element.cell_type).mean(axis=0)
    xi = _pull_back(element, nodes, located, centre)
    w = element.tabulate(0, xi)[0, :, :, 0]                       # (p, k)
    return PointLocation(cells, xi, w, located, distance)


class EmbeddedMesh:
    """A point set, polyline or triangle surface embedded in a full or reduced FEM body.

    Args:
        body: a :class:`~artifem.fem_body.FemBody` or a
            :class:`~artifem.reduction.reduced_body.ReducedFemBody`.
        points: (p, 3) rest positions of the embedded vertices.
        cells: (c, k) vertex indices of the embedded cells (k = 2 for "line",
            3 for "triangle"); None for a point set.
        cell_type: "vertex", "line" or "triangle".
        snap: move points outside the body to the nearest element instead of raising.
        tol: bounding-box padding of the point location.

    Attributes:
        G: (3 p, 3 n) scipy CSR weights on the body's owned block dofs.
        G_reduced: (3 p, r) dense G U on a reduced body (None on a full body).
        rest_positions: (p, 3) x_rest = G X (the located, possibly snapped, points).
        distance: (p,) distance each point was moved by snapping (0 inside).
    """

    def __init__(self, body, points, cells=None, cell_type: str = "vertex", *,
                 snap: bool = False, tol: float = 1e-10, name: str = "embedded"):
        if cell_type not in CELL_TYPES:
            raise ValueError(f"EmbeddedMesh {name!r}: cell_type must be one of "
                             f"{sorted(CELL_TYPES)}, got {cell_type!r}")
        points = np.asarray(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] == 0:
            raise ValueError(f"EmbeddedMesh {name!r}: points must have shape (p, 3), p >= 1, "
                             f"got {points.shape}")
        k = CELL_TYPES[cell_type]
        if cells is None:
            cells = np.arange(points.shape[0]).reshape(-1, 1) if k == 1 else None
            if cells is None:
                raise ValueError(f"EmbeddedMesh {name!r}: a {cell_type} mesh needs cells")
        cells = np.asarray(cells, dtype=np.int64)
        if cells.ndim != 2 or cells.shape[1] != k:
            raise ValueError(f"EmbeddedMesh {name!r}: {cell_type} cells must have shape "
                             f"(c, {k}), got {cells.shape}")
        if cells.size and (cells.min() < 0 or cells.max() >= points.shape[0]):
            raise ValueError(f"EmbeddedMesh {name!r}: cell vertex indices out of range "
                             f"[0, {points.shape[0]})")
        self.name, self.body, self.cell_type, self.cells = name, body, cell_type, cells
        self.full, self.reduced = _full_body(body)
        loc = locate_points(self.full, points, snap=snap, tol=tol)
        self.location = loc
        self.distance = loc.distance
        self.requested_positions = points.copy()

        V = self.full.V
        n = V.dofmap.index_map.size_local
        dofs = V.dofmap.list[loc.cells].astype(np.int64)              # (p, k)
        p, kk = dofs.shape
        rows = (3 * np.arange(p)[:, None, None] + np.arange(3)[None, None, :])
        rows = np.broadcast_to(rows, (p, kk, 3))
        cols = 3 * dofs[:, :, None] + np.arange(3)[None, None, :]
        vals = np.broadcast_to(loc.weights[:, :, None], (p, kk, 3))
        self.G = sparse.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())),
                                   shape=(3 * p, 3 * n))
        X_nodes = V.tabulate_dof_coordinates()[:n]
        self.rest_positions = (self.G @ X_nodes.ravel()).reshape(p, 3)
        if self.reduced is not None:
            self.G_reduced = np.asarray(self.G @ self.reduced.U)
            self._x_bar = self.rest_positions.ravel() + self.G @ self.reduced.u_bar
        else:
            self.G_reduced = None

    @property
    def num_points(self) -> int:
        return self.rest_positions.shape[0]

    @property
    def jacobian(self):
        """dx/d(body coordinates): G (sparse) on a full body, G U (dense) on a reduced one."""
        return self.G if self.reduced is None else self.G_reduced

    def positions(self) -> np.ndarray:
        """Current positions (p, 3), evaluated now from the body's state."""
        if self.reduced is not None:
            return (self._x_bar + self.G_reduced @ self.reduced.q).reshape(-1, 3)
        n3 = self.G.shape[1]
        return self.rest_positions + (self.G @ self.full.u.x.array[:n3]).reshape(-1, 3)

    def velocities(self) -> np.ndarray:
        """Current velocities (p, 3)."""
        if self.reduced is not None:
            return (self.G_reduced @ self.reduced.qdot).reshape(-1, 3)
        return (self.G @ self.full.v.x.array[:self.G.shape[1]]).reshape(-1, 3)

    def force_to_nodes(self, f) -> np.ndarray:
        """G^T f: forces f (p, 3) on the vertices as nodal forces (3 n,) of the full body, or
        as the generalized force (r,) of a reduced body."""
        f = np.asarray(f, dtype=float).reshape(-1)
        if f.size != 3 * self.num_points:
            raise ValueError(f"EmbeddedMesh {self.name!r}: expected {self.num_points} x 3 "
                             f"forces, got {f.size} values")
        return self.jacobian.T @ f

    def to_pyvista(self):
        """The embedded mesh at its current positions as a pyvista PolyData."""
        import pyvista as pv

        x = self.positions()
        k = self.cells.shape[1]
        conn = np.hstack([np.full((self.cells.shape[0], 1), k), self.cells]).ravel()
        if self.cell_type == "vertex":
            return pv.PolyData(x, verts=conn)
        if self.cell_type == "line":
            return pv.PolyData(x, lines=conn)
        return pv.PolyData(x, faces=conn)
