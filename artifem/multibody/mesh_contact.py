"""Contact between two bodies' closed triangle surfaces: hard normal rows, Coulomb friction.

Each body gives its surface (``contact_surface() -> (points, triangles)``: a rigid body's
surface, an FEM or reduced body's exterior facets) whose point set
(:mod:`artifem.contact_points`) gives the vertices now and the rows of points on it
(``rows(W, e)``: a point sum_j W_kj x_j moved along e_k). Each step's pairs, within
``margin``:

- vertex over triangle, both ways (ArtiSynth's vertex-penetration collider, the two-pass
  node-to-surface pairs of FEM contact): a vertex x_v of one surface and a triangle of the
  other that it projects into and faces, c = sum_i b_i y_i its foot (barycentric b_i),
  e the triangle's normal, phi = e . (x_v - c); a vertex over no such triangle takes its
  closest point's pair from libigl's AABB tree (pinned), signed by the pseudonormal of
  its closest feature (as ``igl.signed_distance``), e = (x_v - c) / s, or the
  pseudonormal at contact;
- edge across edge, between sharp convex edges (two boxes turned against each other meet
  edge on edge with no vertex of either over the other): the closest points p_a, p_b
  inside both edges, e = +-(u x v) / |u x v| out of b, phi = e . (p_a - p_b);

and, with an ``offset`` d (a layer of that thickness between the surfaces: a joint's
cartilage), phi minus d for every pair (the surfaces meet d apart); one block of rows per
step:

    normal:    phi >= 0,   lambda_n in [0, inf),
    friction:  t_1, t_2 (the x and y axes of ``axis_rotation(e)``), phi = 0,
               -mu lambda_n <= lambda_t <= mu lambda_n   (when mu > 0),

with W the pair's coefficients on the surfaces' vertices (+1 on a vertex and -b_i on the
triangle's; 1 - s, s on a's edge and -(1 - t), -t on b's), summing to zero over each pair
(equal and opposite impulses). Each body's share is its own rows (rigid G = [w e^T,
(r x e)^T], r = sum_j W_kj R r_j the lever of the point, w = +-1; FEM G = e^T W_kj on the
nodes' dofs; reduced e^T W_kj U_j). The step's rows are those of
:mod:`~artifem.multibody.constraint_rows` (as a plane contact's: reach phi = 0 within the
step, pushed back by -beta phi / h once crossed); friction bounds take the same step's
normal impulses (``RowBlock.friction``). The queries run in the other surface's frame:
a rigid body's surface keeps its tree, normals and sharp edges in its body frame, built
once; a deformable one's are built in the world at each new state. A vertex inside the
other body at any depth is found (every vertex within the other's bounding box is
queried), and so are crossed sharp edges
within the margin: deeper than ``tolerance`` after a step fails the step (halved, like an
inverted element), at the start it is an InputError naming both bodies and the pair.

Checks: a surface must be closed and outward (an edge with one triangle, or a negative
enclosed volume, is an InputError naming the body). Not caught: a body that passes wholly
through a thin one within one step (no continuous collision detection); give a margin of
at least the largest approach speed times the step, as for a plane.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import igl
import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from artifem.errors import InputError
from artifem.multibody.constraint_rows import Friction, RowBlock
from artifem.multibody.contact import check_options
from artifem.multibody.distance_hessian import distance_hessians
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
    weights: object = None  # W (k x n_all) of the normal rows


def _barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(k, 3) barycentric coordinates of the points p (k, 3) in the triangles (a, b, c)."""
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (np.einsum("ij,ij->i", u, w) for u, w in ((v0, v0), (v0, v1), (v1, v1)))
    d20, d21 = np.einsum("ij,ij->i", v2, v0), np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    beta, gamma = (d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den
    return np.column_stack([1.0 - beta - gamma, beta, gamma])


#: the spans of a vertex-over-triangle pair (columns: the vertex, then the triangle's
#: three): its sides y1 - y0 and y2 - y0; of two edges (a0, a1, b0, b1): a1 - a0, b1 - b0
_FACE_SPANS = np.array([[0.0, -1.0, 1.0, 0.0], [0.0, -1.0, 0.0, 1.0]])
_EDGE_SPANS = np.array([[-1.0, 1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 1.0]])


def _feature_spans(b: np.ndarray, pseudo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((k, 2, 4) spans, (k,) their count) of closest-point pairs (columns: the vertex,
    then the triangle's three) from the closest point's barycentric coordinates ``b``
    (k, 3): the triangle (none zero), the edge of the two nonzero ones, or none (a
    vertex: two zero); -1 where e is the pseudonormal (``pseudo``)."""
    zero = b <= 1e-10
    count = 2 - np.minimum(zero.sum(axis=1), 2)
    spans = np.broadcast_to(_FACE_SPANS, (len(b), 2, 4)).copy()
    edge = np.flatnonzero(count == 1)
    if edge.size:
        corners = np.argsort(zero[edge], axis=1, kind="stable")[:, :2]  # the nonzero two
        spans[edge] = 0.0
        spans[edge, 0, 1 + corners[:, 0]] = -1.0
        spans[edge, 0, 1 + corners[:, 1]] = 1.0
    return spans, np.where(pseudo, -1, count)


class _Pairs(NamedTuple):
    """The pairs within the margin: W (k x n_all) their coefficients on the surfaces'
    vertices (a's then b's; summing to zero over each pair), e (k, 3), phi (k,) the signed
    distances, which (k, 3) = (kind, i, j): kind 0 a's vertex i over b's triangle j, 1 b's
    vertex i over a's triangle j, 2 a's edge i across b's edge j; ``deepest``: (phi, kind,
    i, j) of the deepest penetration found (every vertex in the other's bounding box,
    every crossing edge pair), or None; x (n_all, 3) the vertices; cols, weights (k, 4):
    W's four entries of each pair; spans (k, 2, 4) and their count (k,): the features'
    directions on those columns (:func:`~artifem.multibody.distance_hessian.distance_hessians`;
    -1: a pair whose e is a pseudonormal, which does not turn with its points)."""

    W: sparse.csr_matrix
    e: np.ndarray
    phi: np.ndarray
    which: np.ndarray
    deepest: tuple | None
    x: np.ndarray
    cols: np.ndarray
    weights: np.ndarray
    spans: np.ndarray
    span_count: np.ndarray


def _held_pairs(held: _Pairs, x: np.ndarray) -> tuple:
    """The vertex pairs of ``held`` (which kinds 0, 1) at the vertices ``x`` (n_all, 3),
    each on its own feature, as :meth:`MeshContact._vertex_pairs` gives them (cols,
    weights, e, the distance before the offset, which, spans, count): a triangle's pair
    e = n_f, c = x_v - s n_f (b_i of c unclamped); an edge's c = the vertex's projection
    onto the edge's line and a vertex's c = it, e = (x_v - c) / s signed as the held e
    (the held e where |x_v - c| vanishes); a pseudonormal's pair keeps e and b_i."""
    on = held.which[:, 0] < 2
    cols, weights, e = held.cols[on], held.weights[on].copy(), held.e[on].copy()
    spans, count = held.spans[on], held.span_count[on]
    xv, y = x[cols[:, 0]], x[cols[:, 1:]]
    bary = -weights[:, 1:]
    face = count == 2
    if face.any():
        y0, y1, y2 = y[face, 0], y[face, 1], y[face, 2]
        n = _unit(np.cross(y1 - y0, y2 - y0))
        s = np.einsum("ij,ij->i", xv[face] - y0, n)
        bary[face] = _barycentric(xv[face] - s[:, None] * n, y0, y1, y2)
        e[face] = n
    line = count == 1
    if line.any():  # the span's -1 and +1 corners: the edge p -> q
        p, q = np.argmin(spans[line, 0, 1:], axis=1), np.argmax(spans[line, 0, 1:], axis=1)
        rows = np.arange(line.sum())
        yp, yq = y[line][rows, p], y[line][rows, q]
        t = np.einsum("ij,ij->i", xv[line] - yp, yq - yp) / np.einsum("ij,ij->i", yq - yp, yq - yp)
        b = np.zeros((len(rows), 3))
        b[rows, p], b[rows, q] = 1.0 - t, t
        bary[line] = b
    c = np.einsum("kj,kji->ki", bary, y)
    turn = (count == 1) | (count == 0)
    d = xv - c
    dist = np.linalg.norm(d, axis=1)
    turn &= dist > 0.0
    e[turn] = (
        d[turn]
        / dist[turn, None]
        * np.where(np.einsum("ij,ij->i", d[turn], e[turn]) < 0, -1.0, 1.0)[:, None]
    )
    weights[:, 1:] = -bary
    return (cols, weights, e, np.einsum("ij,ij->i", e, d), held.which[on], spans, count)


def _no_pairs() -> tuple:
    """The pair arrays of ``MeshContact._vertex_pairs`` and ``_edge_pairs`` when no pair
    is near: (cols, weights, e, phi, which, spans, count) with no rows."""
    return (
        np.zeros((0, 4), int),
        np.zeros((0, 4)),
        np.zeros((0, 3)),
        np.zeros(0),
        np.zeros((0, 3), int),
        np.zeros((0, 2, 4)),
        np.zeros(0, int),
    )


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


def _face_normals(x: np.ndarray, tris: np.ndarray) -> np.ndarray:
    return _unit(np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]]))


