"""Contact between two bodies' closed triangle surfaces: hard normal rows, Coulomb friction.

Each body gives its surface (``contact_surface() -> (points, triangles)``: a rigid body's
surface, an FEM or reduced body's exterior facets) whose point set
(:mod:`artifem.contact_points`) gives the vertices now and the rows of points on it
(``rows(W, e)``: a point sum_j W_kj x_j moved along e_k). The pairs are vertex
penetration pairs, both ways (ArtiSynth's vertex-penetration collider, the node-to-surface
pairs of two-pass FEM contact): each vertex x_v of one surface within ``margin`` of the
other, its signed distance s, closest point c = sum_i b_i y_i (b the barycentric
coordinates on the closest triangle's vertices y_i) and direction e out of the other
surface come from libigl's signed distance (``igl.signed_distance``, AABB tree, sign by
the angle-weighted pseudonormal; pinned):

    e = (x_v - c) / s   (|s| above 1e-3 tolerance: the face normal where c is inside a face,
                         along x_v - c at an edge or corner), else the pseudonormal at c;
    normal:    phi = e . (x_v - c) = s >= 0,   lambda_n in [0, inf),
    friction:  t_1, t_2 (the x and y axes of ``axis_rotation(e)``), phi = 0,
               -mu lambda_n <= lambda_t <= mu lambda_n   (when mu > 0),

with W = +1 on the vertex and -b_i on the triangle's vertices (each body's share in its
own rows: rigid G = [w e^T, (r x e)^T], r = sum_j W_kj R r_j the lever of the point,
w = +-1; FEM G = e^T W_kj on the nodes' dofs). The step's rows are those of
:mod:`~artifem.multibody.constraint_rows` (as a plane contact's: reach phi = 0 within the
step, pushed back by -beta phi / h once crossed); friction bounds take the same step's
normal impulses (``bounds_from``). A vertex inside the other body at any depth is found
(every vertex within the other's bounding box is queried): deeper than ``tolerance``
after a step fails the step (halved, like an inverted element), at the start it is an
InputError naming both bodies, the vertex and the triangle.

Checks: a surface must be closed and outward (an edge with one triangle, or a negative
enclosed volume, is an InputError naming the body). Not caught: two edges crossing with
no vertex of either surface inside the other (coarse meshes meeting edge on edge), and a
body that passes wholly through a thin one within one step; give a margin of at least the
largest approach speed times the step, as for a plane.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import igl
import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

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
    (+1: a holds the positive coefficients, the force on a is +lambda e) and tangents; the
    rows' keys are (side, vertex, triangle, direction: 0 normal, 1 t_1, 2 t_2)."""

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    side_a: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tangents: tuple = ()


