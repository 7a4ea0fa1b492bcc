"""Reader for ArtiSynth's ANSYS .node/.elem mesh files (8-node SOLID185 hexahedra).

.node: one node a line, ``id x y z``.
.elem: one element a line, ``I J K L M N O P  MAT TYPE REAL SECNUM ESYS  ID``
(the ANSYS EWRITE layout: 8 node ids, 5 attribute columns, the element id).
The MAT column becomes ``MeshData.cell_tags``.  The node order I..P is the
SOLID185 order, which equals the VTK hexahedron order that MeshData stores.
Blank lines and lines starting with ``!`` or ``#`` are ignored.

Non-solid elements (shells, links, beams, surface and mass elements) share the
file: ANSYS writes their unused node slots as id 0, which no node has. They are
skipped and counted in ``MeshData.skipped_cells`` by their number of nodes (1:
vertex, 2: line, 3: triangle, 4: quad); the solids are read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from artifem.io.mesh_checks import reject_degenerate
from artifem.errors import MeshError
from artifem.io.mesh_data import MeshData, require_file

#: Columns of an .elem line: 8 node ids, MAT, TYPE, REAL, SECNUM, ESYS, element id.
ELEM_COLUMNS = 14
MATERIAL_COLUMN = 8
#: Kind of a zero-padded (non-solid) element by its number of distinct nodes.
PADDED_KIND = {
    1: "vertex (mass element)",
    2: "line (link or beam)",
    3: "triangle (shell)",
    4: "quad (shell or surface)",
}


def _data_lines(path: Path):
    """Yield (line number, whitespace-split fields) of the non-comment lines of a file."""
    with open(path) as f:
        for lineno, line in enumerate(f, start=1):
            fields = line.split()
            if fields and not fields[0].startswith(("!", "#")):
                yield lineno, fields


def _parse_int(text: str, path: Path, lineno: int, what: str) -> int:
    """Parse an integer field, or raise MeshError naming file, line and field."""
    try:
        return int(text)
    except ValueError:
        raise MeshError(f"{path}:{lineno}: {what} is not an integer: {text!r}") from None


def read_ansys_nodes(node_path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read an ANSYS .node file; return (node ids (N,), coordinates (N, 3)) in file order."""
    path = require_file(node_path, "ANSYS node file")
    ids, coords, line_of_id = [], [], {}
    for lineno, fields in _data_lines(path):
        if len(fields) != 4:
            raise MeshError(f"{path}:{lineno}: expected 4 columns (id x y z), found {len(fields)}")
        node_id = _parse_int(fields[0], path, lineno, "node id")
        try:
            xyz = [float(v) for v in fields[1:]]
        except ValueError:
            raise MeshError(
                f"{path}:{lineno}: node {node_id} has a non-numeric coordinate: "
                f"{' '.join(fields[1:])!r}"
            ) from None
        if node_id in line_of_id:
            raise MeshError(
                f"{path}:{lineno}: node id {node_id} already defined at line {line_of_id[node_id]}"
            )
        line_of_id[node_id] = lineno
        ids.append(node_id)
        coords.append(xyz)
    if not ids:
        raise MeshError(f"{path}: no nodes found")
    return np.array(ids, dtype=np.int64), np.array(coords, dtype=np.float64)


def read_ansys(
    node_path: str | Path, elem_path: str | Path | None = None, allow_degenerate: bool = False
) -> MeshData:
    """Read an ANSYS .node/.elem pair into MeshData (hexahedra, VTK = SOLID185 order).

    ``elem_path`` defaults to ``node_path`` with the suffix ``.elem``.  Hexahedra
    with repeated node ids (collapsed to wedges, pyramids or tetrahedra) are
    rejected with their element ids unless ``allow_degenerate`` is true.
    Zero-padded (non-solid) elements are skipped and counted in ``skipped_cells``.
    """
    node_path = Path(node_path)
    elem_path = Path(elem_path) if elem_path is not None else node_path.with_suffix(".elem")
    require_file(node_path, "ANSYS node file")
    elem_path = require_file(elem_path, "ANSYS element file")
    node_ids, points = read_ansys_nodes(node_path)
    row_of_node = {int(i): row for row, i in enumerate(node_ids)}

    cells, cell_ids, tags, line_of_elem, skipped = [], [], [], {}, {}
    for lineno, fields in _data_lines(elem_path):
        if len(fields) != ELEM_COLUMNS:
            raise MeshError(
                f"{elem_path}:{lineno}: expected {ELEM_COLUMNS} columns (8 node ids, "
                f"MAT TYPE REAL SECNUM ESYS, element id), found {len(fields)}; only 8-node "
                f"hexahedra on one line each are supported"
            )
        values = [_parse_int(v, elem_path, lineno, f"column {c + 1}") for c, v in enumerate(fields)]
        elem_id = values[-1]
        if elem_id in line_of_elem:
            raise MeshError(
                f"{elem_path}:{lineno}: element id {elem_id} already defined "
                f"at line {line_of_elem[elem_id]}"
            )
        line_of_elem[elem_id] = lineno
        nodes = [n for n in values[:8] if n != 0]  # 0 pads a non-solid element
        missing = [n for n in nodes if n not in row_of_node]
        if missing:
            raise MeshError(
                f"{elem_path}:{lineno}: element {elem_id} references node id(s) "
                f"{', '.join(map(str, missing))} not defined in {node_path}"
            )
        if len(nodes) < 8:
            kind = PADDED_KIND.get(len(set(nodes)), f"zero-padded {len(set(nodes))}-node element")
            skipped[kind] = skipped.get(kind, 0) + 1
            continue
        cells.append([row_of_node[n] for n in values[:8]])
        cell_ids.append(elem_id)
        tags.append(values[MATERIAL_COLUMN])
    if not cells:
        others = ", ".join(f"{n} {t}" for t, n in skipped.items())
        raise MeshError(
            f"{elem_path}: no solid (8-node) elements found"
            + (f"; only non-solid ones: {others}" if others else "")
        )

    mesh = MeshData(
        points=points,
        cell_type="hexahedron",
        cells=np.array(cells, dtype=np.int64),
        node_ids=node_ids,
        cell_ids=np.array(cell_ids, dtype=np.int64),
        cell_tags=np.array(tags, dtype=np.int32),
        source=str(elem_path),
        skipped_cells=skipped,
    )
    if not allow_degenerate:
        reject_degenerate(mesh)
    return mesh
