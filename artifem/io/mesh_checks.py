"""Element validity checks: corner Jacobians, orientation, degeneracy, volume.

Reference cells are those of basix: the unit cube [0,1]^3 for hexahedra and
the unit tetrahedron for tetrahedra, so det J of a unit cube element is 1 and
det J of a tetrahedron is 6 times its signed volume.  Nodes are in VTK order.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artifem.errors import MeshError
from artifem.io.mesh_data import HEX_VTK_CORNER, MeshData

_HEX_FACES = [(0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
_HEX_EDGES = {
    frozenset(e)
    for e in [
        (0, 1),
        (1, 2),
        (2, 3),
        (3, 0),
        (4, 5),
        (5, 6),
        (6, 7),
        (7, 4),
        (0, 4),
        (1, 5),
        (2, 6),
        (3, 7),
    ]
}

#: Node permutation that reverses an element's orientation (VTK order):
#: hexahedra swap bottom and top faces, tetrahedra swap nodes 1 and 2.
REORIENT = {"hexahedron": np.array([4, 5, 6, 7, 0, 1, 2, 3]), "tetrahedron": np.array([0, 2, 1, 3])}


def _hex_corner_edges():
    """For each VTK corner, the VTK (from, to) node pairs of its three reference-axis edges."""
    pairs = []
    for corner, _ in sorted(HEX_VTK_CORNER.items(), key=lambda kv: kv[1]):
        axes = []
        for axis in range(3):
            lo, hi = list(corner), list(corner)
            lo[axis], hi[axis] = 0, 1
            axes.append((HEX_VTK_CORNER[tuple(lo)], HEX_VTK_CORNER[tuple(hi)]))
        pairs.append(axes)
    return np.array(pairs)  # (8 corners, 3 axes, 2)


_HEX_CORNER_EDGES = _hex_corner_edges()


def corner_jacobians(points: np.ndarray, cell_type: str, cells: np.ndarray) -> np.ndarray:
    """det J of the reference map at each element corner: (M, 8) for hexes, (M, 1) for tets.

    For the trilinear hexahedron the Jacobian at a corner has as columns the
    three element edges leaving that corner along the reference axes.
    """
    x = points[cells]  # (M, k, 3)
    if cell_type == "hexahedron":
        e = _HEX_CORNER_EDGES
        cols = x[:, e[..., 1], :] - x[:, e[..., 0], :]  # (M, 8, 3 axes, 3)
        return np.einsum("mcj,mcj->mc", cols[:, :, 0], np.cross(cols[:, :, 1], cols[:, :, 2]))
    if cell_type == "tetrahedron":
        d = x[:, 1:, :] - x[:, :1, :]
        return np.einsum("mj,mj->m", d[:, 0], np.cross(d[:, 1], d[:, 2]))[:, None]
    raise MeshError(f"no Jacobian check for cell type {cell_type!r}")


def element_jacobians(mesh: MeshData) -> np.ndarray:
    """Smallest corner det J of every element, shape (M,)."""
    return corner_jacobians(mesh.points, mesh.cell_type, mesh.cells).min(axis=1)


def classify_orientation(
    points: np.ndarray, cell_type: str, cells: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Row indices of (inverted, tangled) elements.

    Inverted: det J < 0 at every corner (a reversed node ordering, fixable).
    Tangled: det J <= 0 at some corners but not all (self-intersecting or
    degenerate geometry, not fixable by renumbering).
    """
    dets = corner_jacobians(points, cell_type, cells)
    inverted = np.flatnonzero((dets < 0).all(axis=1))
    tangled = np.flatnonzero((dets <= 0).any(axis=1) & ~(dets < 0).all(axis=1))
    return inverted, tangled


def _ids(mesh: MeshData, rows: np.ndarray, limit: int = 20) -> str:
    """Comma-separated element ids of the given rows, shortened after ``limit``."""
    ids = [str(i) for i in mesh.cell_ids[rows[:limit]]]
    more = f" ... ({len(rows)} in all)" if len(rows) > limit else ""
    return ", ".join(ids) + more


def check_orientation(mesh: MeshData, fix: bool = False) -> tuple[MeshData, np.ndarray]:
    """Find inverted elements; return (mesh, ids of inverted elements).

    With ``fix=True`` the returned mesh is a copy with inverted elements
    renumbered (REORIENT permutation) so every det J is positive; otherwise it
    is ``mesh`` itself.  Tangled elements raise MeshError naming them.
    """
    inverted, tangled = classify_orientation(mesh.points, mesh.cell_type, mesh.cells)
    if len(tangled):
        raise MeshError(
            f"{mesh.source}: {len(tangled)} {mesh.cell_type} element(s) with det J of "
            f"mixed sign or zero at their corners (tangled or degenerate, cannot be fixed "
            f"by renumbering): ids {_ids(mesh, tangled)}"
        )
    if fix and len(inverted):
        cells = mesh.cells.copy()
        cells[inverted] = cells[inverted][:, REORIENT[mesh.cell_type]]
        mesh = replace(mesh, cells=cells, cells_by_type={mesh.cell_type: cells})
    return mesh, mesh.cell_ids[inverted]


