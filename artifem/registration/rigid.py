"""Rigid and affine registration of points to a triangle surface.

- :func:`kabsch`: the proper rotation R and translation t minimizing
  sum_i |R p_i + t - q_i|^2 (Kabsch 1976): with H = sum_i (p_i - p0)(q_i - q0)^T =
  U S V^T (p0, q0 the centroids), R = V diag(1, 1, det(V U^T)) U^T and t = q0 - R p0.
- :func:`affine_fit`: the matrix A and translation t minimizing sum_i |A p_i + t - q_i|^2
  (linear least squares; the registration baseline of a bone scaled and sheared as a
  whole).
- :class:`TriangleSurface`: a triangle mesh and libigl's AABB tree over it (built once),
  for exact point-to-triangle closest points; its border (the edges of one triangle)
  tells which closest points lie on the edge of an open surface.
- :func:`icp`: point-to-surface ICP (Besl and McKay 1992): each point's closest point
  c_i on the surface, then (R, t) = kabsch(p, c), until (R, t) stop changing; ``trim``
  < 1 fits only that fraction of the pairs, the closest ones (trimmed ICP, Chetverikov
  et al. 2002), for a target that covers part of the points or more than them; pairs
  whose closest point lies on an open surface's border are left out (Turk and Levoy 1994).
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np

from artifem.errors import InputError

__all__ = ["RigidFit", "TriangleSurface", "affine_fit", "icp", "kabsch"]


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) minimizing sum_i |R src_i + t - dst_i|^2 over proper rotations R (module
    docstring)."""
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise InputError(
            f"kabsch: two (n, 3) point sets with n >= 3 expected, got {src.shape} and {dst.shape}"
        )
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    U, _, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cd - R @ cs