def _barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(k, 3) barycentric coordinates of the points p (k, 3) in the triangles (a, b, c)."""
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (np.einsum("ij,ij->i", u, w) for u, w in ((v0, v0), (v0, v1), (v1, v1)))
    d20, d21 = np.einsum("ij,ij->i", v2, v0), np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    beta, gamma = (d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den
    return np.column_stack([1.0 - beta - gamma, beta, gamma])


class _Pairs(NamedTuple):
    """Vertex-penetration pairs: W (k x n_all) the coefficients (+1 on the vertex, -b_i on
    the triangle's), e (k, 3), phi (k,) the signed distances, and per pair (the body whose
    vertex it is (0: a, 1: b), that vertex, the other's triangle), all within the margin;
    ``deepest``: (phi, side, vertex, triangle) of the deepest vertex of all, or None; x
    (n_all, 3) the surfaces' vertices, a's then b's."""

    W: sparse.csr_matrix
    e: np.ndarray
    phi: np.ndarray
    which: np.ndarray
    deepest: tuple | None
    x: np.ndarray


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
        a, b: rigid bodies (with a ``surface``), full or reduced FEM bodies (their exterior
            facets).
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
        for body in (a, b):
            if not callable(getattr(body, "contact_surface", None)):
                raise InputError(f"{what}: {type(body).__name__} {body.name!r} has no contact "
                                 "surface (rigid bodies with a surface, full and reduced FEM "
                                 "bodies do)")
        (pa, ta), (pb, tb) = self._surfaces = (a.contact_surface(), b.contact_surface())
        xa, xb = pa.positions(), pb.positions()
        _check_closed(xa, ta, a.name)
        _check_closed(xb, tb, b.name)
        self._na = len(xa)

    @property
    def bodies(self) -> tuple:
        return (self.a, self.b)

    def onto_reduced(self, reduced, lift=None) -> MeshContact:
        """The same contact with the reduced body in place of the full body it replaces
        (the reductor: :mod:`artifem.reduction.reductor`)."""
        a, b = (reduced if getattr(reduced, "full", None) is body else body
                for body in (self.a, self.b))
        return MeshContact(a, b, mu=self.mu, tolerance=self.tolerance, margin=self.margin,
                           name=self.name)

    def _pairs(self) -> _Pairs:
        """The vertex-penetration pairs of the current state, both ways (module
        docstring)."""
        (pa, ta), (pb, tb) = self._surfaces
        xa, xb = pa.positions(), pb.positions()
        surfaces, offsets = ((xa, ta), (xb, tb)), (0, len(xa))
        n = len(xa) + len(xb)
        rows, cols, vals, dirs, phis, which = [], [], [], [], [], []
        deepest = None
        for side in (0, 1):
            (xp, _), (xq, tq) = surfaces[side], surfaces[1 - side]
            lo, hi = xq.min(axis=0) - self.margin, xq.max(axis=0) + self.margin
            near = np.flatnonzero(np.all((xp >= lo) & (xp <= hi), axis=1))
            if not near.size:
                continue
            S, I, C, N = igl.signed_distance(xp[near], xq, tq.astype(np.int64),
                                             sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
            j = int(np.argmin(S))
            if deepest is None or S[j] < deepest[0]:
                deepest = (float(S[j]), side, int(near[j]), int(I[j]))
            keep = S < self.margin
            if not np.any(keep):
                continue
            v, f, s, c, pn = near[keep], I[keep], S[keep], C[keep], N[keep]
            d = xp[v] - c
            small = np.abs(s) <= 1e-3 * self.tolerance
            e = np.where(small[:, None], pn / np.linalg.norm(pn, axis=1, keepdims=True),
                         d / np.where(small, 1.0, s)[:, None])
            extra = self._face_pairs(xp, v, f, xq, tq)
            v, f = np.r_[v, extra[0]], np.r_[f, extra[1]]
            s, c, e = np.r_[s, extra[2]], np.vstack([c, extra[3]]), np.vstack([e, extra[4]])
            tri = tq[f]
            bary = _barycentric(c, xq[tri[:, 0]], xq[tri[:, 1]], xq[tri[:, 2]])
            k0 = sum(len(q) for q in phis)
            k = np.arange(k0, k0 + len(v))
            rows += [k, np.repeat(k, 3)]
            cols += [offsets[side] + v, offsets[1 - side] + tri.ravel()]
            vals += [np.ones(len(v)), -bary.ravel()]
            dirs.append(e)
            phis.append(s)
            which.append(np.column_stack([np.full(len(v), side), v, f]))
        if not phis:
            return _Pairs(sparse.csr_matrix((0, n)), np.zeros((0, 3)), np.zeros(0),
                          np.zeros((0, 3), int), deepest, np.vstack([xa, xb]))
        phi = np.concatenate(phis)
        W = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                      np.concatenate(cols))), shape=(len(phi), n))
        return _Pairs(W, np.vstack(dirs), phi, np.vstack(which), deepest,
                      np.vstack([xa, xb]))

    def _face_pairs(self, xp, vertices, closest, xq, tq):
        """The other faces a vertex is over: for each of ``vertices`` (closest triangle
        ``closest``), every triangle f of (xq, tq) whose plane it is within ``margin`` above
        (-tolerance <= s_f = n_f . (x_v - y_f) < margin) and onto whose interior it projects,
        c = x_v - s_f n_f. A vertex sliding across a concave edge (a bowl's facets) meets the
        next facet within the step; with its row only for the closest facet it would cross
        it by about h v sin(angle between the facets). Candidates from a k-d tree of the
        triangles' centroids (scipy). Returns (vertex, triangle, s, c, e = n_f)."""
        empty = (np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros((0, 3)),
                 np.zeros((0, 3)))
        if not len(vertices):
            return empty
        y = xq[tq]
        centroids = y.mean(axis=1)
        reach = np.linalg.norm(y - centroids[:, None], axis=2).max() + self.margin
        lists = cKDTree(centroids).query_ball_point(xp[vertices], reach)
        v = np.repeat(vertices, [len(q) for q in lists])
        f = np.fromiter((t for q in lists for t in q), dtype=int, count=len(v))
        other = f != np.repeat(closest, [len(q) for q in lists])
        v, f = v[other], f[other]
        n = np.cross(y[f, 1] - y[f, 0], y[f, 2] - y[f, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        s = np.einsum("ij,ij->i", xp[v] - y[f, 0], n)
        c = xp[v] - s[:, None] * n
        bary = _barycentric(c, y[f, 0], y[f, 1], y[f, 2])
        keep = (s >= -self.tolerance) & (s < self.margin) & np.all(bary >= -1e-12, axis=1)
        return v[keep], f[keep], s[keep], c[keep], n[keep]

    def _describe(self, side: int, vertex: int, triangle: int) -> str:
        """Vertex ``vertex`` of one body's surface and the other's triangle."""
        bodies = (self.a, self.b)
        return (f"vertex {vertex} of {bodies[side].name!r} and triangle {triangle} of "
                f"{bodies[1 - side].name!r}")

    def row_blocks(self) -> list[RowBlock]:
        """One block: the normal rows and, with mu > 0, the friction rows of the pairs
        within ``margin``; none when no pair is that close."""
        pairs = self._pairs()
        W, e, phi, x = pairs.W, pairs.e, pairs.phi, pairs.x
        (pa, _), (pb, _) = self._surfaces
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
            return sparse.block_diag([sparse.csr_matrix(pa.stiffness(Wa, f)),
                                      sparse.csr_matrix(pb.stiffness(Wb, f))],
                                     format="csr")

        side_a = np.asarray(W[:, :na].sum(axis=1)).ravel()
        return [MeshContactRows(
            self, np.concatenate([phi, np.zeros(m - k)]),
            ((self.a, pa.rows(Wa, directions)), (self.b, pb.rows(Wb, directions))),
            lo, hi, stiffness, friction_bounds if mu > 0 else None,
            np.column_stack([np.tile(pairs.which, (m // k, 1)), np.repeat(np.arange(m // k), k)]),
            points=(W[:, na:] @ x[na:]) / -side_a[:, None], normals=e, side_a=side_a,
            tangents=(bases[:, :, 0], bases[:, :, 1]) if mu > 0 else ())]

    def constraint_failure(self) -> str | None:
        """A vertex of either surface deeper than ``tolerance`` inside the other, if any."""
        deepest = self._pairs().deepest
        if deepest is None or deepest[0] >= -self.tolerance:
            return None
        depth, side, vertex, triangle = deepest
        return (f"contact {self.name!r}: {self._describe(side, vertex, triangle)}: the vertex "
                f"is {-depth:.3g} inside (the tolerance is {self.tolerance:g}; a vertex that "
                f"comes from beyond the margin {self.margin:g} within one step has no row: "
                "the margin should be at least the largest approach speed times the step)")

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