def _vertex_normals(x: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Area-weighted unit normals of the vertices of an outward triangle surface."""
    n = np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]])
    out = np.zeros_like(x)
    for k in range(3):
        np.add.at(out, tris[:, k], n)
    return _unit(out)


def _edges(tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(edges (m, 2) vertex pairs, the two triangles of each (m, 2)) of a closed surface."""
    half = np.vstack([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    face = np.tile(np.arange(len(tris)), 3)
    key = np.sort(half, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, face = key[order], face[order]
    return key[::2], np.column_stack([face[::2], face[1::2]])


#: An edge is sharp, and meets the other surface's sharp edges edge on edge, where its two
#: triangles' normals differ by more than this angle and it is convex (a ridge).
SHARP_ANGLE = np.radians(30.0)


def _sharp(
    x: np.ndarray, tris: np.ndarray, edges: np.ndarray, faces: np.ndarray, normals: np.ndarray
) -> np.ndarray:
    """(m,) bool: the convex edges whose triangles' normals differ by more than
    :data:`SHARP_ANGLE` (a box's edges; not the facets of a smooth surface, whose crossing
    edges leave vertices of one over triangles of the other, nor a split quadrilateral's
    diagonal)."""
    n0, n1 = normals[faces[:, 0]], normals[faces[:, 1]]
    # the vertex of the second triangle off the edge, below the first's plane: a ridge
    t1 = tris[faces[:, 1]]
    off = np.where(t1 != edges[:, [0]], t1, -1)
    off = np.where(off != edges[:, [1]], off, -1).max(axis=1)
    convex = np.einsum("ij,ij->i", x[off] - x[edges[:, 0]], n0) < 0
    return convex & (np.einsum("ij,ij->i", n0, n1) < np.cos(SHARP_ANGLE))


def _close_pairs(p: np.ndarray, q: cKDTree, r: float) -> tuple[np.ndarray, np.ndarray]:
    """(i, j): every pair of points p_i, q_j (given by their KD-tree) closer than r,
    ordered by i then j (scipy's KD-trees, the pairs gathered in C)."""
    d = cKDTree(p).sparse_distance_matrix(q, r, output_type="ndarray")
    order = np.lexsort((d["j"], d["i"]))
    return d["i"][order].astype(int), d["j"][order].astype(int)


class _Geometry(NamedTuple):
    """A surface in a frame where it is at rest (a rigid body's: built once; a deformable
    body's: the world, built for each query): its vertices and triangles, unit face
    normals, area-weighted vertex normals, its sharp edges (:func:`_sharp`), libigl's AABB
    tree, the pseudonormals of Baerentzen and Aanaes (2005: a vertex's angle-weighted, an
    edge's the mean of its two faces', as ``igl.signed_distance`` takes them; ``emap``
    maps the edge opposite corner c of triangle f, c * n_triangles + f, to its row of
    ``edge_normals``), the triangles' centroids' KD-tree and its reach (the largest
    centroid-to-vertex distance), and the bounding box."""

    x: np.ndarray
    tris: np.ndarray
    face_normals: np.ndarray
    vertex_normals: np.ndarray
    sharp: np.ndarray
    tree: object
    vertex_pseudonormals: np.ndarray
    edge_normals: np.ndarray
    emap: np.ndarray
    centroids: cKDTree
    reach: float
    box: tuple


def _geometry(x: np.ndarray, tris: np.ndarray, edges) -> _Geometry:
    """The :class:`_Geometry` of vertices ``x`` (in their frame), ``tris`` (int64) and
    ``edges`` (:func:`_edges`)."""
    tree = igl.AABB()
    tree.init(x, tris)
    normals = _face_normals(x, tris)
    edge_normals, _, emap = igl.per_edge_normals(
        x, tris, igl.PER_EDGE_NORMALS_WEIGHTING_TYPE_UNIFORM
    )
    y = x[tris]
    centroids = y.mean(axis=1)
    return _Geometry(
        x,
        tris,
        normals,
        _vertex_normals(x, tris),
        _sharp(x, tris, edges[0], edges[1], normals),
        tree,
        igl.per_vertex_normals(x, tris, igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_ANGLE),
        edge_normals,
        emap,
        cKDTree(centroids),
        float(np.linalg.norm(y - centroids[:, None], axis=2).max()),
        (x.min(axis=0), x.max(axis=0)),
    )


def _signed_distance(g: _Geometry, points: np.ndarray):
    """(S, I, C, N) of ``igl.signed_distance`` with pseudonormal signs, on the prebuilt
    tree of ``g`` (libigl's Python bindings take no tree there, and building one per
    query was half the contact's time on the foot's bones): S the signed distances, I
    the closest triangles, C the closest points, N the pseudonormals of the closest
    features (the triangle's normal, its edge's or its vertex's, by which barycentric
    coordinates of C vanish), S < 0 inside."""
    sq, I, C = g.tree.squared_distance(g.x, g.tris, points)
    tri = g.tris[I]
    corners = g.x[tri]
    b = _barycentric(C, corners[:, 0], corners[:, 1], corners[:, 2])
    zero = b <= 1e-10
    count = zero.sum(axis=1)
    N = g.face_normals[I].copy()
    edge = np.flatnonzero(count == 1)
    if edge.size:
        corner = np.argmax(zero[edge], axis=1)
        N[edge] = g.edge_normals[g.emap[corner * len(g.tris) + I[edge]]]
    vertex = np.flatnonzero(count >= 2)
    if vertex.size:
        corner = np.argmin(zero[vertex], axis=1)
        N[vertex] = g.vertex_pseudonormals[tri[vertex, corner]]
    S = np.sqrt(np.maximum(sq, 0.0))
    S = np.where(np.einsum("ij,ij->i", points - C, N) < 0, -S, S)
    return S, I, C, N


def _segment_closest(a0, a1, b0, b1):
    """(s, t) of the closest points a0 + s (a1 - a0), b0 + t (b1 - b0) of the lines through
    the segments (not clamped; NaN for parallel ones)."""
    u, v, w = a1 - a0, b1 - b0, a0 - b0
    uu, uv, vv = (np.einsum("ij,ij->i", p, q) for p, q in ((u, u), (u, v), (v, v)))
    uw, vw = np.einsum("ij,ij->i", u, w), np.einsum("ij,ij->i", v, w)
    den = uu * vv - uv * uv
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(den > 1e-12 * uu * vv, (uv * vw - vv * uw) / den, np.nan)
        t = np.where(den > 1e-12 * uu * vv, (uu * vw - uv * uw) / den, np.nan)
    return s, t


def _check_closed(x: np.ndarray, tris: np.ndarray, name: str) -> None:
    """Every edge in two triangles, the enclosed volume positive: else an InputError."""
    edges = np.sort(np.vstack([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    if np.any(counts != 2):
        e = unique[counts != 2][0]
        raise InputError(
            f"mesh contact: the surface of {name!r} is not closed: "
            f"{int(np.sum(counts != 2))} edges not shared by exactly two triangles, "
            f"e.g. vertices ({e[0]}, {e[1]}) (contact needs a closed surface)"
        )
    a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
    if np.einsum("ij,ij->", a, np.cross(b, c)) <= 0:
        raise InputError(
            f"mesh contact: the surface of {name!r} encloses a non-positive "
            "volume: its triangles must be oriented outward"
        )


class MeshContact:
    """Contact between the closed surfaces of bodies a and b (module docstring).

    Args:
        a, b: rigid bodies (with a ``surface``), full or reduced FEM bodies (their exterior
            facets), or triangle meshes embedded in an FEM body (:class:`EmbeddedMesh`: a
            bone or an organ's surface in a coarse grid; the rows act on its master).
        mu: the Coulomb friction coefficient (>= 0; 0: no friction rows).
        tolerance: the penetration allowed (m): deeper fails a step, or the start.
        margin: pairs closer than this (m) beyond ``offset`` get rows.
        offset: the distance (m) at which the surfaces meet, >= 0: a layer of this
            thickness between them that the bodies' surfaces do not show (the cartilage
            that fills a joint's space between two bone meshes); every pair's phi is its
            distance minus ``offset``, and ``tolerance`` and ``margin`` count from there.
        name: used in errors.
        foundation: None (hard normal rows), or an
            :class:`~artifem.multibody.foundation.ElasticFoundation`: compliant normal rows
            of the vertex-over-triangle pairs (C = t / (K A), A the facing area of the
            vertex on its own surface), edge-across-edge rows hard; penetration allowed up
            to max(tolerance, t).
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "contacts"

    def __init__(
        self,
        a,
        b,
        *,
        mu: float = 0.0,
        tolerance: float = 1e-5,
        margin: float = 1e-2,
        offset: float = 0.0,
        name: str = "",
        foundation=None,
    ):
        self.name = name or f"contact of {a.name!r} and {b.name!r}"
        what = f"contact {self.name!r}"
        if a is b:
            raise InputError(f"{what}: a body against itself (self-contact) is not supported")
        check_options(what, mu, tolerance, margin)
        if not (np.isfinite(offset) and offset >= 0):
            raise InputError(f"{what}: offset must be finite and >= 0, got {offset}")
        self.a, self.b = a, b
        self.mu, self.tolerance, self.margin = float(mu), float(tolerance), float(margin)
        self.offset = float(offset)
        self.foundation = None if foundation is None else foundation.checked(what)
        for body in (a, b):
            if not callable(getattr(body, "contact_surface", None)):
                raise InputError(
                    f"{what}: {type(body).__name__} {body.name!r} has no contact "
                    "surface (rigid bodies with a surface, full and reduced FEM "
                    "bodies and embedded triangle meshes do)"
                )
        (pa, ta), (pb, tb) = self._surfaces = (a.contact_surface(), b.contact_surface())
        if pa.body is pb.body:
            raise InputError(
                f"{what}: both surfaces move with {pa.body.name!r} (self-contact is not supported)"
            )
        xa, xb = pa.positions(), pb.positions()
        _check_closed(xa, ta, a.name)
        _check_closed(xb, tb, b.name)
        self._na = len(xa)
        self._edges = (_edges(ta), _edges(tb))
        self._tris = (np.asarray(ta, dtype=np.int64), np.asarray(tb, dtype=np.int64))
        self._at_rest = [None, None]  # a rigid side's _Geometry in its body frame
        self._last_pairs = None  # (the surfaces' vertices, held, pairs): _pairs's memo
        self._held = None  # the pairs whose features are held (hold_pairs)

    @property
    def bodies(self) -> tuple:
        """The scene bodies the rows act on (an embedded mesh's: its master)."""
        return (self._surfaces[0][0].body, self._surfaces[1][0].body)

    def onto_reduced(self, reduced, lift=None) -> MeshContact:
        """The same contact with the reduced body in place of the full body it replaces
        (the reductor: :mod:`artifem.reduction.reductor`)."""
        a, b = (
            reduced if getattr(reduced, "full", None) is body else body for body in (self.a, self.b)
        )
        return MeshContact(
            a,
            b,
            mu=self.mu,
            tolerance=self.tolerance,
            margin=self.margin,
            offset=self.offset,
            name=self.name,
            foundation=self.foundation,
        )

    def _pairs(self) -> _Pairs:
        """The pairs of the current state (module docstring): vertex over triangle both
        ways, and edge across edge."""
        xs = (self._surfaces[0][0].positions(), self._surfaces[1][0].positions())
        last = self._last_pairs
        if (
            last is not None
            and last[1] is self._held
            and all(np.array_equal(x, y) for x, y in zip(last[0], xs))
        ):
            return last[2]  # the same state: a step's failure check, the next rows
        frames = (self._in_frame(0, xs[0]), self._in_frame(1, xs[1]))
        offsets = (0, len(xs[0]))
        parts, deepest = [], None
        for side in (0, 1):
            part, deep = self._vertex_pairs(xs[side], frames[side], frames[1 - side])
            part[0][:, 0] += offsets[side]
            part[0][:, 1:] += offsets[1 - side]
            part[4][:, 0] = side
            parts.append(part)
            if deep is not None and (deepest is None or deep[0] < deepest[0]):
                deepest = (deep[0], side, deep[1], deep[2])
        if self._held is not None:  # held vertices keep their features
            held = _held_pairs(self._held, np.vstack(xs))
            for side in (0, 1):
                mine = held[4][:, 0] == side
                fresh = ~np.isin(parts[side][4][:, 1], held[4][mine, 1])
                parts[side] = tuple(p[fresh] for p in parts[side])
            parts.append(held)
        part, deep = self._edge_pairs(xs, frames)
        part[0][:, 2:] += offsets[1]
        parts.append(part)
        if deep is not None and (deepest is None or deep[0] < deepest[0]):
            deepest = deep
        if deepest is not None:
            deepest = (deepest[0] - self.offset,) + deepest[1:]
        cols = [p[0] for p in parts]
        k = sum(len(c) for c in cols)
        rows = (
            np.concatenate(
                [
                    np.repeat(np.arange(len(c)), c.shape[1]) + sum(len(q) for q in cols[:i])
                    for i, c in enumerate(cols)
                ]
            )
            if k
            else np.zeros(0, int)
        )
        x = np.vstack(xs)
        W = sparse.csr_matrix(
            (
                np.concatenate([p[1].ravel() for p in parts]),
                (rows, np.concatenate([c.ravel() for c in cols])),
            ),
            shape=(k, len(x)),
        )
        pairs = _Pairs(
            W,
            np.vstack([p[2] for p in parts]),
            np.concatenate([p[3] for p in parts]) - self.offset,
            np.vstack([p[4] for p in parts]),
            deepest,
            x,
            np.vstack(cols),
            np.vstack([p[1] for p in parts]),
            np.vstack([p[5] for p in parts]),
            np.concatenate([p[6] for p in parts]),
        )
        self._last_pairs = ((xs[0].copy(), xs[1].copy()), self._held, pairs)
        return pairs

    def hold_pairs(self, hold: bool) -> None:
        """Hold (True) or release (False) the features the vertices are paired with now
        (the constraint protocol's ``hold_pairs``). While held, a vertex keeps its
        triangles, or its closest edge or vertex, their geometry taken at each new state
        (:func:`_held_pairs`: the projection onto the triangle's plane or the feature's
        line, inside it or not), and only vertices that had no pair get new ones; edge
        pairs are found again. Statics holds them when its Newton iterations circle: a
        cartilage-pressed vertex near the edge between two triangles of a foot's bone
        went from one to the other and back in each iteration (merit 22, 37, 22, ...),
        each triangle's normal pushing it onto the other's; on the triangle it had, Newton
        converges (FEBio's contact interfaces likewise stop updating their segments after
        a number of passes, ``seg_up``)."""
        self._held = self._pairs() if hold else None

    def _in_frame(self, side: int, x: np.ndarray) -> tuple:
        """(the side's :class:`_Geometry`, R, p), world = p + R local: a rigid body's
        surface in its body frame (the point set's ``rigid_frame()``), built once; any
        other surface in the world (R = I, p = 0) at its vertices ``x``."""
        points = self._surfaces[side][0]
        frame = getattr(points, "rigid_frame", None)
        if frame is None:
            return _geometry(x, self._tris[side], self._edges[side]), np.eye(3), np.zeros(3)
        local, R, p = frame()
        if self._at_rest[side] is None:
            self._at_rest[side] = _geometry(local, self._tris[side], self._edges[side])
        return self._at_rest[side], R, p

    @property
    def _reach(self) -> float:
        """Pairs closer than this (m) get rows: the offset plus the margin."""
        return self.offset + self.margin

    def _vertex_pairs(self, xw, own, other):
        """(cols (k, 4): the vertex then the triangle's vertices, weights (k, 4): 1, -b_i,
        e, phi, which (k, 3): (side, vertex, triangle)), and (depth, vertex, triangle) of
        the deepest vertex, for the vertices ``xw`` (world) of ``own`` over the triangles
        of ``other`` (each (:class:`_Geometry`, R, p): :meth:`_in_frame`; the queries run
        in other's frame, e is turned back to the world):

        - every triangle f whose interior the vertex projects onto, within -tolerance <=
          s_f = n_f . (x_v - y_f) < margin, and that faces it (n_f . m_v < 0, m_v the
          vertex's own normal: a box's corner on another's is over its top face, not its
          side): e = n_f, c = x_v - s_f n_f. A vertex sliding across a concave edge (a
          bowl's facets) meets the next facet within the step; with its closest facet's
          row alone it would cross the next by about h v sin(angle between them);
        - a vertex over no such triangle gets its closest point's pair (libigl's AABB
          tree: :func:`_signed_distance`), e = (x_v - c) / s, or the pseudonormal at
          contact (|s| below 1e-3 tolerance).
        """
        g, R, p = other
        xp = (xw - p) @ R  # in other's frame
        xq, tq = g.x, g.tris
        lo, hi = g.box[0] - self._reach, g.box[1] + self._reach
        near = np.flatnonzero(np.all((xp >= lo) & (xp <= hi), axis=1))
        if not near.size:
            return _no_pairs(), None
        S, I, C, N = _signed_distance(g, xp[near])
        j = int(np.argmin(S))
        deepest = (float(S[j]), int(near[j]), int(I[j]))
        close = S < self._reach
        if not np.any(close):
            return _no_pairs(), deepest
        near, S, I, C, N = near[close], S[close], I[close], C[close], N[close]
        k, f = _close_pairs(xp[near], g.centroids, g.reach + self._reach)
        v = near[k]
        n = g.face_normals[f]
        y = xq[tq[f]]
        s = np.einsum("ij,ij->i", xp[v] - y[:, 0], n)
        c = xp[v] - s[:, None] * n
        bary = _barycentric(c, y[:, 0], y[:, 1], y[:, 2])
        g_own, R_own, _ = own
        m = g_own.vertex_normals[v] @ (R_own.T @ R)  # own's normals, in other's frame
        facing = np.einsum("ij,ij->i", n, m) < 0
        keep = (s >= -self.tolerance) & (s < self._reach) & np.all(bary >= -1e-12, axis=1) & facing
        v, f, s, n, bary = v[keep], f[keep], s[keep], n[keep], bary[keep]
        alone = ~np.isin(near, v)  # over no facing triangle
        d = xp[near[alone]] - C[alone]
        small = np.abs(S[alone]) <= 1e-3 * self.tolerance
        e = np.where(small[:, None], _unit(N[alone]), d / np.where(small, 1.0, S[alone])[:, None])
        tri = tq[I[alone]]
        b = _barycentric(C[alone], xq[tri[:, 0]], xq[tri[:, 1]], xq[tri[:, 2]])
        spans, count = _feature_spans(b, small)
        spans = np.concatenate([np.broadcast_to(_FACE_SPANS, (len(v), 2, 4)), spans])
        count = np.r_[np.full(len(v), 2), count]
        v, f = np.r_[v, near[alone]], np.r_[f, I[alone]]
        bary, e, s = np.vstack([bary, b]), np.vstack([n, e]) @ R.T, np.r_[s, S[alone]]
        cols = np.column_stack([v, tq[f]])
        weights = np.column_stack([np.ones(len(v)), -bary])
        return (
            cols,
            weights,
            e,
            s,
            np.column_stack([np.zeros(len(v), int), v, f]),
            spans,
            count,
        ), deepest

    def _edge_pairs(self, xs, frames):
        """(cols (k, 4): a's edge's vertices then b's, weights (k, 4): 1 - s, s, -(1 - t),
        -t, e, phi, which (k, 3): (2, a's edge, b's edge)), and (depth, 2, edge, edge) of
        the deepest crossing, for the edges of a and b (vertices ``xs`` in the world,
        ``frames`` of :meth:`_in_frame`) whose closest points are inside both
        (not parallel) within the margin, facing (e . m_b > 0 > e . m_a, m the edges'
        normals, the sums of their two triangles'): e = +-(u x v) / |u x v| (u, v the edges)
        out of b, phi = e . (p_a - p_b), between sharp edges of both (:func:`_sharp`). Two
        boxes turned against each other meet edge on edge, with no vertex of either over
        the other."""
        xa, xb = xs
        (ga, Ra, _), (gb, Rb, _) = frames
        (ea, fa), (eb, fb) = self._edges
        lo, hi = xb.min(axis=0) - self._reach, xb.max(axis=0) + self._reach
        # only sharp edges of both meet edge on edge: the candidates are among those
        sharp_b = np.flatnonzero(gb.sharp)
        mid_a, mid_b = xa[ea].mean(axis=1), xb[eb[sharp_b]].mean(axis=1)
        half_a = 0.5 * np.linalg.norm(xa[ea[:, 1]] - xa[ea[:, 0]], axis=1)
        half_b = 0.5 * np.linalg.norm(xb[eb[sharp_b, 1]] - xb[eb[sharp_b, 0]], axis=1)
        cand = np.flatnonzero(
            ga.sharp
            & np.all((mid_a + half_a[:, None] >= lo) & (mid_a - half_a[:, None] <= hi), axis=1)
        )
        if not cand.size or not sharp_b.size:
            return _no_pairs(), None
        k, j = _close_pairs(
            mid_a[cand], cKDTree(mid_b), half_a[cand].max() + half_b.max() + self._reach
        )
        i, j = cand[k], sharp_b[j]
        a0, a1, b0, b1 = xa[ea[i, 0]], xa[ea[i, 1]], xb[eb[j, 0]], xb[eb[j, 1]]
        s, t = _segment_closest(a0, a1, b0, b1)
        inside = (s > 1e-9) & (s < 1 - 1e-9) & (t > 1e-9) & (t < 1 - 1e-9)
        i, j, s, t = i[inside], j[inside], s[inside], t[inside]
        a0, a1, b0, b1 = a0[inside], a1[inside], b0[inside], b1[inside]
        pa, pb = a0 + s[:, None] * (a1 - a0), b0 + t[:, None] * (b1 - b0)
        ma = ga.face_normals[fa[i]].sum(axis=1) @ Ra.T
        mb = gb.face_normals[fb[j]].sum(axis=1) @ Rb.T
        e = _unit(np.cross(a1 - a0, b1 - b0))
        e *= np.where(np.einsum("ij,ij->i", e, mb - ma) < 0, -1.0, 1.0)[:, None]
        phi = np.einsum("ij,ij->i", e, pa - pb)
        keep = (
            (np.linalg.norm(pa - pb, axis=1) < self._reach)
            & (np.einsum("ij,ij->i", e, mb) > 0)
            & (np.einsum("ij,ij->i", e, ma) < 0)
        )
        i, j, s, t, e, phi = i[keep], j[keep], s[keep], t[keep], e[keep], phi[keep]
        deepest = None
        if phi.size:
            k = int(np.argmin(phi))
            deepest = (float(phi[k]), 2, int(i[k]), int(j[k]))
        close = phi < self._reach
        i, j, s, t, e, phi = i[close], j[close], s[close], t[close], e[close], phi[close]
        cols = np.column_stack([ea[i], eb[j]])
        weights = np.column_stack([1.0 - s, s, -(1.0 - t), -t])
        return (
            cols,
            weights,
            e,
            phi,
            np.column_stack([np.full(len(i), 2), i, j]),
            np.broadcast_to(_EDGE_SPANS, (len(i), 2, 4)),
            np.full(len(i), 2),
        ), deepest

    def _describe(self, kind: int, i: int, j: int) -> str:
        """A pair (:class:`_Pairs` ``which``) in words."""
        a, b = self.a.name, self.b.name
        if kind == 2:
            (ea, _), (eb, _) = self._edges
            return (
                f"the edge of vertices {ea[i].tolist()} of {a!r} and the edge of vertices "
                f"{eb[j].tolist()} of {b!r}"
            )
        own, other = (a, b) if kind == 0 else (b, a)
        return f"vertex {i} of {own!r} and triangle {j} of {other!r}"

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
        Ga, Gb = pa.rows(Wa, directions), pb.rows(Wb, directions)

        def stiffness(lam):
            f = lam[:, None] * directions
            return sparse.block_diag(
                [sparse.csr_matrix(pa.stiffness(Wa, f)), sparse.csr_matrix(pb.stiffness(Wb, f))],
                format="csr",
            ) + self._turning(pairs, lam[:k], (Ga.shape[1], Gb.shape[1]))

        side_a = np.asarray(W[:, :na].sum(axis=1)).ravel()
        return [
            MeshContactRows(
                self,
                np.concatenate([phi, np.zeros(m - k)]),
                ((pa.body, Ga), (pb.body, Gb)),
                lo,
                hi,
                stiffness,
                Friction.tangents(k, self.mu) if self.mu > 0 else None,
                np.column_stack(
                    [np.tile(pairs.which, (m // k, 1)), np.repeat(np.arange(m // k), k)]
                ),
                points=(W[:, na:] @ x[na:]) / -side_a[:, None],
                normals=e,
                side_a=side_a,
                tangents=(bases[:, :, 0], bases[:, :, 1]) if self.mu > 0 else (),
                weights=W,
                compliance=self._compliance(pairs, m),
            )
        ]

    def _turning(self, pairs: _Pairs, lam: np.ndarray, sizes: tuple) -> sparse.csr_matrix:
        """J^T (sum_k lambda_k d^2 s_k / dX^2) J on both bodies' coordinates: how the
        normal rows turn (their normals, and the closest points sliding along the
        features) under the normal impulses ``lam`` held fixed, J = dX/dq of the pairs'
        points (:mod:`~artifem.multibody.distance_hessian`). The friction rows' tangents
        are left out (they turn with e by the frame of ``axis_rotation``). ``sizes``: the
        bodies' coordinate counts."""
        (pa, _), (pb, _) = self._surfaces
        na, size = self._na, len(pairs.x)
        n_a, n_b = sizes
        used = np.flatnonzero((lam != 0) & (pairs.span_count >= 0))
        if not used.size:
            return sparse.csr_matrix((n_a + n_b, n_a + n_b))
        cols = pairs.cols[used]
        H = lam[used, None, None] * distance_hessians(
            pairs.x[cols],
            pairs.weights[used],
            pairs.spans[used],
            pairs.span_count[used],
            pairs.e[used],
            pairs.phi[used] + self.offset,
        )
        verts, local = np.unique(cols, return_inverse=True)
        local = local.reshape(cols.shape)
        # J: three rows per vertex (its x, y, z) on its body's coordinates
        J = []
        for points, mine, start, n in (
            (pa, verts[verts < na], 0, na),
            (pb, verts[verts >= na], na, size - na),
        ):
            select = sparse.csr_matrix(
                (np.ones(3 * len(mine)), (np.arange(3 * len(mine)), np.repeat(mine - start, 3))),
                shape=(3 * len(mine), n),
            )
            J.append(sparse.csr_matrix(points.rows(select, np.tile(np.eye(3), (len(mine), 1)))))
        J = sparse.block_diag(J, format="csr")
        dofs = (3 * local[:, :, None] + np.arange(3)).reshape(len(used), 12)
        Hs = sparse.csr_matrix(
            (H.ravel(), (np.repeat(dofs, 12, axis=1).ravel(), np.tile(dofs, (1, 12)).ravel())),
            shape=(3 * len(verts), 3 * len(verts)),
        )
        return sparse.csr_matrix(J.T @ Hs @ J)

    def _compliance(self, pairs: _Pairs, m: int):
        """The normal rows' compliance of the foundation, or None: a vertex-over-triangle
        pair's from its vertex's facing area on its own surface, shared equally among the
        vertex's pairs (a vertex over the common edge of two triangles, or meeting the
        facets of a concave edge, has one row for each: one spring in all), edge pairs and
        friction rows hard."""
        if self.foundation is None:
            return None
        areas = np.zeros(m)
        for side, (points, _) in enumerate(self._surfaces):
            rows = np.flatnonzero(pairs.which[:, 0] == side)
            if rows.size:
                _, inverse, counts = np.unique(
                    pairs.which[rows, 1], return_inverse=True, return_counts=True
                )
                areas[rows] = (
                    points.facing_areas(pairs.which[rows, 1], pairs.e[rows]) / counts[inverse]
                )
        return self.foundation.compliance(areas)

    def constraint_failure(self) -> str | None:
        """A vertex of either surface deeper than ``tolerance`` inside the other, or two
        edges crossed by more, if any."""
        deepest = self._pairs().deepest
        allowed = (
            self.tolerance
            if self.foundation is None
            else max(self.tolerance, self.foundation.thickness)
        )
        if deepest is None or deepest[0] >= -allowed:
            return None
        depth, kind, i, j = deepest
        what = "the vertex is" if kind < 2 else "they are crossed by"
        return (
            f"contact {self.name!r}: {self._describe(kind, i, j)}: {what} {-depth:.3g} "
            f"inside (the tolerance is {allowed:g}; a pair that comes from beyond "
            f"the margin {self.margin:g} within one step has no row: the margin should be "
            "at least the largest approach speed times the step)"
        )

    def forces(self, parts: list, h: float) -> MeshContactForces:
        """The forces of the impulses ``parts`` [(block, lambda)] of a step of size h."""
        if not parts:
            return MeshContactForces(
                np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
            )
        ((block, lam),) = parts
        k = len(block.points)
        side = block.side_a[:, None]
        friction = np.zeros((k, 3))
        if self.mu > 0:
            friction = (
                side
                * (
                    lam[k : 2 * k, None] * block.tangents[0]
                    + lam[2 * k :, None] * block.tangents[1]
                )
                / h
            )
        return MeshContactForces(block.points, lam[:k] / h, side * block.normals, friction)

    def normal_forces(self, parts: list, h: float) -> list:
        """[(a body's surface points, the normal force on each (N))] for a and b over the
        last step: each pair's normal force shared by its coefficients, f_j = sum_k
        |W_kj| lambda_k / h (a vertex takes all of it, a triangle's vertices b_i of it)."""
        (pa, _), (pb, _) = self._surfaces
        f = np.zeros(len(pa) + len(pb))
        for block, lam in parts:
            k = len(block.points)
            f += abs(block.weights).T @ (lam[:k] / h)
        return [(pa, f[: len(pa)]), (pb, f[len(pa) :])]
