"""Convert MeshData to a distributed DOLFINx mesh with region tags.

MeshData stores hexahedra in VTK (= ANSYS SOLID185 = gmsh) order: bottom face
0,1,2,3 counter-clockwise, top face 4,5,6,7 above it.  basix numbers the
vertices of the reference hexahedron in tensor-product order
(0,0,0),(1,0,0),(0,1,0),(1,1,0),(0,0,1),(1,0,1),(0,1,1),(1,1,1), so VTK
[0,1,2,3,4,5,6,7] -> DOLFINx [0,1,3,2,4,5,7,6].  Tetrahedra need no permutation.

Every rank passes the same MeshData (each reads the file); only rank 0 hands
its cells and points to dolfinx.mesh.create_mesh, which distributes them.
"""

from __future__ import annotations

import basix.ufl
import dolfinx.mesh
import numpy as np
from mpi4py import MPI

from artifem.io.mesh_checks import check_orientation, reject_degenerate
from artifem.errors import MeshError
from artifem.io.mesh_data import MeshData

#: Column permutation from VTK node order to DOLFINx/basix node order, per cell type.
VTK_TO_DOLFINX = {
    "hexahedron": np.array([0, 1, 3, 2, 4, 5, 7, 6]),
    "tetrahedron": np.array([0, 1, 2, 3]),
}


def to_dolfinx(
    mesh: MeshData, comm: MPI.Comm = MPI.COMM_WORLD, reorient: bool = True
) -> tuple[dolfinx.mesh.Mesh, dolfinx.mesh.MeshTags | None]:
    """Build (DOLFINx mesh, cell MeshTags of ``mesh.cell_tags``) from MeshData.

    Degenerate, tangled, duplicated and mixed-type meshes are refused with MeshError
    (two cells on the same vertices corrupt DOLFINx's topology computation).
    Inverted elements are renumbered when ``reorient`` (default) and refused
    otherwise.  The tags are None when every cell tag is 0 (no regions in the
    file).  Input cell rows are recovered with ``mesh.topology.original_cell_index``
    and input nodes with :func:`dolfinx_node_to_input`.
    """
    if mesh.is_mixed:
        counts = ", ".join(f"{len(c)} {t}" for t, c in mesh.cells_by_type.items())
        raise MeshError(
            f"{mesh.source}: mixed mesh ({counts}); DOLFINx conversion supports "
            f"a single cell type per mesh"
        )
    if mesh.skipped_volume_cells:
        counts = ", ".join(f"{n} {t}" for t, n in mesh.skipped_volume_cells.items())
        raise MeshError(
            f"{mesh.source}: has volume cells that are not linear hexahedra or "
            f"tetrahedra ({counts}); converting the rest would leave holes"
        )
    reject_degenerate(mesh)
    fixed, inverted = check_orientation(mesh, fix=reorient)
    _reject_duplicate_cells(mesh)
    if len(inverted) and not reorient:
        raise MeshError(
            f"{mesh.source}: {len(inverted)} inverted element(s) (negative det J "
            f"everywhere), ids {', '.join(map(str, inverted[:20]))}; "
            f"pass reorient=True to renumber them"
        )

    element = basix.ufl.element("Lagrange", mesh.cell_type, 1, shape=(3,))
    k = fixed.cells.shape[1]
    if comm.rank == 0:
        cells = fixed.cells[:, VTK_TO_DOLFINX[mesh.cell_type]]
        points = fixed.points
    else:
        cells = np.empty((0, k), dtype=np.int64)
        points = np.empty((0, 3), dtype=np.float64)
    msh = dolfinx.mesh.create_mesh(comm, cells, element, points)
    return msh, _cell_tags(msh, mesh.cell_tags)


def _reject_duplicate_cells(mesh: MeshData) -> None:
    """MeshError naming the elements that use the same vertex set as an earlier one."""
    keys = np.sort(np.asarray(mesh.cells), axis=1)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    duplicates = np.flatnonzero(first[inverse.ravel()] != np.arange(len(keys)))
    if duplicates.size:
        pairs = ", ".join(
            f"{mesh.element_label(d)} repeats {mesh.element_label(first[inverse.ravel()[d]])}"
            for d in duplicates[:10]
        )
        raise MeshError(
            f"{mesh.source}: {duplicates.size} element(s) on the same nodes as another: {pairs}"
        )


def _cell_tags(msh: dolfinx.mesh.Mesh, input_tags: np.ndarray) -> dolfinx.mesh.MeshTags | None:
    """Cell MeshTags from per-input-cell tags through original_cell_index, or None if all 0."""
    if not input_tags.any():
        return None
    tdim = msh.topology.dim
    num_local = msh.topology.index_map(tdim).size_local + msh.topology.index_map(tdim).num_ghosts
    local = np.arange(num_local, dtype=np.int32)
    values = input_tags[msh.topology.original_cell_index[:num_local]].astype(np.int32)
    tags = dolfinx.mesh.meshtags(msh, tdim, local, values)
    tags.name = "cell_tags"
    return tags


def dolfinx_node_to_input(msh: dolfinx.mesh.Mesh) -> np.ndarray:
    """Input point row (index into MeshData.points) of each local geometry node of ``msh``."""
    return np.asarray(msh.geometry.input_global_indices, dtype=np.int64)


def dolfinx_node_ids(msh: dolfinx.mesh.Mesh, mesh: MeshData) -> np.ndarray:
    """File node id (e.g. ANSYS id) of each local geometry node of ``msh``."""
    return mesh.node_ids[dolfinx_node_to_input(msh)]


def dolfinx_cell_ids(msh: dolfinx.mesh.Mesh, mesh: MeshData) -> np.ndarray:
    """File element id of each local cell (owned, then ghosts) of ``msh``."""
    return mesh.cell_ids[msh.topology.original_cell_index]
