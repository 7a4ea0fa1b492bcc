"""Meshes embedded in an FEM body (Lloyd et al. 2019, section 4).

A passive point set, polyline or triangle surface follows a deformable body
through the body's own shape functions: each embedded vertex p lies in an
element e(p) of the body at reference coordinates xi_p, and

    x_p = sum_j N_j(xi_p) (X_j + u_j),     i.e.   x = x_rest + G u,

with G (3 p x 3 n, scipy CSR, n the body's local block dofs) holding the
weights N_j(xi_p) on the block diagonals, and x_rest = G X the rest
positions the weights reproduce. The weights sum to one and reproduce any
affine field exactly, so an affine displacement of the body moves the
embedded mesh by the same affine map.

Forces on the embedded vertices come back to the body by virtual work,
f_nodes = G^T f (:meth:`EmbeddedMesh.force_to_nodes`), so f . (G v) =
(G^T f) . v. On a :class:`~artifem.reduction.reduced_body.ReducedFemBody`
(u = u_bar + U q) the same weights give x = (x_rest + G u_bar) + (G U) q and
the generalized force (G U)^T f.

Location (:func:`locate_points`) is vectorized: DOLFINx's bounding-box tree
and colliding cells for all points at once, then a Newton pull-back
vectorized over all (point, candidate cell) pairs (one basix tabulation of
the coordinate element per iteration; one iteration is exact on affine
tetrahedra); of several candidates a point takes the cell its reference
coordinates lie deepest in (DOLFINx accepts cells within 1e-6, and the convex
hull of a distorted hexahedron is larger than the trilinear cell). Points
outside the body are an error that states how many there are and the worst
distance, or, with ``snap=True``, move to the closest point of the nearest
element: GJK on a tetrahedron, an active-set Gauss-Newton on the reference
cube of a (trilinear) hexahedron, so the weights stay in [0, 1]; the per-point
distances are kept in :attr:`EmbeddedMesh.distance`.

Positions are not stored: :meth:`EmbeddedMesh.positions` evaluates
x_rest + G u from the body's current state each time it is called (a sparse
product of 3 p x 8 entries), so an embedded mesh costs nothing until something
observes it (rendering, output, a force that needs the current geometry).

In parallel every rank passes the same full point set (the constructor is
collective). Each point is owned by exactly one rank: the one whose owned
cell contains it (the deepest candidate, ties to the lowest rank), or, for a
point outside the body, the one with the nearest owned cell (ties to the
lowest rank). A rank's G has rows for the points it owns and columns in its
local block dofs (owned, then ghosts; the ghost values of u and v must be
current, as the integrators keep them). :meth:`~EmbeddedMesh.positions`,
:meth:`~EmbeddedMesh.velocities`, :attr:`~EmbeddedMesh.rest_positions` and
:attr:`~EmbeddedMesh.distance` are the full (p, 3) / (p,) arrays on every
rank (gathered); :meth:`~EmbeddedMesh.force_to_nodes` takes the full f on
every rank and returns the nodal forces on the rank's owned dofs, ghost
contributions added into their owners, so that the sum over ranks of
f_nodes . v_owned is f . v. A ReducedFemBody is serial.
"""

from __future__ import annotations

import basix
import numpy as np
from dolfinx import fem, geometry, la
from scipy import sparse

from artifem.contact_points import EmbeddedPoints
from artifem.errors import InputError, OutsideMeshError

__all__ = ["EmbeddedMesh", "locate_points", "PointLocation", "OutsideMeshError"]

CELL_TYPES = {"vertex": 1, "line": 2, "triangle": 3}


class PointLocation:
    """Result of :func:`locate_points`: the points this rank owns (all of them in serial)."""

    def __init__(self, indices, cells, reference, weights, points, distance):
        self.indices = indices  # (m,) indices of the owned points in the input
        self.cells = cells  # (m,) local cell of each owned point
        self.reference = reference  # (m, 3) reference coordinates
        self.weights = weights  # (m, k) shape-function values (k nodes per cell)
        self.points = points  # (m, 3) located (possibly snapped) points
        self.distance = distance  # (p,) distance of every input point from the mesh
        #      (0 inside; the same on every rank)


def _full_body(body):
    """(FemBody, ReducedFemBody or None) of a full or reduced body."""
    if hasattr(body, "full") and hasattr(body, "U"):
        return body.full, body
    return body, None


