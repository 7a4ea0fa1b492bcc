"""A structured hexahedral mesh of a spherical shell octant (analytic test problems).

The three faces of the cube corner max(i, j, k) = n are mapped onto the unit sphere by
the equal-angle (tangent) map, giving three patches of n x n quads, and swept radially
in ``layers`` layers from the inner to the outer radius: Q1 hexahedra filling
inner <= |X| <= outer, X >= 0, with the three symmetry planes X_k = 0 as faces.
"""

from __future__ import annotations

import basix.ufl
import numpy as np
from mpi4py import MPI

from dolfinx import mesh as dmesh

from artifem.errors import InputError

__all__ = ["spherical_shell_octant"]


def spherical_shell_octant(
    inner: float, outer: float, n: int, layers: int, comm=MPI.COMM_SELF
) -> dmesh.Mesh:
    """Q1 hexahedra of the octant shell inner <= |X| <= outer (module docstring)."""
    if not 0.0 < inner < outer or int(n) != n or n < 1 or int(layers) != layers or layers < 1:
        raise InputError(
            f"spherical_shell_octant: need 0 < inner < outer and n, layers >= 1 "
            f"integers, got {inner}, {outer}, {n}, {layers}"
        )
    index, grid = {}, []
    for ijk in np.ndindex(n + 1, n + 1, n + 1):
        if max(ijk) == n:
            index[ijk] = len(grid)
            grid.append(ijk)
    g = np.tan(0.25 * np.pi * np.array(grid, dtype=float) / n)
    directions = g / np.linalg.norm(g, axis=1)[:, None]
    quads = []
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        for s, t in np.ndindex(n, n):
            corners = []
            for ds, dt in ((0, 0), (1, 0), (0, 1), (1, 1)):
                key = [0, 0, 0]
                key[axis], key[a], key[b] = n, s + ds, t + dt
                corners.append(index[tuple(key)])
            quads.append(corners)
    radii = inner + (outer - inner) * np.arange(layers + 1) / layers
    x = (radii[:, None, None] * directions[None]).reshape(-1, 3)
    cells = []
    for layer in range(layers):
        for q in quads:
            c = [layer * len(grid) + k for k in q] + [(layer + 1) * len(grid) + k for k in q]
            if np.cross(x[c[1]] - x[c[0]], x[c[2]] - x[c[0]]) @ (x[c[4]] - x[c[0]]) < 0:
                c = [c[0], c[2], c[1], c[3], c[4], c[6], c[5], c[7]]  # right-handed
            cells.append(c)
    element = basix.ufl.element("Lagrange", "hexahedron", 1, shape=(3,))
    cells = np.array(cells, dtype=np.int64) if comm.rank == 0 else np.zeros((0, 8), np.int64)
    x = x if comm.rank == 0 else np.zeros((0, 3))
    return dmesh.create_mesh(comm, cells, element, x)
