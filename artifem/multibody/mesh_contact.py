"""Contact between two bodies' closed triangle surfaces: hard normal rows, Coulomb friction.

Each body gives its surface (``contact_surface() -> (x, triangles)``: a rigid body's
surface at its pose, an FEM body's exterior facets at x = X + u) and the rows of points on
it (``point_rows(W, e)``: a point sum_j W_kj x_j moved along e_k). The IPC Toolkit
(``ipctk``, pinned) finds the pairs of the two surfaces within ``margin`` (its BVH broad
phase and its vertex-face, edge-edge, edge-vertex and vertex-vertex stencils, the pairs
within one body filtered out): each pair's closest points are x_1 = sum_i c_i x_i over its
positive coefficients and x_2 over its negative ones, d = sum_i c_i x_i = x_1 - x_2. One
block of rows per step:

    normal:    phi = e . d >= 0,   lambda_n in [0, inf),
    friction:  t_1, t_2 (the x and y axes of ``axis_rotation(e)``), phi = 0,
               -mu lambda_n <= lambda_t <= mu lambda_n   (when mu > 0),

with W_kj = c_i on the stencil's vertices (each body's share in its own rows: rigid
G = [w e^T, (r x e)^T], r = sum_j W_kj R r_j the lever of the closest point, w = +-1;
FEM G = e^T W_kj on the nodes' dofs). The direction e points from x_2 to x_1, from
the surfaces' outward normals so that it stays defined at contact (d = 0) and phi is
signed (negative: crossed):

    vertex-face (the closest point inside the face): e = its outward unit normal;
    edge-edge (closest points inside both, not parallel): e = +-(a x b) / |a x b| (a, b the edges), the sign along
                  m_2 - m_1 (m the stencil's vertex normals, weighted by |c_i|);
    otherwise:    e = d / |d| (phi = |d|), or (m_2 - m_1) normalized when |d| is below
                  1e-3 tolerance.

The step's rows are those of :mod:`~artifem.multibody.constraint_rows` (as a plane
contact's: reach phi = 0 within the step, pushed back by -beta phi / h once crossed);
friction bounds take the same step's normal impulses (``bounds_from``).

Checks: a surface must be closed and outward (an edge with one triangle, or a negative
enclosed volume, is an InputError naming the body). After a step (and at the start, an
InputError then) a pair deeper than ``tolerance`` (phi < -tolerance) fails the step, and
so do surfaces that pass through each other: each surface pulled in by tolerance / 2
along its vertex normals, an edge of one through a triangle of the other (ipctk's
edge-triangle test on its candidates) is a failure naming both bodies and the two
elements. Not checked: a body that passes wholly through the other within one step
(no continuous collision detection: at resting contact, d = 0, ipctk's CCD reports a
collision on every step); give a margin of at least the largest approach speed times
the step, as for a plane.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import ipctk
import numpy as np
from scipy import sparse

from artifem.errors import InputError
from artifem.multibody.constraint_rows import RowBlock
from artifem.multibody.joints import axis_rotation

__all__ = ["MeshContact", "MeshContactForces"]


class MeshContactForces(NamedTuple):
    """The forces of a :class:`MeshContact` over the last step (lambda / h), on body a.

    points: (k, 3) the contact points (world: the closest point on b of each pair);
    normal: (k,) the normal forces (N, >= 0); directions: (k, 3) their unit directions
    on a; friction: (k, 3) the friction forces on a (world, N). b takes the opposite.
    """

    points: np.ndarray
    normal: np.ndarray
    directions: np.ndarray
    friction: np.ndarray

    @property
    def resultant(self) -> np.ndarray:
        """The total force of b on a (N)."""
        return self.normal @ self.directions + self.friction.sum(axis=0)


@dataclass(frozen=True, eq=False)
class MeshContactRows(RowBlock):
    """A :class:`MeshContact`'s rows: k normal rows, then k along t_1 and k along t_2
    (with friction); per pair its contact point on b, normal e, the sign of a's share
    (+1: a holds the positive coefficients, the force on a is +lambda e) and tangents."""

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    side_a: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tangents: tuple = ()


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _vertex_normals(x: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Area-weighted unit normals of the vertices of an outward triangle surface."""
    n = np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]])
    out = np.zeros_like(x)
    for k in range(3):
        np.add.at(out, tris[:, k], n)
    return _unit(out)