def _pull_back(
    element,
    nodes: np.ndarray,
    x: np.ndarray,
    centre: np.ndarray,
    tol: float = 1e-12,
    max_iterations: int = 30,
):
    """Reference coordinates (p, 3) of points x (p, 3) in cells with node coordinates
    (p, k, 3), and whether each converged.

    Newton on x(xi) = sum_j N_j(xi) X_j, vectorized over the points.
    """
    xi = np.tile(centre, (x.shape[0], 1))
    scale = np.maximum(np.ptp(nodes, axis=1).max(axis=1), np.finfo(float).tiny)
    converged = np.zeros(x.shape[0], dtype=bool)
    for _ in range(max_iterations if x.shape[0] else 0):
        tab = element.tabulate(1, xi)[..., 0]  # (4, p, k)
        phi = np.einsum("ipk,pkd->ipd", tab, nodes)  # x and its derivatives
        residual = x - phi[0]  # (p, 3)
        J = np.transpose(phi[1:4], (1, 2, 0))  # (p, d, reference dir)
        dxi = np.linalg.solve(J, residual[..., None])[..., 0]
        xi = xi + dxi
        # Reference coordinates are O(1); round-off in x amplified by J^-1 limits dxi to
        # about 1e-14 (x / h), so converge on 1e-12.
        converged = (np.abs(dxi).max(axis=1) <= tol) & (
            np.abs(residual).max(axis=1) <= 1e-8 * scale
        )
        if converged.all():
            break
    return xi, converged


def _outside_reference(cell_name: str, xi: np.ndarray) -> np.ndarray:
    """How far reference coordinates (p, 3) lie outside the reference cell (0 inside)."""
    if cell_name == "hexahedron":
        excess = np.maximum(-xi, xi - 1.0).max(axis=1)
    else:
        excess = np.maximum(-xi.min(axis=1), xi.sum(axis=1) - 1.0)
    return np.maximum(excess, 0.0)


def _closest_in_hexahedra(
    element, nodes: np.ndarray, X: np.ndarray, max_iterations: int = 200
) -> np.ndarray:
    """Reference coordinates xi in [0, 1]^3 of the closest points of trilinear cells with
    nodes (p, 8, 3) to points X (p, 3): argmin |x(xi) - X|^2 by an active-set Gauss-Newton
    (coordinates on a bound whose gradient points outward stay there; the others take the
    Gauss-Newton step), projected onto the cube with backtracking, falling back to a
    projected gradient step; from the cell centres, vectorized over the points. (The
    pull-back of the closest point of a distorted cell's convex hull can land on a spurious
    root far outside the cell, hence extrapolated weights.)"""

    def residual(xi, idx):
        return np.einsum("pk,pkd->pd", element.tabulate(0, xi)[0, :, :, 0], nodes[idx]) - X[idx]

    def descend(xi, r, step, idx):
        """Backtracking along step projected on the cube: (xi, r, decreased?) per point."""
        xi, r, decreased = xi.copy(), r.copy(), np.zeros(len(idx), dtype=bool)
        todo, alpha = np.arange(len(idx)), 1.0
        while todo.size and alpha > 1e-8:
            trial = np.clip(xi[todo] + alpha * step[todo], 0.0, 1.0)
            r_trial = residual(trial, idx[todo])
            ok = (r_trial**2).sum(axis=1) < (r[todo] ** 2).sum(axis=1)
            xi[todo[ok]], r[todo[ok]], decreased[todo[ok]] = trial[ok], r_trial[ok], True
            todo, alpha = todo[~ok], 0.5 * alpha
        return xi, r, decreased

    xi = np.full(X.shape, 0.5)
    r = residual(xi, np.arange(X.shape[0]))
    active = np.arange(X.shape[0])
    eye = np.eye(3)
    for _ in range(max_iterations):
        if active.size == 0:
            break
        xa, ra = xi[active], r[active]
        tab = element.tabulate(1, xa)[1:4, :, :, 0]  # (3, a, k)
        J = np.einsum("ipk,pkd->pdi", tab, nodes[active])  # dx/dxi
        g = np.einsum("pdi,pd->pi", J, ra)
        free = ~(((xa <= 0.0) & (g > 0)) | ((xa >= 1.0) & (g < 0)))
        both = free[:, :, None] & free[:, None, :]
        H = np.where(both, np.einsum("pdi,pdj->pij", J, J), eye)
        gauss = np.linalg.solve(H, np.where(free, -g, 0.0)[..., None])[..., 0]
        new, r_new, decreased = descend(xa, ra, gauss, active)
        if not decreased.all():
            stuck = np.flatnonzero(~decreased)
            lipschitz = np.maximum(np.linalg.norm(J[stuck], 2, axis=(1, 2)) ** 2, 1e-300)
            new[stuck], r_new[stuck], decreased[stuck] = descend(
                xa[stuck], ra[stuck], -g[stuck] / lipschitz[:, None], active[stuck]
            )
        done = ~decreased | (np.abs(new - xa).max(axis=1) < 1e-14)
        xi[active], r[active] = new, r_new
        active = active[~done]
    return xi


