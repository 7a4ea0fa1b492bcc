"""Evaluate a strain energy, its stress and its tangent at one homogeneous deformation.

The UFL energy psi(F; fields) of any material in ``artifem.forms`` is compiled
once with FFCx into a ``dolfinx.fem.Expression`` on a one-tetrahedron mesh
(COMM_SELF). F and the fields are ``fem.Constant`` values, so every later call
only copies numbers in and runs the compiled kernel:

    psi = W(F),   P = dpsi/dF (first Piola-Kirchhoff),   A[i,J,k,L] = dP_iJ/dF_kL.
"""

import numpy as np
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

import basix.ufl

import artifem.jit  # noqa: F401  (waits for another process's compile of a form)
from artifem.errors import InputError

_CELL = np.zeros(1, dtype=np.int32)
_REFERENCE_POINT = np.array([[0.25, 0.25, 0.25]])
_mesh = None


def _single_tetrahedron():
    global _mesh
    if _mesh is None:
        coordinate_element = basix.ufl.element("Lagrange", "tetrahedron", 1, shape=(3,))
        vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        cells = np.array([[0, 1, 2, 3]], dtype=np.int64)
        _mesh = mesh.create_mesh(MPI.COMM_SELF, cells, coordinate_element, vertices)
    return _mesh


class PointEvaluator:
    """Compiled (psi, P, A) of ``material.strain_energy(F, **fields)`` at a homogeneous F.

    ``field_shapes`` maps each field name to its shape, e.g. {"a0": (3,), "excitation": ()}.
    Calling ``evaluator(F, a0=..., excitation=...)`` returns numpy values
    psi (), P (3, 3) and A (3, 3, 3, 3) with A[i, J, k, L] = dP_iJ / dF_kL.
    """

    def __init__(self, material, field_shapes=None):
        self.material = material
        self.field_shapes = {name: tuple(shape) for name, shape in (field_shapes or {}).items()}
        self._mesh = _single_tetrahedron()
        self._F = fem.Constant(self._mesh, np.eye(3))
        self._fields = {
            name: fem.Constant(self._mesh, np.zeros(shape))
            for name, shape in self.field_shapes.items()
        }
        # A fixed Label: ufl.variable's global counter would enter FFCx's signature.
        F = ufl.classes.Variable(self._F, ufl.classes.Label(0))
        psi = material.strain_energy(F, **self._fields)
        if ufl.shape(psi) != ():
            raise InputError(
                f"{type(material).__name__}.strain_energy must return a scalar, "
                f"got shape {ufl.shape(psi)}"
            )
        P = ufl.diff(psi, F)
        A = ufl.diff(P, F)
        packed = ufl.as_vector(
            [psi]
            + [P[i, J] for i in range(3) for J in range(3)]
            + [
                A[i, J, k, L]
                for i in range(3)
                for J in range(3)
                for k in range(3)
                for L in range(3)
            ]
        )
        self._expression = fem.Expression(packed, _REFERENCE_POINT, comm=MPI.COMM_SELF)

    def __call__(self, F, **fields):
        F = np.asarray(F, dtype=float)
        if F.shape != (3, 3) or not np.all(np.isfinite(F)):
            raise InputError(f"F must be a finite 3x3 array, got shape {F.shape}: {F!r}")
        if set(fields) != set(self.field_shapes):
            raise InputError(
                f"{type(self.material).__name__}: expected fields "
                f"{sorted(self.field_shapes)}, got {sorted(fields)}"
            )
        self._F.value[:] = F
        for name, value in fields.items():
            value = np.asarray(value, dtype=float)
            if value.shape != self.field_shapes[name]:
                raise InputError(
                    f"field {name!r} must have shape {self.field_shapes[name]}, got {value.shape}"
                )
            self._fields[name].value[...] = value
        values = self._expression.eval(self._mesh, _CELL).reshape(-1)
        return (
            values[0].copy(),
            values[1:10].reshape(3, 3).copy(),
            values[10:].reshape(3, 3, 3, 3).copy(),
        )


_evaluators = {}


def evaluator_for(material, **fields):
    """A PointEvaluator for ``material`` and the shapes of the given field values, compiled once.

    Evaluators are cached by (material, field shapes); materials that are not
    hashable get a fresh evaluator each time.
    """
    field_shapes = {name: np.shape(value) for name, value in fields.items()}
    key = (material, tuple(sorted(field_shapes.items())))
    try:
        evaluator = _evaluators.get(key)
    except TypeError:
        return PointEvaluator(material, field_shapes)
    if evaluator is None:
        evaluator = _evaluators[key] = PointEvaluator(material, field_shapes)
    return evaluator
