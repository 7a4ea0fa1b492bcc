"""Muscle fiber directions and bundle geometry of the ArtiSynth tongue.

Fibers.mac gives each muscle bundle as polylines of node ids; the FEM fiber
material needs a unit direction a0 per element instead.  ArtiSynth derives
element directions from nearby fibers too (``MuscleBundle.computeElementDirections``);
here the rule is the simplest one that is exact on the data:

    for each element of a bundle, a0 is the unit direction of the bundle's
    fiber segment (two consecutive polyline nodes) nearest to the element's
    centroid (the mean of its 8 nodes), by point-to-segment distance; it is
    oriented like the polyline (from node k to node k+1).

The sign of a0 does not matter to a fiber energy written in |F a0|, but it is
deterministic.  Ties between equally near segments go to the first segment in
file order (fiber by fiber, node by node).  Zero-length segments (repeated
nodes) are ignored.

The styloglossus fibers end on two points outside the tongue mesh, the styloid
process insertions, ANSYS ids 4037 and 4042 (see :data:`EXTRA_NODES`).
"""

from __future__ import annotations

import numpy as np

from artifem.errors import InputError, UnknownNameError
from artifem.io.mesh_checks import element_volumes
from artifem.io.mesh_data import MeshData

#: Points that Fibers.mac refers to but tongue.node does not define: the
#: styloglossus insertions on the styloid process.  ArtiSynth's
#: AnsysMuscleFiberReader maps ANSYS 4037 -> node 947 and 4042 -> node 946,
#: and HexTongueDemo.addStyNodes creates nodes 946, 947 (fixed, non-dynamic)
#: at ``styNodeLowerPositions`` = (0.14984029, +-0.035891287, 0.125) m, in that
#: order: 4042 at y > 0 (with STY_R, whose elements lie at y > 0) and 4037 at
#: y < 0 (with STY_L).
EXTRA_NODES: dict[int, tuple[float, float, float]] = {
    4037: (0.14984029, -0.035891287, 0.125),
    4042: (0.14984029, 0.035891287, 0.125),
}


def fiber_points(
    md: MeshData,
    fibers: dict[str, list[np.ndarray]],
    extra_points: dict[int, tuple[float, float, float]] | None = None,
) -> dict[str, list[np.ndarray]]:
    """Coordinates of the fibers: name -> list of (n, 3) arrays.

    Node ids are looked up in ``md.node_ids``; ids that are not mesh nodes are
    taken from ``extra_points`` (default :data:`EXTRA_NODES`); an id in
    neither is an error.
    """
    extra = EXTRA_NODES if extra_points is None else extra_points
    known = set(md.node_ids.tolist())
    out: dict[str, list[np.ndarray]] = {}
    for name, polylines in fibers.items():
        xyz = []
        for ids in polylines:
            ids = np.asarray(ids, dtype=np.int64)
            pts = np.empty((len(ids), 3))
            inside = np.array([i in known for i in ids.tolist()], dtype=bool)
            if inside.any():
                pts[inside] = md.points[md.node_rows(ids[inside])]
            for k in np.flatnonzero(~inside):
                if int(ids[k]) not in extra:
                    raise UnknownNameError(
                        f"fiber node {int(ids[k])} of {name} is neither a mesh node "
                        f"nor in extra_points"
                    )
                pts[k] = extra[int(ids[k])]
            xyz.append(pts)
        out[name] = xyz
    return out


