"""Linear solver configurations: agreement with a direct solve, and the indefinite fallback."""

import numpy as np
import pytest
from mpi4py import MPI

import artifem  # noqa: F401
from petsc4py import PETSc

from artifem.linear_solver import LinearSolver


def _tridiagonal(diagonal):
    """A symmetric tridiagonal PETSc matrix with -0.1 off the diagonal (serial)."""
    n = len(diagonal)
    A = PETSc.Mat().createAIJ([n, n], nnz=3, comm=MPI.COMM_SELF)
    for i, d in enumerate(diagonal):
        A.setValue(i, i, d)
        if i + 1 < n:
            A.setValue(i, i + 1, -0.1)
            A.setValue(i + 1, i, -0.1)
    A.assemble()
    return A


@pytest.mark.parametrize("method", ["mumps", "cg-gamg", "cg-gamg-lagged"])
def test_positive_definite_solve(method):
    A = _tridiagonal(np.linspace(1.0, 3.0, 50))
    x_true = A.createVecRight()
    x_true.setArray(np.sin(np.arange(50)))
    b = A.createVecLeft()
    A.mult(x_true, b)
    x = A.createVecRight()
    solver = LinearSolver(MPI.COMM_SELF, method, rtol=1e-10)
    solver.solve(A, b, x)
    assert np.abs(x.array - x_true.array).max() < 1e-8
    assert solver.direct_solves == 0


def test_indefinite_matrix_falls_back_to_mumps():
    """CG breaks down on an indefinite matrix; the solver answers with LDL^T instead."""
    diagonal = np.linspace(1.0, 3.0, 50)
    diagonal[::7] = -2.0
    A = _tridiagonal(diagonal)
    x_true = A.createVecRight()
    x_true.setArray(np.cos(np.arange(50)))
    b = A.createVecLeft()
    A.mult(x_true, b)
    x = A.createVecRight()
    solver = LinearSolver(MPI.COMM_SELF, "cg-gamg-lagged")
    solver.solve(A, b, x)
    assert solver.direct_solves == 1
    assert np.abs(x.array - x_true.array).max() < 1e-10


@pytest.mark.parametrize("method", ["mumps", "cg-gamg", "cg-gamg-lagged", "cg-mumps-lagged"])
def test_unsymmetric_matrix_with_symmetric_false(method):
    """An unsymmetric matrix (a follower load's tangent): GMRES or MUMPS LU solve it; the
    symmetric configuration (LDL^T reads one triangle) does not."""
    n = 50
    A = PETSc.Mat().createAIJ([n, n], nnz=3, comm=MPI.COMM_SELF)
    for i, d in enumerate(np.linspace(1.0, 3.0, n)):
        A.setValue(i, i, d)
        if i + 1 < n:
            A.setValue(i, i + 1, -0.4)
            A.setValue(i + 1, i, 0.2)
    A.assemble()
    x_true = A.createVecRight()
    x_true.setArray(np.sin(np.arange(n)))
    b = A.createVecLeft()
    A.mult(x_true, b)
    x = A.createVecRight()
    LinearSolver(MPI.COMM_SELF, method, rtol=1e-10, symmetric=False).solve(A, b, x)
    assert np.abs(x.array - x_true.array).max() < 1e-8
    if method == "mumps":
        wrong = A.createVecRight()
        LinearSolver(MPI.COMM_SELF, method).solve(A, b, wrong)
        assert np.abs(wrong.array - x_true.array).max() > 1e-3