def _lowest(comm, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each entry of ``values`` (the same length on every rank): the rank holding the
    smallest value (the lowest such rank on ties) and that value."""
    if comm.size == 1 or values.size == 0:
        return np.full(values.size, comm.rank), values
    every = np.empty((comm.size, values.size))
    comm.Allgather(np.ascontiguousarray(values, dtype=float), every)
    rank = np.argmin(every, axis=0)
    return rank, every[rank, np.arange(values.size)]


def locate_points(body, points, *, snap: bool = False, tol: float = 1e-10) -> PointLocation:
    """Locate all ``points`` (p, 3) in a FEM body's mesh at once (see the module docstring).

    Collective: every rank passes the same points and gets those it owns. Points farther
    than ``tol`` from the mesh raise :class:`OutsideMeshError` on every rank unless ``snap``.
    """
    body, _ = _full_body(body)
    msh = body.mesh
    comm = msh.comm
    if msh.geometry.cmaps[0].degree != 1:
        raise NotImplementedError(
            f"embedding in FEM body {body.name!r} needs a degree-1 "
            f"geometry, got {msh.geometry.cmaps[0].degree}"
        )
    X = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3))
    p = X.shape[0]
    tdim = msh.topology.dim
    owned_cells = np.arange(msh.topology.index_map(tdim).size_local, dtype=np.int32)
    x_geom, geom_dofs = msh.geometry.x, msh.geometry.dofmaps[0]
    element = basix.create_element(
        basix.ElementFamily.P, getattr(basix.CellType, body.cell_name), 1
    )
    centre = basix.geometry(element.cell_type).mean(axis=0)
    tree = geometry.bb_tree(msh, tdim, padding=tol, entities=owned_cells)

    # Inside: of all (point, colliding owned cell) pairs, the cell the point lies deepest in.
    colliding = geometry.compute_colliding_cells(
        msh, geometry.compute_collisions_points(tree, X), X
    )
    pair_point = np.repeat(np.arange(p), np.diff(colliding.offsets))
    pair_cell = np.asarray(colliding.array, dtype=np.int32)
    pair_xi, converged = _pull_back(element, x_geom[geom_dofs[pair_cell]], X[pair_point], centre)
    depth = np.where(converged, _outside_reference(body.cell_name, pair_xi), np.inf)
    depth[depth <= 1e-12] = 0.0  # round-off on a shared face: a tie
    order = np.lexsort((depth, pair_point))
    first = (
        order[np.r_[True, pair_point[order][1:] != pair_point[order][:-1]]] if order.size else order
    )
    best = np.full(p, np.inf)
    best[pair_point[first]] = depth[first]
    owner, best = _lowest(comm, best)
    cells = np.full(p, -1, dtype=np.int32)
    cells[pair_point[first]] = pair_cell[first]
    xi = np.zeros((p, 3))
    xi[pair_point[first]] = pair_xi[first]
    located = X.copy()
    distance = np.zeros(p)

    # Outside every rank's cells: the closest point of the globally nearest element.
    outside = np.flatnonzero(~np.isfinite(best))
    if outside.size:
        Xo = X[outside]
        d = np.full(outside.size, np.inf)
        if owned_cells.size:
            midpoints = geometry.create_midpoint_tree(msh, tdim, owned_cells)
            near = np.asarray(
                geometry.compute_closest_entity(tree, midpoints, msh, Xo), dtype=np.int32
            )
            nodes = x_geom[geom_dofs[near]]
            if body.cell_name == "hexahedron":
                xi_o = _closest_in_hexahedra(element, nodes, Xo)
                y = np.einsum("pk,pkd->pd", element.tabulate(0, xi_o)[0, :, :, 0], nodes)
            else:  # convex cells: GJK, then the pull-back
                y = Xo + np.array(
                    [geometry.compute_distance_gjk(c, x.reshape(1, 3)) for c, x in zip(nodes, Xo)]
                )
                xi_o = _pull_back(element, nodes, y, centre)[0]
            d = np.linalg.norm(y - Xo, axis=1)
            cells[outside], xi[outside], located[outside] = near, xi_o, y
        owner[outside], distance[outside] = _lowest(comm, d)
        far = outside[distance[outside] > tol]
        if far.size and not snap:
            raise OutsideMeshError(body.name, far, distance)

    mine = np.flatnonzero(owner == comm.rank)
    w = (
        element.tabulate(0, xi[mine])[0, :, :, 0] if mine.size else np.zeros((0, element.dim))
    )  # (m, k)
    return PointLocation(mine, cells[mine], xi[mine], w, located[mine], distance)


class EmbeddedMesh:
    """A point set, polyline or triangle surface embedded in a full or reduced FEM body.

    Args:
        body: a :class:`~artifem.fem_body.FemBody` or a
            :class:`~artifem.reduction.reduced_body.ReducedFemBody`.
        points: (p, 3) rest positions of the embedded vertices (the same on every rank).
        cells: (c, k) vertex indices of the embedded cells (k = 2 for "line",
            3 for "triangle"); None for a point set.
        cell_type: "vertex", "line" or "triangle".
        snap: move points outside the body to the nearest element instead of raising.
        tol: bounding-box padding of the point location.

    Attributes:
        G: (3 m, 3 n) scipy CSR weights of the m points this rank owns (all p in serial, in
            the order of :attr:`owned`) on the body's n local block dofs (owned, then ghosts).
        G_reduced: (3 p, r) dense G U on a reduced body (None on a full body).
        owned: (m,) indices of the points this rank owns.
        rest_positions: (p, 3) x_rest = G X (the located, possibly snapped, points).
        distance: (p,) distance each point was moved by snapping (0 inside).
    """

    def __init__(
        self,
        body,
        points,
        cells=None,
        cell_type: str = "vertex",
        *,
        snap: bool = False,
        tol: float = 1e-10,
        name: str = "embedded",
    ):
        if cell_type not in CELL_TYPES:
            raise InputError(
                f"EmbeddedMesh {name!r}: cell_type must be one of "
                f"{sorted(CELL_TYPES)}, got {cell_type!r}"
            )
        points = np.asarray(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] == 0:
            raise InputError(
                f"EmbeddedMesh {name!r}: points must have shape (p, 3), p >= 1, got {points.shape}"
            )
        k = CELL_TYPES[cell_type]
        if cells is None:
            cells = np.arange(points.shape[0]).reshape(-1, 1) if k == 1 else None
            if cells is None:
                raise InputError(f"EmbeddedMesh {name!r}: a {cell_type} mesh needs cells")
        cells = np.asarray(cells, dtype=np.int64)
        if cells.ndim != 2 or cells.shape[1] != k:
            raise InputError(
                f"EmbeddedMesh {name!r}: {cell_type} cells must have shape "
                f"(c, {k}), got {cells.shape}"
            )
        if cells.size and (cells.min() < 0 or cells.max() >= points.shape[0]):
            raise InputError(
                f"EmbeddedMesh {name!r}: cell vertex indices out of range [0, {points.shape[0]})"
            )
        self.name, self.body, self.cell_type, self.cells = name, body, cell_type, cells
        self.full, self.reduced = _full_body(body)
        loc = locate_points(self.full, points, snap=snap, tol=tol)
        self.location = loc
        self.distance = loc.distance
        self.requested_positions = points.copy()
        self.owned = loc.indices

        V = self.full.V
        imap = V.dofmap.index_map
        n = imap.size_local + imap.num_ghosts
        self._n_owned = imap.size_local
        dofs = V.dofmap.list[loc.cells].astype(np.int64)  # (m, k)
        m, kk = dofs.shape
        rows = 3 * np.arange(m)[:, None, None] + np.arange(3)[None, None, :]
        rows = np.broadcast_to(rows, (m, kk, 3))
        cols = 3 * dofs[:, :, None] + np.arange(3)[None, None, :]
        vals = np.broadcast_to(loc.weights[:, :, None], (m, kk, 3))
        self.G = sparse.csr_matrix(
            (vals.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * m, 3 * n)
        )
        comm = self.full.mesh.comm
        if comm.size > 1:
            counts = np.array(comm.allgather(3 * m))
            self._gathered = (counts, np.concatenate(comm.allgather(self.owned)))
            self._nodal = fem.Function(V)  # G^T f with ghosts, summed to owners
        X_nodes = V.tabulate_dof_coordinates()[:n]
        self._rest_owned = self.G @ X_nodes.ravel()
        self.rest_positions = self._gather(self._rest_owned)
        if self.reduced is not None:
            self.G_reduced = np.asarray(self.G @ self.reduced.U)
            self._x_bar = self.rest_positions.ravel() + self.G @ self.reduced.u_bar
        else:
            self.G_reduced = None

    def _gather(self, owned: np.ndarray) -> np.ndarray:
        """The (p, 3) array of all points from each rank's rows (3 m,) of its owned points."""
        if self.full.mesh.comm.size == 1:
            return owned.reshape(-1, 3)
        counts, order = self._gathered
        every = np.empty(counts.sum())
        self.full.mesh.comm.Allgatherv(np.ascontiguousarray(owned), [every, counts])
        out = np.empty((order.size, 3))
        out[order] = every.reshape(-1, 3)
        return out

    @property
    def num_points(self) -> int:
        return self.rest_positions.shape[0]

    @property
    def jacobian(self):
        """dx/d(body coordinates): G (sparse) on a full body, G U (dense) on a reduced one."""
        return self.G if self.reduced is None else self.G_reduced

    def positions(self) -> np.ndarray:
        """Current positions (p, 3), evaluated now from the body's state (collective)."""
        if self.reduced is not None:
            return (self._x_bar + self.G_reduced @ self.reduced.q).reshape(-1, 3)
        n3 = self.G.shape[1]
        return self._gather(self._rest_owned + self.G @ self.full.u.x.array[:n3])

    def velocities(self) -> np.ndarray:
        """Current velocities (p, 3) (collective)."""
        if self.reduced is not None:
            return (self.G_reduced @ self.reduced.qdot).reshape(-1, 3)
        return self._gather(self.G @ self.full.v.x.array[: self.G.shape[1]])

    def contact_points(self, points=None) -> EmbeddedPoints:
        """The vertices contact may push (:mod:`artifem.contact_points`; ``points`` must be
        None: every vertex); the rows act on the master body."""
        if points is not None:
            raise InputError(
                f"EmbeddedMesh {self.name!r}: contact takes all its vertices (points=None)"
            )
        return EmbeddedPoints(self)

    def contact_surface(self) -> tuple[EmbeddedPoints, np.ndarray]:
        """(the vertices, the triangles) of an embedded triangle surface."""
        if self.cell_type != "triangle":
            raise InputError(
                f"EmbeddedMesh {self.name!r}: a contact surface must be a "
                f"triangle mesh, this one is a {self.cell_type} mesh"
            )
        return EmbeddedPoints(self), self.cells

    def force_to_nodes(self, f) -> np.ndarray:
        """G^T f: forces f (p, 3) on the vertices (all of them, on every rank) as nodal forces
        (3 n_owned,) on the full body's owned dofs, or as the generalized force (r,) of a
        reduced body."""
        f = np.asarray(f, dtype=float).reshape(-1)
        if f.size != 3 * self.num_points:
            raise InputError(
                f"EmbeddedMesh {self.name!r}: expected {self.num_points} x 3 "
                f"forces, got {f.size} values"
            )
        if self.reduced is not None:
            return self.G_reduced.T @ f
        local = self.G.T @ f.reshape(-1, 3)[self.owned].ravel()
        if self.full.mesh.comm.size == 1:
            return local
        self._nodal.x.array[:] = local
        self._nodal.x.scatter_reverse(la.InsertMode.add)
        return self._nodal.x.array[: 3 * self._n_owned].copy()

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
