"""Uniform 2x2x2 refinement of trilinear hexahedral meshes, with parent maps.

Each hexahedron is split into 8 by adding a node at the midpoint of each of
its 12 edges, the centre of each of its 6 faces and its own centre.  Those
points are values of the element's trilinear map at reference coordinates
in {0, 1/2, 1}^3, which for a trilinear map are exactly the means of the
corners they depend on: edge midpoint = mean of 2 corners, face centre =
mean of 4, cell centre = mean of 8.  The refined mesh therefore has the same
geometry (the same volume, to round-off) and stays conforming: a new node is
identified by the sorted tuple of its parent corner rows, not by its
coordinates, so neighbours share their edge and face nodes.

Numbering
    Nodes: the coarse nodes keep their rows 0..N-1 and their ids; the new
    nodes follow, first the E edge midpoints, then the F face centres, then
    the M cell centres (each group sorted by parent rows).  New nodes get ids
    max(coarse id) + 1, + 2, ... in row order, so a mesh whose ids are row + 1
    (the ArtiSynth tongue) keeps ids = row + 1 throughout.
    Cells: the child of coarse row p that contains coarse corner c (VTK corner
    numbering 0..7) is row 8 p + c, with id 8 p + c + 1 (ids are new: 1..8M;
    ``parent_cell`` maps back).  Children keep the parent's VTK node ordering,
    hence its orientation, and inherit its ``cell_tags``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from artifem.errors import MeshError
from artifem.io.mesh_data import HEX_VTK_CORNER, MeshData

# HEX_VTK_CORNER (mesh_data) backwards: the reference corner of each VTK vertex.
_REF_OF = {v: k for k, v in HEX_VTK_CORNER.items()}
#: Local corner pairs of the 12 edges and quadruples of the 6 faces (VTK numbering).
HEX_EDGES = np.array(
    [(0, 1), (1, 2), (3, 2), (0, 3), (4, 5), (5, 6), (7, 6), (4, 7), (0, 4), (1, 5), (2, 6), (3, 7)]
)
HEX_FACES = np.array(
    [(0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (3, 2, 6, 7), (0, 3, 7, 4)]
)


def _lattice_table() -> tuple[np.ndarray, np.ndarray]:
    """For each of the 27 lattice points (i, j, k) in {0,1,2}^3: (kind, local index).

    kind 0 = coarse corner (index: VTK corner), 1 = edge (index into HEX_EDGES),
    2 = face (index into HEX_FACES), 3 = cell centre (index 0).
    """
    edges = {frozenset(e): n for n, e in enumerate(HEX_EDGES.tolist())}
    faces = {frozenset(f): n for n, f in enumerate(HEX_FACES.tolist())}
    kind = np.zeros((3, 3, 3), dtype=np.int64)
    index = np.zeros((3, 3, 3), dtype=np.int64)
    for i in range(3):
        for j in range(3):
            for k in range(3):
                choices = [(0, 1) if t == 1 else (t // 2,) for t in (i, j, k)]
                corners = frozenset(
                    HEX_VTK_CORNER[(a, b, c)]
                    for a in choices[0]
                    for b in choices[1]
                    for c in choices[2]
                )
                n_mid = (i == 1) + (j == 1) + (k == 1)
                kind[i, j, k] = n_mid
                if n_mid == 0:
                    index[i, j, k] = next(iter(corners))
                elif n_mid == 1:
                    index[i, j, k] = edges[corners]
                elif n_mid == 2:
                    index[i, j, k] = faces[corners]
    return kind, index


def _children_lattice() -> np.ndarray:
    """(8 children, 8 VTK nodes, 3) lattice coordinates; child c contains coarse corner c."""
    out = np.zeros((8, 8, 3), dtype=np.int64)
    for child in range(8):
        p, q, r = _REF_OF[child]
        for node in range(8):
            a, b, c = _REF_OF[node]
            out[child, node] = (p + a, q + b, r + c)
    return out


_KIND, _INDEX = _lattice_table()
_CHILDREN = _children_lattice()


@dataclass
class RefinedMesh:
    """A 2x2x2-refined hexahedral mesh and its relation to the coarse mesh.

    mesh:          the refined MeshData (see the module docstring for numbering).
    parent_cell:   (8M,) coarse cell row of every refined cell.
    node_parents:  for every new node (refined rows N, N+1, ...), the array of
                   coarse corner rows it is the mean of (2, 4 or 8 of them).
    n_coarse_nodes: N; rows < N are the coarse nodes, unchanged.
    edge_parents, face_parents, centre_parents: the same parents grouped,
                   (E, 2), (F, 4), (M, 8), for new rows N.., N+E.., N+E+F..
    """

    mesh: MeshData
    parent_cell: np.ndarray
    node_parents: list[np.ndarray]
    n_coarse_nodes: int
    edge_parents: np.ndarray = field(repr=False, default=None)
    face_parents: np.ndarray = field(repr=False, default=None)
    centre_parents: np.ndarray = field(repr=False, default=None)


def refine_hexahedra(md: MeshData) -> RefinedMesh:
    """Split every hexahedron of ``md`` into 8 conforming children (module docstring)."""
    if md.cell_type != "hexahedron":
        raise MeshError(
            f"{md.source}: refine_hexahedra needs a hexahedral mesh, got {md.cell_type}"
        )
    if md.is_mixed:
        raise MeshError(f"{md.source}: cannot refine a mixed mesh ({', '.join(md.cells_by_type)})")
    cells = md.cells
    m, n = len(cells), len(md.points)
    repeated = np.flatnonzero(np.array([len(np.unique(c)) < 8 for c in cells], dtype=bool))
    if repeated.size:
        raise MeshError(
            f"{md.source}: cannot refine hexahedra with repeated nodes (degenerate): "
            f"elements {md.cell_ids[repeated[:20]].tolist()}"
        )

    edge_keys = np.sort(cells[:, HEX_EDGES], axis=2).reshape(-1, 2)  # (12M, 2)
    face_keys = np.sort(cells[:, HEX_FACES], axis=2).reshape(-1, 4)  # (6M, 4)
    edge_parents, edge_of = np.unique(edge_keys, axis=0, return_inverse=True)
    face_parents, face_of = np.unique(face_keys, axis=0, return_inverse=True)
    edge_of = edge_of.reshape(m, 12)
    face_of = face_of.reshape(m, 6)
    n_e, n_f = len(edge_parents), len(face_parents)
    centre_parents = np.sort(cells, axis=1)

    points = np.concatenate(
        [
            md.points,
            md.points[edge_parents].mean(axis=1),
            md.points[face_parents].mean(axis=1),
            md.points[cells].mean(axis=1),
        ]
    )

    # Refined row of every lattice point of every cell: (M, 3, 3, 3).
    lattice = np.empty((m, 3, 3, 3), dtype=np.int64)
    for i in range(3):
        for j in range(3):
            for k in range(3):
                kind, idx = _KIND[i, j, k], _INDEX[i, j, k]
                if kind == 0:
                    lattice[:, i, j, k] = cells[:, idx]
                elif kind == 1:
                    lattice[:, i, j, k] = n + edge_of[:, idx]
                elif kind == 2:
                    lattice[:, i, j, k] = n + n_e + face_of[:, idx]
                else:
                    lattice[:, i, j, k] = n + n_e + n_f + np.arange(m)
    ch = _CHILDREN
    new_cells = lattice[:, ch[..., 0], ch[..., 1], ch[..., 2]].reshape(8 * m, 8)

    first_new = int(md.node_ids.max()) + 1 if n else 1
    node_ids = np.concatenate([md.node_ids, first_new + np.arange(len(points) - n, dtype=np.int64)])
    mesh = MeshData(
        points=points,
        cell_type="hexahedron",
        cells=new_cells,
        node_ids=node_ids,
        cell_ids=np.arange(1, 8 * m + 1),
        cell_tags=np.repeat(md.cell_tags, 8),
        source=f"{md.source} (refined 2x2x2)" if md.source else "refined 2x2x2",
    )
    node_parents = (
        [row for row in edge_parents]
        + [row for row in face_parents]
        + [row for row in centre_parents]
    )
    return RefinedMesh(
        mesh=mesh,
        parent_cell=np.repeat(np.arange(m), 8),
        node_parents=node_parents,
        n_coarse_nodes=n,
        edge_parents=edge_parents,
        face_parents=face_parents,
        centre_parents=centre_parents,
    )


def carry_node_set(refined: RefinedMesh, rows) -> np.ndarray:
    """Refined rows of a coarse node set S: S itself plus every new node whose parents all lie in S.

    E.g. fixed (attached) nodes: an edge midpoint between two fixed nodes, or
    a face centre of a face with four fixed corners, is fixed too.  Note that
    the rule also takes an edge or face whose corners are in S but which is
    not on the surface patch S describes (say an interior edge between two
    surface nodes); the tongue test checks that this does not happen there.
    """
    rows = np.unique(np.asarray(rows, dtype=np.int64).ravel())
    n = refined.n_coarse_nodes
    if rows.size and (rows.min() < 0 or rows.max() >= n):
        raise MeshError(f"carry_node_set: rows outside the {n} coarse nodes")
    inside = np.zeros(n, dtype=bool)
    inside[rows] = True
    parts = [rows]
    offset = n
    for parents in (refined.edge_parents, refined.face_parents, refined.centre_parents):
        parts.append(offset + np.flatnonzero(inside[parents].all(axis=1)))
        offset += len(parents)
    return np.concatenate(parts)


def carry_cell_set(refined: RefinedMesh, rows) -> np.ndarray:
    """Refined rows of the children of the given coarse cell rows (sorted)."""
    rows = np.unique(np.asarray(rows, dtype=np.int64).ravel())
    m = len(refined.parent_cell) // 8
    if rows.size and (rows.min() < 0 or rows.max() >= m):
        raise MeshError(f"carry_cell_set: rows outside the {m} coarse cells")
    return (8 * rows[:, None] + np.arange(8)[None, :]).ravel()
