"""The integration points of a body's internal energy: the candidates of a cubature.

Every :class:`~artifem.fem_body.EnergyTerm` of a FEM body is integrated with a
quadrature rule of its own degree (2x2x2 Gauss for the hexahedral strain
energy, the one-point centre rule for the incompressibility penalty). Point c
of the table lies in a local cell, carries the full quadrature's weight
``volume[c] = w_q |det J(xi_q)|`` and the gradients of the cell's shape
functions, so that at that point

    grad u (X_c) = sum_a u_{dofs[c, a]} (x) grad_N[c, a],   F = I + grad u.

A reduced body keeps m of these points with cubature weights; with all of
them and weights 1 it integrates exactly what DOLFINx assembles (the same
basix rules).
"""

from __future__ import annotations

from dataclasses import dataclass

import basix
import numpy as np

from artifem.errors import InputError
from artifem.fem_body import FemBody

__all__ = ["QuadraturePoints", "quadrature_points"]


@dataclass(frozen=True)
class QuadraturePoints:
    """All energy integration points of a body's owned cells (see the module docstring)."""

    cell: np.ndarray  # (C,) owned local cell
    degree: np.ndarray  # (C,) degree of the rule the point belongs to
    volume: np.ndarray  # (C,) w_q |det J|
    dofs: np.ndarray  # (C, k) local block dofs of the cell
    grad_N: np.ndarray  # (C, k, 3) reference-configuration shape function gradients
    N: np.ndarray  # (C, k) shape function values (u(X_c) = sum_a u_{dofs[c, a]} N[c, a])

    @property
    def size(self) -> int:
        return int(self.cell.size)

    def of_term(self, term) -> np.ndarray:
        """Indices of the points where ``term`` (an EnergyTerm) is integrated."""
        mask = self.degree == term.degree
        if term.cells is not None:
            mask &= np.isin(self.cell, term.cells)
        return np.flatnonzero(mask)


def quadrature_points(body: FemBody) -> QuadraturePoints:
    """The table of every energy integration point of ``body``, ordered by (degree, cell, point)."""
    msh = body.mesh
    cell_type = getattr(basix.CellType, body.cell_name)
    n_cells = msh.topology.index_map(msh.topology.dim).size_local
    x = msh.geometry.x[msh.geometry.dofmaps[0][:n_cells]]  # (cells, k, 3)
    dofs = body.V.dofmap.list[:n_cells]  # same local order
    lagrange = basix.create_element(basix.ElementFamily.P, cell_type, 1)
    parts = []
    for degree in sorted({t.degree for t in body.energy_terms()}):
        pts, wts = basix.make_quadrature(cell_type, degree)
        tab = lagrange.tabulate(1, pts)[:, :, :, 0]
        N, dN = tab[0], tab[1:4]  # (q, k), (3, q, k) d/dxi
        J = np.einsum("cai,jqa->cqij", x, dN)  # dx_i/dxi_j
        detJ = np.linalg.det(J)
        if np.any(detJ <= 0):
            bad = body.input_cell_index(np.unique(np.nonzero(detJ <= 0)[0]))
            raise InputError(f"quadrature_points: det J <= 0 in input elements {bad[:10].tolist()}")
        grad = np.einsum("cqji,jqa->cqai", np.linalg.inv(J), dN)  # J^-T dN/dxi
        nq = pts.shape[0]
        parts.append(
            (
                np.repeat(np.arange(n_cells), nq),
                np.full(n_cells * nq, degree),
                (detJ * wts).reshape(-1),
                np.repeat(dofs, nq, axis=0),
                grad.reshape(n_cells * nq, -1, 3),
                np.tile(N, (n_cells, 1)),
            )
        )
    cell, degree, volume, point_dofs, grad_N, N = (np.concatenate(a) for a in zip(*parts))
    return QuadraturePoints(cell, degree, volume, point_dofs.astype(np.int64), grad_N, N)
