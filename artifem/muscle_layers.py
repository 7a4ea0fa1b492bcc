"""A body's muscles merged into a few integrals: one per layer of disjoint cells.

Each muscle of a :class:`~artifem.fem_body.FemBody` is an integral of its fiber energy
W(F; a0, a) over its own cells, with its own direction field a0, excitation a and
parameters. FFCx generates one kernel per integral, each a full copy of the fiber
energy's tangent: the tongue's 21 bundles made a 5.4 MB C file that took about 20 s to
compile, for every variant of the model.

Muscles whose fibers differ only in the parameters that enter the energy as factors
(``form_constants``, e.g. BlemkerFiber's max_stress) and whose directions live in the same
space are merged here: the (cell, muscle) pairs are dealt into layers, each cell at most
once per layer (a cell in k muscles lands in k layers), and a layer is one integral

    int_{cells of the layer} W(F; a0_L, a_L; c_L) dX,

with a0_L, a_L and every form constant c_L cell-wise fields that hold, on each cell, the
values of the muscle that owns it in that layer. The sum over layers is the sum over
muscles, term by term, at every quadrature point; the kernels are one per layer (three for
the tongue). The excitations stay the muscles' own ``fem.Constant`` objects: the layers'
fields are refreshed from them before each assembly (:meth:`MuscleLayers.refresh`).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable

import numpy as np
from petsc4py import PETSc

from dolfinx import fem

from artifem.errors import InputError

__all__ = ["MuscleLayers"]


def _kind(muscle) -> tuple:
    """What must be equal for two muscles to share a layer: the fiber without its form
    constants, and the direction's element."""
    fiber = muscle.fiber
    names = getattr(fiber, "form_constants", ())
    if dataclasses.is_dataclass(fiber):
        fiber = copy.copy(fiber)
        for name in names:
            object.__setattr__(fiber, name, None)
        key = repr(fiber)
    else:
        key = id(muscle)  # anything else: an integral of its own
    return key, repr(muscle.direction.function_space.ufl_element())


class MuscleLayers:
    """The muscles of ``body`` dealt into layers (module docstring); ``terms`` gives one
    (density, cells, direction) per layer. The layers' excitations are the muscles' times
    the body's :attr:`~artifem.fem_body.FemBody.activation_factor` (a static solve ramps
    the activation with the loads; 1 otherwise)."""

    def __init__(self, body):
        self.layers = []
        mesh = body.mesh
        Q = fem.functionspace(mesh, ("DG", 0))
        groups: dict[tuple, list] = {}
        for muscle in body.muscles.values():
            groups.setdefault(_kind(muscle), []).append(muscle)
        for muscles in groups.values():
            taken: list[set] = []  # cells of each layer of this group
            pairs: list[list] = []  # (cell, muscle index) of each layer
            for k, muscle in enumerate(muscles):
                for cell in muscle.cells.tolist():
                    depth = next(
                        (d for d, cells in enumerate(taken) if cell not in cells), len(taken)
                    )
                    if depth == len(taken):
                        taken.append(set())
                        pairs.append([])
                    taken[depth].add(cell)
                    pairs[depth].append((cell, k))
            for layer in pairs:
                layer.sort()
                cells = np.array([c for c, _ in layer], dtype=np.int32)
                owner = np.array([k for _, k in layer], dtype=np.int64)
                self.layers.append(_Layer(muscles, cells, owner, Q, body.activation_factor))

    def refresh(self) -> None:
        """Copy the muscles' excitations into the layers' fields."""
        for layer in self.layers:
            layer.refresh()

    def terms(self) -> list[tuple]:
        """(density(F, a0), cells, direction, fields_at) of each layer
        (:meth:`_Layer.fields_at`)."""
        return [
            (layer.density, layer.cells, layer.direction, layer.fields_at) for layer in self.layers
        ]


class _Layer:
    """One integral: cells, the owning muscle of each, and the cell-wise fields."""

    def __init__(self, muscles: list, cells: np.ndarray, owner: np.ndarray, Q, activation):
        self.muscles, self.cells, self.owner = muscles, cells, owner
        self.activation = activation  # the body's activation factor
        W = muscles[0].direction.function_space
        bs = W.dofmap.index_map_bs
        self.direction = fem.Function(W, name="layer fiber direction")
        target = self.direction.x.array.reshape(-1, bs)
        for k, muscle in enumerate(muscles):
            mine = cells[owner == k]
            source = muscle.direction
            target[W.dofmap.list[mine]] = source.x.array.reshape(-1, bs)[
                source.function_space.dofmap.list[mine]
            ]
        self.direction.x.scatter_forward()
        self._dofs = Q.dofmap.list[cells, 0]
        self.excitation = fem.Function(Q, name="layer excitation")
        fiber = copy.copy(muscles[0].fiber)
        self._constants = {}  # cell-wise form constant -> value per muscle
        for name in getattr(fiber, "form_constants", ()):
            field = fem.Function(Q, name=f"layer {name}")
            values = np.array(
                [float(getattr(m.fiber, name)) for m in muscles], dtype=PETSc.ScalarType
            )
            field.x.array[self._dofs] = values[owner]
            self._constants[field] = values
            object.__setattr__(fiber, name, field)
        self.fiber = fiber
        self._excitation_values = [m.excitation.value for m in muscles]
        self.refresh()

    def _excitations(self) -> np.ndarray:
        # views of the Constants' values (a Constant's value is updated in place)
        return np.array([float(v) for v in self._excitation_values])

    def refresh(self) -> None:
        self.excitation.x.array[self._dofs] = self._excitations()[self.owner]

    def fields_at(self, cells: np.ndarray) -> tuple[dict, Callable[[], dict]]:
        """The layer's cell-wise fields at ``cells`` (cells of the layer, e.g. those of a
        reduced body's points), without the full mesh: ({form constant field: values},
        a callable returning {excitation field: the muscles' current excitations}); O(len
        (cells)) each, for evaluations at a few points."""
        cells = np.asarray(cells)
        pos = np.minimum(np.searchsorted(self.cells, cells), self.cells.size - 1)
        if not np.array_equal(self.cells[pos], cells):
            raise InputError("fields_at: cells outside the muscle layer")
        owner = self.owner[pos]
        static = {field: values[owner] for field, values in self._constants.items()}
        return static, lambda: {self.excitation: self._excitations()[owner]}

    def density(self, F, a0):
        return self.fiber.strain_energy(F, a0, self.activation * self.excitation)
