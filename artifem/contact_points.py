"""The points of a body that contact can push: where they are, and their rows.

A contact (:mod:`artifem.multibody.contact`, :mod:`artifem.multibody.mesh_contact`)
asks a body for a set of points (``body.contact_points(...)``) or for its closed surface
(``body.contact_surface() -> (points, triangles)``) and never looks at the body's kind.
A point set gives

    positions() -> (n, 3)   the points x_j in the world, now;
    rows(W, e) -> G          (k, n_coordinates): the rates e_k . sum_j W_kj x_j' of k
                             points, each a combination of the set's points (W sparse
                             k x n) moved along e_k (k, 3), on the body's coordinates;
    stiffness(W, f)          d(G^T lambda)/dq with forces f_k = lambda_k e_k held fixed
                             in the world (the levers of a rigid body turn with it);
    labels, describe(i)      the points' names for output and errors;
    mesh_body                the FEM body whose mesh nodes the points are (a reduced
                             body's full body), or None (a rigid body): where a contact
                             pressure can be given (:mod:`artifem.multibody.contact_pressure`);
    facing_areas(i, e)       (k,) the area of its own surface each point i_k stands for,
                             facing against e_k (an elastic foundation's rows,
                             :func:`facing_areas`).
    rigid_frame()            (optional: a rigid body's points) (r_j, R, p) with
                             x_j = p + R r_j, so a contact can keep the set's
                             geometry in that frame (:mod:`artifem.multibody.mesh_contact`).

This module holds the sets of FEM nodes, full (x_j = X_j + u_j, G = e^T W on the nodes'
velocity dofs) and reduced (x_j = X_j + u_bar_j + U_j q, G = e^T W U: k x r, dense, only
the rows U_j of the set's nodes are read). A rigid body's points are
:class:`artifem.multibody.rigid_body.BodyPoints`.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

__all__ = ["EmbeddedPoints", "FemNodes", "ReducedNodes", "facing_areas"]


class FemNodes:
    """Nodes of a full FEM body: its local blocked dofs ``dofs`` (P1: nodes), named by
    their input indices ``labels``."""

    def __init__(self, body, dofs: np.ndarray, labels: np.ndarray):
        self.body, self.dofs, self.labels = body, np.asarray(dofs), np.asarray(labels)
        self.mesh_body = body
        index_map = body.V.dofmap.index_map
        self.n = 3 * (index_map.size_local + index_map.num_ghosts)

    def __len__(self) -> int:
        return len(self.dofs)

    def positions(self) -> np.ndarray:
        X = self.body.V.tabulate_dof_coordinates()[self.dofs]
        return X + self.body.u.x.array.reshape(-1, 3)[self.dofs]

    def describe(self, i: int) -> str:
        return f"node {self.labels[i]}"

    def rows(self, W, directions: np.ndarray) -> sparse.csr_matrix:
        """G_k = e_k^T W_kj on node j's three velocity dofs (m x 3 n_nodes, sparse)."""
        W = sparse.coo_matrix(W)
        cols = 3 * self.dofs[W.col][:, None] + np.arange(3)
        vals = W.data[:, None] * directions[W.row]
        return sparse.csr_matrix(
            (vals.ravel(), (np.repeat(W.row, 3), cols.ravel())), shape=(W.shape[0], self.n)
        )

    def stiffness(self, W, forces: np.ndarray) -> sparse.csr_matrix:
        """Zero: a node's rows do not turn with it."""
        return sparse.csr_matrix((self.n, self.n))

    def facing_areas(self, indices: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(k,) the boundary area node ``indices[k]`` of the set stands for against
        ``directions[k]`` (:func:`facing_areas`), over the
        exterior facets of the (full) body's mesh at the current node positions: a
        triangle's projected area by thirds, a quadrilateral's (its two triangles of
        ``FemBody._surface``) by quarters, as the lumped ``boundary_areas`` of the facing
        facets on a flat face. Nodes off the boundary: 0."""
        full = getattr(self.body, "full", self.body)
        if getattr(self, "_facets", None) is None:
            dofs, tris = full._surface()
            corners = tris
            if len(tris) and full.mesh.topology.cell_type.name == "hexahedron":
                # FemBody._surface: a quadrilateral's two triangles are f and f + n_quads
                half = len(tris) // 2
                t1, t2 = tris[:half], tris[half:]
                fourth = np.where((t2[:, :, None] != t1[:, None, :]).all(axis=2), t2, -1).max(
                    axis=1
                )
                corners = np.column_stack([t1, fourth])
                pairs = (t1, t2)
            else:
                pairs = (tris,)
            self._facets = (dofs, corners, pairs, self.body.contact_points(None))
        dofs, corners, pairs, surface = self._facets
        x = surface.positions()
        area = sum(0.5 * np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]]) for t in pairs)
        mine = self.dofs[np.asarray(indices, dtype=int)]
        where = np.minimum(np.searchsorted(dofs, mine), len(dofs) - 1)
        on = dofs[where] == mine
        out = np.zeros(len(mine))
        if on.any():
            out[on] = facing_areas(area, corners, where[on], np.asarray(directions)[on], len(dofs))
        return out


class ReducedNodes(FemNodes):
    """Nodes of a reduced FEM body (its full body's dofs ``dofs``): x = X + u_bar + U q."""

    def __init__(self, body, dofs: np.ndarray, labels: np.ndarray):
        self.body, self.dofs, self.labels = body, np.asarray(dofs), np.asarray(labels)
        self.mesh_body = body.full
        rows = (3 * self.dofs[:, None] + np.arange(3)).ravel()
        self._X = body.full.V.tabulate_dof_coordinates()[self.dofs]
        self._u_bar = body.u_bar[rows].reshape(-1, 3)
        self._U = body.U[rows].reshape(len(self.dofs), 3, -1)  # (n, 3, r)
        self.n = body.U.shape[1]

    def positions(self) -> np.ndarray:
        return self._X + self._u_bar + self._U @ self.body.q

    def rows(self, W, directions: np.ndarray) -> np.ndarray:
        """G_k = sum_j W_kj e_k^T U_j (k x r, dense)."""
        W = sparse.csr_matrix(W)
        return np.einsum(
            "ka,kar->kr",
            directions,
            np.asarray((W @ self._U.reshape(len(self.dofs), -1))).reshape(W.shape[0], 3, -1),
        )

    def stiffness(self, W, forces: np.ndarray) -> np.ndarray:
        """Zero: the basis does not turn."""
        return np.zeros((self.n, self.n))


class EmbeddedPoints:
    """The vertices of a mesh embedded in a full or reduced FEM body
    (:class:`~artifem.embedding.embedded_mesh.EmbeddedMesh`: x_j = sum_i N_i(X_j) x_i, its
    ``jacobian`` J = dx/dq on the master's coordinates): G_k = sum_j W_kj e_k^T J_j."""

    def __init__(self, embedded):
        self.embedded, self.body = embedded, embedded.body
        self.labels = np.arange(embedded.num_points)
        self.mesh_body = None  # the embedded mesh has no FEM areas
        self.n = embedded.jacobian.shape[1]

    def __len__(self) -> int:
        return len(self.labels)

    def positions(self) -> np.ndarray:
        return self.embedded.positions()

    def describe(self, i: int) -> str:
        return f"vertex {i} of embedded mesh {self.embedded.name!r}"

    def rows(self, W, directions: np.ndarray):
        """E J, E_k = W_kj e_k^T on the vertices' three coordinates (sparse k x 3 p)."""
        W = sparse.coo_matrix(W)
        cols = 3 * W.col[:, None] + np.arange(3)
        E = sparse.csr_matrix(
            ((W.data[:, None] * directions[W.row]).ravel(), (np.repeat(W.row, 3), cols.ravel())),
            shape=(W.shape[0], 3 * len(self)),
        )
        G = E @ self.embedded.jacobian
        return G if sparse.issparse(G) else np.asarray(G)

    def stiffness(self, W, forces: np.ndarray):
        """Zero: J is fixed (the master's nodes carry the vertices on fixed weights)."""
        return sparse.csr_matrix((self.n, self.n))


def facing_areas(
    area_vectors: np.ndarray,
    corners: np.ndarray,
    vertices: np.ndarray,
    directions: np.ndarray,
    n: int,
) -> np.ndarray:
    """(k,) the area each surface vertex ``vertices[k]`` stands for against
    ``directions[k]`` (an elastic foundation's area rule, :mod:`artifem.multibody.foundation`):
    the facets (outward vector areas (f, 3), their corners (f, c) into n vertices) at the
    vertex with a_f . e_k < 0 give -(a_f . e_k) / c."""
    f, c = corners.shape
    incidence = sparse.csr_matrix(
        (np.ones(f * c), (corners.ravel(), np.repeat(np.arange(f), c))), shape=(n, f)
    )
    at = sparse.coo_matrix(incidence[np.asarray(vertices, dtype=int)])
    share = np.maximum(-np.einsum("ij,ij->i", area_vectors[at.col], directions[at.row]), 0.0) / c
    return np.bincount(at.row, share, minlength=len(vertices))