def affine_fit(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, t) minimizing sum_i |A src_i + t - dst_i|^2 (module docstring); the points must
    not all lie in a plane."""
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 4:
        raise InputError(
            f"affine_fit: two (n, 3) point sets with n >= 4 expected, got "
            f"{src.shape} and {dst.shape}"
        )
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    P = src - cs
    if np.linalg.matrix_rank(P, tol=1e-12 * max(np.abs(P).max(), 1e-300)) < 3:
        raise InputError("affine_fit: the points lie in a plane or on a line: no unique affine map")
    A = np.linalg.lstsq(P, dst - cd, rcond=None)[0].T
    return A, cd - A @ cs


class TriangleSurface:
    """Vertices (n, 3) and triangles (m, 3) with libigl's AABB tree for closest points."""

    def __init__(self, vertices, triangles):
        self.vertices = np.ascontiguousarray(vertices, dtype=float)
        self.triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        if (
            self.vertices.ndim != 2
            or self.vertices.shape[1] != 3
            or self.triangles.ndim != 2
            or self.triangles.shape[1] != 3
            or not len(self.triangles)
        ):
            raise InputError(
                f"TriangleSurface: vertices (n, 3) and triangles (m >= 1, 3) "
                f"expected, got {self.vertices.shape} and {self.triangles.shape}"
            )
        if self.triangles.min() < 0 or self.triangles.max() >= len(self.vertices):
            raise InputError(
                f"TriangleSurface: triangle indices outside 0...{len(self.vertices) - 1}"
            )
        self.tree = igl.AABB()
        self.tree.init(self.vertices, self.triangles)
        edges = np.sort(self.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        keys, counts = np.unique(edges[:, 0] * len(self.vertices) + edges[:, 1], return_counts=True)
        #: the border edges (edges of one triangle) as keys a n + b (a < b, n vertices)
        self.border_edges = keys[counts == 1]
        #: (n,) True at the vertices on a border edge
        self.border_vertices = np.zeros(len(self.vertices), dtype=bool)
        self.border_vertices[
            np.concatenate(
                [self.border_edges // len(self.vertices), self.border_edges % len(self.vertices)]
            )
        ] = True

    @classmethod
    def from_polydata(cls, polydata) -> TriangleSurface:
        """The triangles of a pyvista PolyData (other polygons split into triangles)."""
        surface = polydata.triangulate()
        return cls(np.asarray(surface.points), np.asarray(surface.faces).reshape(-1, 4)[:, 1:])

    def closest(self, points) -> tuple[np.ndarray, np.ndarray]:
        """(distances (k,), closest points (k, 3)) of ``points`` on the surface."""
        d, c, _ = self.closest_triangles(points)
        return d, c

    def closest_triangles(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(distances (k,), closest points (k, 3), their triangles (k,))."""
        points = np.ascontiguousarray(points, dtype=float).reshape(-1, 3)
        sq, triangle, closest = self.tree.squared_distance(self.vertices, self.triangles, points)
        return np.sqrt(np.maximum(sq, 0.0)), closest, np.asarray(triangle, dtype=np.int64)

    def closest_kept(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(distances (k,), closest points (k, 3), kept (k,)): kept where the closest point
        is not on the surface's border (:meth:`on_border`; all kept on a closed surface)."""
        d, c, tri = self.closest_triangles(points)
        return d, c, ~self.on_border(tri, self.barycentric(c, tri))

    def barycentric(self, points, triangles) -> np.ndarray:
        """(k, 3) barycentric coordinates of ``points`` (on the surface) in their
        ``triangles``, clipped to [0, 1]."""
        corners = self.vertices[self.triangles[triangles]]
        b = igl.barycentric_coordinates(
            np.ascontiguousarray(points, dtype=float),
            *(np.ascontiguousarray(corners[:, k]) for k in range(3)),
        )
        return np.clip(b, 0.0, 1.0)

    def on_border(self, triangles, barycentric, zero: float = 1e-10) -> np.ndarray:
        """(k,) True where the surface point of ``barycentric`` coordinates (coordinates
        <= ``zero`` are on an edge or at a vertex) in ``triangles`` lies on a border edge
        or at a border vertex; all False on a closed surface."""
        on = np.zeros(len(barycentric), dtype=bool)
        if not self.border_edges.size:
            return on
        corners = self.triangles[triangles]
        zero = np.asarray(barycentric) <= zero
        count = zero.sum(axis=1)
        vertex = np.flatnonzero(count == 2)
        on[vertex] = self.border_vertices[corners[vertex, np.argmin(zero[vertex], axis=1)]]
        edge = np.flatnonzero(count == 1)
        ends = np.sort(corners[edge][~zero[edge]].reshape(-1, 2), axis=1)
        on[edge] = np.isin(ends[:, 0] * len(self.vertices) + ends[:, 1], self.border_edges)
        return on


@dataclass(frozen=True)
class RigidFit:
    """x -> R x + t (R a rotation; any matrix for affine ICP): ``distances`` of every moved
    point to the surface, ``score`` the mean distance of the fitted fraction,
    ``iterations`` the ICP iterations taken."""

    R: np.ndarray
    t: np.ndarray
    distances: np.ndarray
    score: float
    iterations: int


def icp(
    points,
    surface: TriangleSurface,
    R=None,
    t=None,
    *,
    trim: float = 1.0,
    iterations: int = 60,
    rotation_tol: float = 1e-10,
    translation_tol: float = 1e-12,
    affine: bool = False,
    drop_border: bool = True,
) -> RigidFit:
    """Trimmed point-to-surface ICP of ``points`` onto ``surface`` from (R, t) (default
    identity): at most ``iterations`` of closest points and :func:`kabsch` (``affine``:
    :func:`affine_fit`, R then any matrix) on the fraction ``trim`` of the pairs with the
    smallest distances (all of them at 1), without the pairs whose closest point lies on
    the surface's border (a partial target's edge; Turk and Levoy; unless not
    ``drop_border``), until the entries of R change by less than
    ``rotation_tol`` and those of t by less than ``translation_tol`` (module
    docstring)."""
    points = np.asarray(points, dtype=float)
    if not 0.0 < trim <= 1.0:
        raise InputError(f"icp: trim must be in (0, 1], got {trim}")
    R = np.eye(3) if R is None else np.asarray(R, dtype=float)
    t = np.zeros(3) if t is None else np.asarray(t, dtype=float)

    def kept(r):
        return r <= np.quantile(r, trim) if trim < 1.0 else np.ones(r.size, dtype=bool)

    done = 0
    for done in range(1, iterations + 1):  # noqa: B007 (returned: the iterations taken)
        moved = points @ R.T + t
        r, closest, off_border = surface.closest_kept(moved)
        keep = kept(r) & off_border if drop_border else kept(r)
        R_new, t_new = (affine_fit if affine else kabsch)(points[keep], closest[keep])
        converged = (
            np.abs(R_new - R).max() < rotation_tol and np.abs(t_new - t).max() < translation_tol
        )
        R, t = R_new, t_new
        if converged:
            break
    r, _ = surface.closest(points @ R.T + t)
    return RigidFit(R, t, r, float(r[kept(r)].mean()), done)
