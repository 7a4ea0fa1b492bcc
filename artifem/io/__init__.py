"""Meshes in (readers, checks, the DOLFINx mesh) and results out.

from artifem.io import read_mesh, MeshData, check_orientation, to_dolfinx
"""

from artifem import lazy_exports

#: public name -> the module that defines it
_PUBLIC = {
    "read_mesh": "artifem.io.readers",
    "read_ansys": "artifem.io.ansys",
    "MeshData": "artifem.io.mesh_data",
    **dict.fromkeys(
        ["check_orientation", "degenerate_elements", "element_volumes"], "artifem.io.mesh_checks"
    ),
    "spherical_shell_octant": "artifem.io.shell_mesh",
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, globals(), _PUBLIC)
