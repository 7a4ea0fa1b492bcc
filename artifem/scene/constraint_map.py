"""The scene's constraints on the coupled island's coordinates.

Every constraint of the scene (``Scene.constraints``: the joints, with their limits)
gives its rows at the current state as :class:`~artifem.multibody.constraint_rows.RowBlock`
(rows G_k on each touched body's coordinates, phi, bounds on lambda). Placed at each
body's all-space offset (:meth:`~artifem.scene.layout.Layout.span`) they stack into
G (rows x n_all); the solve sees them on the masters,

    G_m = G P,     c = rhs(phi, h, beta) - G z_k        (z = P z_m + z_k),

one product for all constraints, whatever their kind (:meth:`ConstraintMap.rows`).
Back on the bodies, impulses lambda act as G^T lambda (:meth:`ConstraintMap.forces`)
and their rows' turn as d(G^T lambda)/dq (:meth:`ConstraintMap.stiffness`).
"""

from __future__ import annotations

import time

import numpy as np
from scipy import sparse

from artifem.errors import InputError
from artifem.scene.constraints import StepRows

__all__ = ["ConstraintMap"]


class ConstraintMap:
    """The constraints of ``layout``'s scene on its all-space coordinates (module docstring)."""

    def __init__(self, layout):
        self.layout = layout
        #: seconds of the last :meth:`rows`: "detection" (the constraints' row_blocks,
        #: a contact's collision query) and "mapping" (G P and c)
        self.seconds: dict = {}

    def blocks(self) -> list:
        """The non-empty row blocks of every constraint at the current state."""
        return [
            block
            for constraint in self.layout.scene.constraints
            for block in constraint.row_blocks()
            if len(block)
        ]

    def _placed(self, block):
        """(all-space offset, G_k) of the block's bodies (the world left out)."""
        out = []
        for body, G in block.jacobians:
            if body is None:
                continue
            span = self.layout.span(body)
            if span is None or span[1] != G.shape[1]:
                raise InputError(
                    f"constraint {getattr(block.owner, 'name', block.owner)!r}: "
                    f"rows on {getattr(body, 'name', body)!r}, which is not a "
                    "body of this island or has another number of coordinates"
                )
            out.append((span[0], G))
        return out

    def rows(self, P, z_k: np.ndarray, h: float, beta: float) -> list[StepRows]:
        """The blocks on the masters, G P, with their right-hand sides (module docstring);
        every block is mapped by P in one product."""
        L = self.layout
        tic = time.perf_counter()
        blocks = self.blocks()
        toc = time.perf_counter()
        self.seconds = {"detection": toc - tic, "mapping": 0.0}
        if not blocks:
            return []
        parts, start = [], 0
        for block in blocks:
            for o, G_body in self._placed(block):
                G_body = sparse.coo_matrix(G_body)  # dense or sparse rows
                parts.append((G_body.data, start + G_body.row, o + G_body.col))
            start += len(block)
        G = L.triplets(parts, (start, L.n_all))
        GP, Gz = L.fmt(G @ P), G @ z_k
        out, start = [], 0
        for block in blocks:
            s1 = start + len(block)
            # compliant rows: C / h^2 on the multiplier block (constraint_rows docstring)
            C = None if block.compliance is None else np.asarray(block.compliance) / h**2
            out.append(StepRows(block, GP[start:s1], block.rhs(h, beta) - Gz[start:s1], C))
            start = s1
        self.seconds["mapping"] = time.perf_counter() - toc
        return out

    def forces(self, impulses) -> np.ndarray:
        """sum G^T lambda over (RowBlock, lambda) pairs, all-space."""
        out = np.zeros(self.layout.n_all)
        for block, lam in impulses:
            for o, G in self._placed(block):
                out[o : o + G.shape[1]] += np.asarray(G.T @ lam).ravel()
        return out

    def stiffness(self, rows: list, lam: np.ndarray):
        """d(G^T lambda)/dq (all-space) of ``rows`` (:class:`StepRows`) at fixed impulses
        ``lam`` (in their order): each block's ``stiffness(lambda)`` (dense or sparse)
        placed on its bodies."""
        L = self.layout
        parts, start = [], 0
        for g in rows:
            block = g.block
            part = lam[start : start + len(block)]
            start += len(block)
            if not np.any(part):
                continue
            K = block.stiffness(part)
            cols = np.cumsum([0] + [G.shape[1] for _, G in block.jacobians])
            spans = [None if body is None else L.span(body) for body, _ in block.jacobians]
            for i, si in enumerate(spans):
                for j, sj in enumerate(spans):
                    if si is None or sj is None:
                        continue
                    sub = sparse.coo_matrix(K[cols[i] : cols[i + 1], cols[j] : cols[j + 1]])
                    parts.append((sub.data, si[0] + sub.row, sj[0] + sub.col))
        return L.triplets(parts, (L.n_all, L.n_all))
