"""The slip of friction rows over a static load increment (statics' anchored friction).

A friction row of the step (:mod:`~artifem.multibody.constraint_rows`) asks G z+ = 0
while it sticks: no tangential velocity over the step. Statics has no velocity; asked of
each Newton correction (G dq = 0), sticking would hold a contact point wherever the last
iterate left it, and every iterate would be an equilibrium of another problem: the
active set of a foot standing on the floor circled between two sets of sliding points
(the merit 22, 37, 22, ...; scripts/static_newton_counts.py ``foot_standing_auto``).
Statics asks it of the whole increment instead (the tangential gap measured from the
sticking point, as in the incremental friction laws of computational contact mechanics,
e.g. Wriggers 2006): with

    s = sum of G dq over the increment's Newton steps    (the row's slip, by row keys)

a sticking row asks s + G dq = 0 (its point back where the increment found it) and a
sliding row's force opposes the slip of the increment, not of one correction. s is the
rows' motion to first order in each step: exact for a node on a plane (its tangents are
fixed), to second order in the rotation for a rigid body's point. A row that appears in
the increment (a point that came into contact) starts from s = 0 where it appeared; a
mesh contact's key names the triangle, so a point that slides onto another one starts
again from there.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artifem.scene.constraints import find_keys, row_keys

__all__ = ["IncrementSlip"]


class IncrementSlip:
    """The slip s of each friction row since the load increment began (module
    docstring), by row keys, per constraint. Rows without keys, and the other rows, have
    none."""

    def __init__(self, slips: dict | None = None):
        self._slips = {} if slips is None else slips  # id(owner) -> (keys, s)

    def of(self, rows: list) -> np.ndarray:
        """s over the stacked rows (0 on rows that are not friction rows or not known)."""
        parts = []
        for g in rows:
            s = np.zeros(len(g.c))
            keys = row_keys(g.block)
            known = self._slips.get(id(g.block.owner))
            if keys is not None and known is not None:
                found, hit = find_keys(known[0], keys)
                s[hit] = known[1][found[hit]]
            parts.append(s)
        return np.concatenate(parts) if parts else np.zeros(0)

    def anchored(self, rows: list) -> list:
        """The rows with their friction rows' right-hand side c - s: a sticking row
        returns to where the increment found it."""
        out, start = [], 0
        s = self.of(rows)
        for g in rows:
            m = len(g.c)
            part = s[start : start + m]
            out.append(replace(g, c=g.c - part) if np.any(part) else g)
            start += m
        return out

    def advanced(self, rows: list, motion: np.ndarray) -> IncrementSlip:
        """The slip after a step that moves the stacked ``rows`` by ``motion`` = G dq:
        s + G dq on their friction rows."""
        s = self.of(rows) + motion
        slips, start = {}, 0
        for g in rows:
            m = len(g.c)
            keys = row_keys(g.block)
            if keys is not None and g.block.friction is not None:
                on = g.block.friction.rows
                moved = s[start : start + m]
                prev = slips.get(id(g.block.owner))
                part = (keys[on], moved[on])
                slips[id(g.block.owner)] = (
                    part
                    if prev is None
                    else (np.concatenate([prev[0], part[0]]), np.concatenate([prev[1], part[1]]))
                )
            start += m
        return IncrementSlip(slips)

    def take(self, other: IncrementSlip) -> None:
        """Become ``other`` (a step's :meth:`advanced` slip, once the step is taken)."""
        self._slips = other._slips
