"""Read a volume mesh from any supported file into MeshData, dispatching on the extension.

.node/.elem  ArtiSynth ANSYS pair (either file may be given; the other is found beside it)
.msh         gmsh (physical groups become cell tags)
.geo         gmsh geometry: meshed in 3D by gmsh, then read as .msh
others       every format meshio reads (.vtk, .vtu, .inp, .xdmf, .med, ...)

Only linear hexahedra and tetrahedra are kept; the number of other cells
(boundary triangles, lines, wedges, quadratic cells, ...) is recorded in
``MeshData.skipped_cells``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import meshio
import numpy as np

from artifem.io.ansys import read_ansys
from artifem.io.mesh_checks import reject_degenerate
from artifem.errors import MeshError
from artifem.io.mesh_data import MeshData, require_file

_MESHIO_TO_CELL_TYPE = {"hexahedron": "hexahedron", "tetra": "tetrahedron"}
_TAG_KEYS = ("gmsh:physical", "medit:ref", "CellEntityIds", "cell_tags", "material")
_ANSYS_SUFFIXES = (".node", ".elem")
_GMSH_SUFFIXES = (".msh", ".geo")


def supported_extensions() -> list[str]:
    """File extensions read_mesh accepts."""
    return sorted(set(_ANSYS_SUFFIXES) | set(_GMSH_SUFFIXES) | set(meshio.extension_to_filetypes))


def read_mesh(
    path: str | Path, allow_degenerate: bool = False, gmsh_mesh_size: float | None = None
) -> MeshData:
    """Read the volume mesh in ``path`` (format from its extension) into MeshData.

    Elements with repeated nodes raise MeshError unless ``allow_degenerate``;
    ``gmsh_mesh_size`` sets gmsh's maximum element size when meshing a .geo.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in _ANSYS_SUFFIXES:
        mesh = read_ansys(
            path.with_suffix(".node"), path.with_suffix(".elem"), allow_degenerate=True
        )
    elif suffix == ".geo":
        mesh = _read_geo(require_file(path), gmsh_mesh_size)
    elif suffix in meshio.extension_to_filetypes:
        mesh = _read_meshio(require_file(path))
    else:
        raise MeshError(
            f"{path}: unknown mesh file extension {suffix!r}; supported: "
            f"{', '.join(supported_extensions())}"
        )
    if not allow_degenerate:
        reject_degenerate(mesh)
    return mesh


def _read_geo(path: Path, mesh_size: float | None) -> MeshData:
    """Mesh a gmsh .geo in 3D with the gmsh API and read the resulting mesh. A caller's gmsh
    session is left as it was: its models, its current model and the options set here."""
    import gmsh

    started = not gmsh.isInitialized()
    if started:
        gmsh.initialize(interruptible=False)
    options = ("General.Terminal", "Mesh.MeshSizeMax")
    caller = (
        None if started else (gmsh.model.getCurrent(), [gmsh.option.getNumber(o) for o in options])
    )
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        # a model of its own: gmsh.open would replace the caller's models
        gmsh.model.add(f"artifem:{path.stem}")
        gmsh.merge(str(path))
        if mesh_size is not None:
            gmsh.option.setNumber("Mesh.MeshSizeMax", mesh_size)
        gmsh.model.mesh.generate(3)
        with tempfile.TemporaryDirectory() as tmp:
            msh = Path(tmp) / (path.stem + ".msh")
            gmsh.write(str(msh))
            mesh = _read_meshio(msh)
    except Exception as exc:
        if isinstance(exc, MeshError):
            raise
        raise MeshError(f"{path}: gmsh failed to mesh it: {exc}") from exc
    finally:
        gmsh.model.remove()  # the reader's model
        if started:
            gmsh.finalize()
        else:
            current, values = caller
            gmsh.model.setCurrent(current)
            for option, value in zip(options, values):
                gmsh.option.setNumber(option, value)
    mesh.source = str(path)
    return mesh


def _read_meshio(path: Path) -> MeshData:
    """Read a file with meshio and keep its linear hexahedra and tetrahedra."""
    try:
        m = meshio.read(path)
    except Exception as exc:
        raise MeshError(f"{path}: meshio could not read it: {exc}") from exc
    points = np.asarray(m.points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise MeshError(f"{path}: points are {points.shape[1]}D; a volume mesh needs 3D points")

    blocks: dict[str, list[np.ndarray]] = {}
    tags: dict[str, list[np.ndarray]] = {}
    skipped: dict[str, int] = {}
    tag_key = next((k for k in _TAG_KEYS if k in m.cell_data), None)
    for i, block in enumerate(m.cells):
        cell_type = _MESHIO_TO_CELL_TYPE.get(block.type)
        if cell_type is None:
            skipped[block.type] = skipped.get(block.type, 0) + len(block.data)
            continue
        blocks.setdefault(cell_type, []).append(np.asarray(block.data, dtype=np.int64))
        block_tags = (
            np.asarray(m.cell_data[tag_key][i]).reshape(-1)
            if tag_key
            else np.zeros(len(block.data))
        )
        tags.setdefault(cell_type, []).append(block_tags.astype(np.int32))
    if not blocks:
        raise MeshError(
            f"{path}: no hexahedra or tetrahedra found (cells in file: "
            f"{', '.join(f'{n} {t}' for t, n in skipped.items()) or 'none'})"
        )

    cells_by_type = {t: np.concatenate(b) for t, b in blocks.items()}
    primary = max(cells_by_type, key=lambda t: len(cells_by_type[t]))
    cells = cells_by_type[primary]
    return MeshData(
        points=points,
        cell_type=primary,
        cells=cells,
        node_ids=np.arange(len(points)),
        cell_ids=np.arange(len(cells)),
        cell_tags=np.concatenate(tags[primary]),
        source=str(path),
        cells_by_type=cells_by_type,
        skipped_cells=skipped,
    )
