"""In-memory volume mesh as read from a file, before conversion to DOLFINx.

Node ordering convention: ``MeshData.cells`` uses the VTK ordering, which for
the 8-node hexahedron is also the ANSYS SOLID185 / gmsh ordering
(I,J,K,L = bottom face counter-clockwise seen from the top, M,N,O,P = top
face above them).  DOLFINx/basix number hexahedron vertices in tensor-product
order instead; :mod:`artifem.io.to_dolfinx` applies the permutation.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from artifem.errors import MeshError, MeshFileNotFoundError

#: Volume cell types MeshData can hold, with their number of vertices.
VERTICES_PER_CELL = {"hexahedron": 8, "tetrahedron": 4}


def require_file(path: str | Path, what: str = "mesh file") -> Path:
    """Return ``path`` as a Path, or raise MeshFileNotFoundError naming it."""
    path = Path(path)
    if not path.is_file():
        raise MeshFileNotFoundError(f"{what} not found: {path}")
    return path


#: The VTK hexahedron's vertex at each reference corner (a, b, c) in {0, 1}^3 (the order of
#: MeshData's hexahedra).
HEX_VTK_CORNER = {
    (0, 0, 0): 0,
    (1, 0, 0): 1,
    (1, 1, 0): 2,
    (0, 1, 0): 3,
    (0, 0, 1): 4,
    (1, 0, 1): 5,
    (1, 1, 1): 6,
    (0, 1, 1): 7,
}


@dataclass
class MeshData:
    """A single-cell-type volume mesh with the ids and tags of its source file.

    Attributes:
        points: (N, 3) float64 node coordinates.
        cell_type: "hexahedron" or "tetrahedron" (the type of ``cells``).
        cells: (M, k) int64 row indices into ``points``, VTK node ordering.
        node_ids: (N,) int64 node ids of the file (ANSYS ids, or 0..N-1).
        cell_ids: (M,) int64 element ids of the file (ANSYS ids, or 0..M-1).
        cell_tags: (M,) int32 region tags (ANSYS material, gmsh physical group, or 0).
        source: file the mesh came from.
        cells_by_type: every volume cell block kept from the file, by type; it has more
            than one entry only for mixed meshes, which can be inspected but not converted
            to DOLFINx.
        skipped_cells: number of cells of each type the reader did not keep
            (surface/line/point cells, or volume types other than linear hex/tet).
    """

    points: np.ndarray
    cell_type: str
    cells: np.ndarray
    node_ids: np.ndarray
    cell_ids: np.ndarray
    cell_tags: np.ndarray
    source: str = ""
    cells_by_type: dict[str, np.ndarray] = field(default_factory=dict)
    skipped_cells: dict[str, int] = field(default_factory=dict)

    def __post_init__(self):
        self.points = np.ascontiguousarray(self.points, dtype=np.float64)
        self.cells = np.ascontiguousarray(self.cells, dtype=np.int64)
        self.node_ids = np.asarray(self.node_ids, dtype=np.int64)
        self.cell_ids = np.asarray(self.cell_ids, dtype=np.int64)
        self.cell_tags = np.asarray(self.cell_tags, dtype=np.int32)
        if self.cell_type not in VERTICES_PER_CELL:
            raise MeshError(
                f"{self.source}: unsupported cell type {self.cell_type!r}; "
                f"supported: {', '.join(VERTICES_PER_CELL)}"
            )
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise MeshError(f"{self.source}: points must be (N, 3), got {self.points.shape}")
        k = VERTICES_PER_CELL[self.cell_type]
        if self.cells.ndim != 2 or self.cells.shape[1] != k:
            raise MeshError(
                f"{self.source}: {self.cell_type} cells must be (M, {k}), got {self.cells.shape}"
            )
        m, n = len(self.cells), len(self.points)
        for name, arr, size in (
            ("node_ids", self.node_ids, n),
            ("cell_ids", self.cell_ids, m),
            ("cell_tags", self.cell_tags, m),
        ):
            if arr.shape != (size,):
                raise MeshError(f"{self.source}: {name} must have shape ({size},), got {arr.shape}")
        if m and (self.cells.min() < 0 or self.cells.max() >= n):
            raise MeshError(f"{self.source}: cell connectivity indexes outside the {n} points")
        if not self.cells_by_type:
            self.cells_by_type = {self.cell_type: self.cells}

    @property
    def is_mixed(self) -> bool:
        """True when the file holds more than one volume cell type."""
        return len(self.cells_by_type) > 1

    @property
    def skipped_volume_cells(self) -> dict[str, int]:
        """Skipped cells that carry volume (wedges, pyramids, quadratic cells...)."""
        lower_dim = ("vertex", "line", "triangle", "quad", "polygon")
        return {t: n for t, n in self.skipped_cells.items() if not t.startswith(lower_dim)}

    def element_label(self, index: int) -> str:
        """Human-readable name of the element in row ``index``: its file id."""
        return f"element {int(self.cell_ids[index])}"

    def node_rows(self, ids) -> np.ndarray:
        """Row (input) indices of the nodes with the given file ids; unknown ids are an error."""
        return _rows_of(self.node_ids, ids, f"{self.source or 'mesh'}: node")

    def cell_rows(self, ids) -> np.ndarray:
        """Row (input) indices of the elements with the given file ids; unknown ids are an error."""
        return _rows_of(self.cell_ids, ids, f"{self.source or 'mesh'}: element")


def _rows_of(file_ids: np.ndarray, ids, what: str) -> np.ndarray:
    ids = np.asarray(ids, dtype=np.int64).ravel()
    order = np.argsort(file_ids)
    pos = np.searchsorted(file_ids, ids, sorter=order)
    pos = np.minimum(pos, len(file_ids) - 1)
    rows = order[pos]
    unknown = ids[file_ids[rows] != ids]
    if unknown.size:
        raise MeshError(f"{what} ids not in the mesh: {unknown[:20].tolist()}")
    return rows