def _segments(fibers_xyz) -> tuple[np.ndarray, np.ndarray]:
    """Start points and vectors of the non-degenerate segments of a list of polylines."""
    starts, vecs = [], []
    for pts in fibers_xyz:
        pts = np.asarray(pts, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
            raise InputError(f"a fiber must be an (n >= 2, 3) array of points, got {pts.shape}")
        d = np.diff(pts, axis=0)
        keep = np.linalg.norm(d, axis=1) > 0
        starts.append(pts[:-1][keep])
        vecs.append(d[keep])
    if not starts or sum(len(s) for s in starts) == 0:
        raise InputError("no fiber segment of positive length")
    return np.concatenate(starts), np.concatenate(vecs)


def point_segment_distances(x: np.ndarray, starts: np.ndarray, vecs: np.ndarray) -> np.ndarray:
    """(P, S) distances from points x (P, 3) to segments starts + t vecs, t in [0, 1]."""
    rel = x[:, None, :] - starts[None, :, :]
    t = np.einsum("psj,sj->ps", rel, vecs) / np.einsum("sj,sj->s", vecs, vecs)
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(rel - t[..., None] * vecs[None], axis=2)


def element_directions(
    points: np.ndarray, cells: np.ndarray, element_rows, fibers_xyz
) -> tuple[np.ndarray, np.ndarray]:
    """Fiber direction of each element of a bundle: (directions (E, 3), distances (E,)).

    ``element_rows`` are rows of ``cells``; ``fibers_xyz`` is the bundle's list of
    polylines ((n, 3) point arrays, e.g. from :func:`fiber_points`).  The rule
    (module docstring): the unit direction, oriented like the polyline, of the
    fiber segment nearest to the element centroid; ``distances`` are the
    centroid-to-segment distances.
    """
    rows = np.asarray(element_rows, dtype=np.int64).ravel()
    centroids = np.asarray(points)[np.asarray(cells)[rows]].mean(axis=1)
    starts, vecs = _segments(fibers_xyz)
    dist = point_segment_distances(centroids, starts, vecs)
    nearest = dist.argmin(axis=1)
    d = vecs[nearest]
    return d / np.linalg.norm(d, axis=1, keepdims=True), dist[np.arange(len(rows)), nearest]


def polyline_length(pts: np.ndarray) -> float:
    """Length of a polyline given as (n, 3) points."""
    return float(np.linalg.norm(np.diff(np.asarray(pts, dtype=float), axis=0), axis=1).sum())


def bundle_geometry(
    md: MeshData,
    muscle_elements: dict[str, np.ndarray],
    fibers: dict[str, list[np.ndarray]],
    extra_points: dict[int, tuple[float, float, float]] | None = None,
) -> dict[str, dict[str, float]]:
    """Size of each bundle, for turning a muscle's maximum force into a fiber stress.

    For every bundle present in both ``muscle_elements`` (ANSYS element ids) and
    ``fibers`` (ANSYS node ids): number of elements and fibers, total element
    volume (m^3, exact 2x2x2 Gauss volume of the trilinear hexes), mean fiber
    polyline length (m) and cross_section = volume / mean fiber length (m^2);
    a maximum force F then corresponds to a fiber stress F / cross_section.
    ``mean_fiber_length_inside_m`` leaves out the segments that end on a point
    outside the mesh (the styloglossus' tendon to the styloid process), which
    only changes STY; ``cross_section_m2`` uses the full length, as asked,
    ``cross_section_inside_m2`` the inside length.
    """
    extra = EXTRA_NODES if extra_points is None else extra_points
    xyz = fiber_points(md, fibers, extra)
    vols = np.abs(element_volumes(md.points, md.cell_type, md.cells))
    known = set(md.node_ids.tolist())
    out = {}
    for name, ids in muscle_elements.items():
        if name not in fibers:
            continue
        volume = float(vols[md.cell_rows(ids)].sum())
        lengths, inside = [], []
        for node_ids, pts in zip(fibers[name], xyz[name]):
            seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
            in_mesh = np.array([i in known for i in np.asarray(node_ids).tolist()])
            lengths.append(seg.sum())
            inside.append(seg[in_mesh[:-1] & in_mesh[1:]].sum())
        mean_len = float(np.mean(lengths))
        mean_in = float(np.mean(inside))
        out[name] = {
            "elements": int(len(ids)),
            "fibers": int(len(fibers[name])),
            "volume_m3": volume,
            "mean_fiber_length_m": mean_len,
            "cross_section_m2": volume / mean_len,
            "mean_fiber_length_inside_m": mean_in,
            "cross_section_inside_m2": volume / mean_in,
        }
    return out