def degenerate_elements(mesh: MeshData) -> list[tuple[int, str]]:
    """(row, description) of elements with repeated nodes, naming what they collapse to.

    Hexahedra: a face collapsed to an edge is a wedge, a face collapsed to a
    point a pyramid, both (plus the opposite face's edge) a tetrahedron; any
    other repetition is reported as an irregular collapse.
    """
    found = []
    for row, cell in enumerate(mesh.cells):
        if len(np.unique(cell)) == len(cell):
            continue
        if mesh.cell_type == "tetrahedron":
            found.append((row, "zero-volume tetrahedron (repeated node)"))
        else:
            found.append((row, _hex_collapse(cell)))
    return found


def _hex_collapse(cell: np.ndarray) -> str:
    """Name the element a hexahedron with repeated nodes (VTK order) collapses to."""
    groups = [frozenset(np.flatnonzero(cell == n)) for n in np.unique(cell)]
    repeated = sorted((g for g in groups if len(g) > 1), key=len)
    faces = [frozenset(f) for f in _HEX_FACES]
    distinct = len(groups)
    sizes = [len(g) for g in repeated]
    if (
        sizes == [2, 2]
        and all(g in _HEX_EDGES for g in repeated)
        and repeated[0] | repeated[1] in faces
    ):
        return "wedge (a face collapsed to an edge)"
    if sizes == [4] and repeated[0] in faces:
        return "pyramid (a face collapsed to a point)"
    if (
        sizes == [2, 4]
        and repeated[1] in faces
        and repeated[0] in _HEX_EDGES
        and not repeated[0] & repeated[1]
    ):
        return "tetrahedron (a face collapsed to a point, the opposite face to a triangle)"
    return f"irregular collapse ({distinct} distinct nodes)"


def reject_degenerate(mesh: MeshData) -> None:
    """Raise MeshError listing elements with repeated nodes and what they collapse to."""
    found = degenerate_elements(mesh)
    if found:
        listing = "; ".join(f"element {mesh.cell_ids[row]}: {what}" for row, what in found[:20])
        more = f"; ... ({len(found)} in all)" if len(found) > 20 else ""
        raise MeshError(
            f"{mesh.source}: {len(found)} degenerate {mesh.cell_type} element(s) with "
            f"repeated node ids ({listing}{more}); a DOLFINx mesh holds one cell type, "
            f"so split or remesh them"
        )


# 2-point Gauss rule on [0, 1]: exact for the degree-2-per-variable det J of a trilinear map.
_GAUSS_01 = 0.5 + np.array([-1.0, 1.0]) / (2.0 * np.sqrt(3.0))


def _trilinear_shape_gradients(xi: np.ndarray) -> np.ndarray:
    """Gradients (3,8) of the trilinear shape functions (VTK order) at reference point xi."""
    grads = np.zeros((3, 8))
    for (a, b, c), node in HEX_VTK_CORNER.items():
        fa = (xi[0] if a else 1 - xi[0], 1 if a else -1)
        fb = (xi[1] if b else 1 - xi[1], 1 if b else -1)
        fc = (xi[2] if c else 1 - xi[2], 1 if c else -1)
        grads[:, node] = (fa[1] * fb[0] * fc[0], fa[0] * fb[1] * fc[0], fa[0] * fb[0] * fc[1])
    return grads


def element_volumes(points: np.ndarray, cell_type: str, cells: np.ndarray) -> np.ndarray:
    """Signed volume of each element (2x2x2 Gauss on hexes, exact; exact on tets)."""
    x = points[cells]
    if cell_type == "tetrahedron":
        return corner_jacobians(points, cell_type, cells)[:, 0] / 6.0
    vol = np.zeros(len(cells))
    for xi in np.array(np.meshgrid(_GAUSS_01, _GAUSS_01, _GAUSS_01)).reshape(3, -1).T:
        jac = np.einsum("kn,mnj->mjk", _trilinear_shape_gradients(xi), x)
        vol += np.linalg.det(jac) / 8.0
    return vol


def volume(mesh: MeshData) -> float:
    """Total volume of all volume cells of the mesh (sum of |element volume|)."""
    return float(
        sum(np.abs(element_volumes(mesh.points, t, c)).sum() for t, c in mesh.cells_by_type.items())
    )