def _check_closed(x: np.ndarray, tris: np.ndarray, name: str) -> None:
    """Every edge in two triangles, the enclosed volume positive: else an InputError."""
    edges = np.sort(np.vstack([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    if np.any(counts != 2):
        e = unique[counts != 2][0]
        raise InputError(f"mesh contact: the surface of {name!r} is not closed: "
                         f"{int(np.sum(counts != 2))} edges not shared by exactly two triangles, "
                         f"e.g. vertices ({e[0]}, {e[1]}) (contact needs a closed surface)")
    a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
    if np.einsum("ij,ij->", a, np.cross(b, c)) <= 0:
        raise InputError(f"mesh contact: the surface of {name!r} encloses a non-positive "
                         "volume: its triangles must be oriented outward")


class MeshContact:
    """Contact between the closed surfaces of bodies a and b (module docstring).

    Args:
        a, b: rigid bodies (with a ``surface``) or full FEM bodies (their exterior facets).
        mu: the Coulomb friction coefficient (>= 0; 0: no friction rows).
        tolerance: the penetration allowed (m): deeper fails a step, or the start.
        margin: pairs closer than this (m) get rows.
        name: used in errors.
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "contacts"

    def __init__(self, a, b, *, mu: float = 0.0, tolerance: float = 1e-5,
                 margin: float = 1e-2, name: str = ""):
        self.name = name or f"contact of {a.name!r} and {b.name!r}"
        what = f"contact {self.name!r}"
        if a is b:
            raise InputError(f"{what}: a body against itself (self-contact) is not supported")
        if not (np.isfinite(mu) and mu >= 0):
            raise InputError(f"{what}: the friction coefficient mu must be >= 0, got {mu!r}")
        if not (np.isfinite(tolerance) and tolerance > 0):
            raise InputError(f"{what}: tolerance must be > 0, got {tolerance!r}")
        if not (np.isfinite(margin) and margin > tolerance):
            raise InputError(f"{what}: margin must be finite and > tolerance ({tolerance:g}), "
                             f"got {margin!r}")
        self.a, self.b = a, b
        self.mu, self.tolerance, self.margin = float(mu), float(tolerance), float(margin)
        xa, ta = a.contact_surface()
        xb, tb = b.contact_surface()
        _check_closed(xa, ta, a.name)
        _check_closed(xb, tb, b.name)
        self._na = len(xa)
        self._tris = np.vstack([ta, tb + self._na]).astype(np.int32)
        self._owner = np.r_[np.zeros(len(xa), int), np.ones(len(xb), int)]
        self._mesh = ipctk.CollisionMesh(np.vstack([xa, xb]), ipctk.edges(self._tris),
                                         self._tris)
        self._mesh.can_collide = ipctk.make_connected_components_filter(self._tris)

    @property
    def bodies(self) -> tuple:
        return (self.a, self.b)

    def _positions(self) -> np.ndarray:
        return np.vstack([self.a.contact_surface()[0], self.b.contact_surface()[0]])

    def _pairs(self, x: np.ndarray):
        """(W (k x n) coefficients, e (k, 3), phi (k,), descriptions) of the pairs of a and
        b within ``margin`` (module docstring)."""
        mesh, tris = self._mesh, self._tris
        edges = mesh.edges
        collisions = ipctk.NormalCollisions()
        collisions.build(mesh, x, self.margin)
        normals = _vertex_normals(x, tris)
        rows, cols, vals, dirs, phis, names = [], [], [], [], [], []
        for i in range(len(collisions)):
            c = collisions[i]
            ids = np.array(c.vertex_ids(edges, tris))
            ids = ids[ids >= 0]
            coef = np.asarray(c.compute_coefficients(c.dof(x, edges, tris))).ravel()[:len(ids)]
            if np.all(self._owner[ids] == self._owner[ids[0]]):
                continue                        # within one body
            d = coef @ x[ids]
            m = coef @ normals[ids]                 # m_1 - m_2
            interior = len(ids) == 4 and np.all(np.abs(coef) > 1e-12)
            e = None
            if interior and isinstance(c, ipctk.FaceVertexNormalCollision):
                f = tris[c.face_id]
                e = _unit(np.cross(x[f[1]] - x[f[0]], x[f[2]] - x[f[0]]))
            elif interior:                          # edge-edge, both closest points inside
                axb = np.cross(x[ids[1]] - x[ids[0]], x[ids[3]] - x[ids[2]])
                if np.linalg.norm(axb) > 1e-6 * np.linalg.norm(x[ids[1]] - x[ids[0]]) \
                        * np.linalg.norm(x[ids[3]] - x[ids[2]]):
                    e = _unit(axb) * (-1.0 if axb @ m > 0 else 1.0)
            if e is None:
                dist = np.linalg.norm(d)
                e = d / dist if dist > 1e-3 * self.tolerance else _unit(-m)
            k = len(dirs)
            rows += [k] * len(ids)
            cols += ids.tolist()
            vals += coef.tolist()
            dirs.append(e)
            phis.append(e @ d)
            names.append(self._describe(ids))
        W = sparse.csr_matrix((vals, (rows, cols)), shape=(len(dirs), len(x)))
        return W, np.reshape(dirs, (-1, 3)), np.array(phis), names

    def _describe(self, ids: np.ndarray) -> str:
        """The stencil's vertices, per body (surface vertex indices)."""
        parts = []
        for body, k in ((self.a, 0), (self.b, 1)):
            mine = ids[self._owner[ids] == k] - (self._na if k else 0)
            if mine.size:
                parts.append(f"vertices {mine.tolist()} of {body.name!r}")
        return " and ".join(parts)

    def row_blocks(self) -> list[RowBlock]:
        """One block: the normal rows and, with mu > 0, the friction rows of the pairs
        within ``margin``; none when no pair is that close."""
        x = self._positions()
        W, e, phi, _ = self._pairs(x)
        k = len(phi)
        if not k:
            return []
        bases = np.array([axis_rotation(n) for n in e]) if self.mu > 0 else None
        directions = np.vstack([e] + ([bases[:, :, 0], bases[:, :, 1]] if self.mu > 0 else []))
        Wall = sparse.vstack([W] * (len(directions) // k)).tocsr()
        m = len(directions)
        na = self._na
        Wa, Wb = Wall[:, :na], Wall[:, na:]
        lo, hi = np.zeros(m), np.zeros(m)
        hi[:k] = np.inf
        mu = self.mu

        def friction_bounds(lam):
            """|lambda_t| <= mu lambda_n on both tangent rows of each pair."""
            cap = np.tile(mu * np.maximum(lam[:k], 0.0), 2)
            return np.concatenate([np.zeros(k), -cap]), np.concatenate([np.full(k, np.inf), cap])

        def stiffness(lam):
            f = lam[:, None] * directions
            return sparse.block_diag([sparse.csr_matrix(self.a.point_stiffness(Wa, f)),
                                      sparse.csr_matrix(self.b.point_stiffness(Wb, f))],
                                     format="csr")

        side_a = np.asarray(W[:, :na].sum(axis=1)).ravel()
        return [MeshContactRows(
            self, np.concatenate([phi, np.zeros(m - k)]),
            ((self.a, self.a.point_rows(Wa, directions)),
             (self.b, self.b.point_rows(Wb, directions))),
            lo, hi, stiffness, friction_bounds if mu > 0 else None,
            points=(W[:, na:] @ x[na:]) / -side_a[:, None], normals=e, side_a=side_a,
            tangents=(bases[:, :, 0], bases[:, :, 1]) if mu > 0 else ())]

    def constraint_failure(self) -> str | None:
        """A pair deeper than ``tolerance``, or surfaces through each other (module
        docstring), if any."""
        x = self._positions()
        _, _, phi, names = self._pairs(x)
        if phi.size and phi.min() < -self.tolerance:
            i = int(np.argmin(phi))
            return (f"contact {self.name!r}: {names[i]} are {-phi[i]:.3g} deep (the "
                    f"tolerance is {self.tolerance:g}; a pair that comes from beyond the "
                    f"margin {self.margin:g} within one step has no row: the margin should be "
                    "at least the largest approach speed times the step)")
        shrunk = x - 0.5 * self.tolerance * _vertex_normals(x, self._tris)
        if not ipctk.has_intersections(self._mesh, shrunk):
            return None
        for ei, fi in _edges_through_triangles(self._mesh.edges, self._tris, shrunk,
                                               self._owner):
            return (f"contact {self.name!r}: the surfaces of {self.a.name!r} and "
                    f"{self.b.name!r} pass through each other (by more than the tolerance "
                    f"{self.tolerance:g}): the edge of {self._describe(self._mesh.edges[ei])} "
                    f"through the triangle of {self._describe(self._tris[fi])}")
        return None

    def forces(self, parts: list, h: float) -> MeshContactForces:
        """The forces of the impulses ``parts`` [(block, lambda)] of a step of size h."""
        if not parts:
            return MeshContactForces(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)),
                                     np.zeros((0, 3)))
        (block, lam), = parts
        k = len(block.points)
        side = block.side_a[:, None]
        friction = np.zeros((k, 3))
        if self.mu > 0:
            friction = side * (lam[k:2 * k, None] * block.tangents[0]
                               + lam[2 * k:, None] * block.tangents[1]) / h
        return MeshContactForces(block.points, lam[:k] / h, side * block.normals, friction)


def _edges_through_triangles(edges: np.ndarray, tris: np.ndarray, x: np.ndarray,
                             owner: np.ndarray):
    """(edge, triangle) pairs of different bodies where the edge crosses the triangle
    (bounding boxes first, then ipctk's exact edge-triangle test)."""
    for k in (0, 1):
        E = edges[owner[edges[:, 0]] == k]
        eid = np.flatnonzero(owner[edges[:, 0]] == k)
        fid = np.flatnonzero(owner[tris[:, 0]] != k)
        elo, ehi = np.minimum(x[E[:, 0]], x[E[:, 1]]), np.maximum(x[E[:, 0]], x[E[:, 1]])
        tx = x[tris[fid]]
        tlo, thi = tx.min(axis=1), tx.max(axis=1)
        for i in range(len(E)):
            hit = np.flatnonzero(np.all((elo[i] <= thi) & (tlo <= ehi[i]), axis=1))
            for j in hit:
                t = tris[fid[j]]
                if ipctk.is_edge_intersecting_triangle(x[E[i, 0]], x[E[i, 1]], x[t[0]],
                                                       x[t[1]], x[t[2]]):
                    yield eid[i], fid[j]
