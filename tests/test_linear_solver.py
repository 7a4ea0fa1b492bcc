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


def _saddle_point(n=600, m=300):
    """[[A, B^T], [B, 0]] (scipy CSR): sparse random A + A^T + 1e-3 I and B, an exact zero
    block whose pivots MUMPS' LU delays past its workspace estimate at ICNTL(14) = 0
    (INFOG(1) = -9, measured)."""
    from scipy import sparse

    A = sparse.random(n, n, density=0.01, random_state=1)
    A = A + A.T + 1e-3 * sparse.identity(n)
    B = sparse.random(m, n, density=0.02, random_state=2)
    K = sparse.bmat([[A, B.T], [B, None]], format="csr")
    K.sort_indices()
    return K


def test_mumps_workspace_too_small_is_enlarged_and_factored_again(monkeypatch):
    """A factorization that outgrows MUMPS' workspace estimate (its relaxation ICNTL(14)
    set to 0 here; at the default 20 % it happens on some CPUs and not others) is
    analysed and factored again with a larger one, by the scene's direct solver and by
    the LinearSolver's MUMPS LU, and solves the system."""
    import scipy.sparse.linalg as sla
    from artifem import linear_solver
    from artifem.scene import direct_solver
    from artifem.scene.direct_solver import DirectSolver

    monkeypatch.setattr(linear_solver, "MUMPS_ICNTL", {**linear_solver.MUMPS_ICNTL, 14: 0})
    monkeypatch.setattr(direct_solver, "MUMPS_ICNTL", {14: 0})
    K = _saddle_point()
    rhs = np.cos(np.arange(K.shape[0]))
    expected = sla.spsolve(K.tocsc(), rhs)
    scale = np.abs(expected).max()
    x = DirectSolver().solve(K, rhs, "the saddle point")
    assert np.abs(x - expected).max() < 1e-8 * scale
    M = PETSc.Mat().createAIJ(
        size=K.shape,
        csr=(K.indptr.astype(PETSc.IntType), K.indices.astype(PETSc.IntType), K.data),
        comm=MPI.COMM_SELF,
    )
    M.assemble()
    b = M.createVecLeft()
    b.setArray(rhs)
    y = M.createVecRight()
    LinearSolver(MPI.COMM_SELF, "mumps", symmetric=False).solve(M, b, y)
    assert np.abs(y.array - expected).max() < 1e-8 * scale


def test_removing_a_body_frees_its_linear_solver():
    """A scene's linear solver of a body it steps is freed when the body leaves the scene
    (Scene.remove: its KSPs and warm-start vectors destroyed, not left to the collector)."""
    from dolfinx import mesh

    from artifem.fem_body import FemBody
    from artifem.forms import NeoHookean
    from artifem.scene import Scene

    box = mesh.create_box(MPI.COMM_SELF, [[0, 0, 0], [1, 0.2, 0.2]], [4, 1, 1])
    body = FemBody(box, NeoHookean(1e4, 1e4), 1000.0)
    body.fix_nodes(body.find_nodes(lambda x: np.isclose(x[0], 0.0)))
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add(body)
    scene.step(1e-3)  # the default iterative solver, with its warm start
    solver = scene.linear_solver_for(body)
    assert solver.ksp.handle != 0 and solver._previous is not None
    scene.remove(body)
    assert solver.ksp.handle == 0 and solver._previous.handle == 0


def test_small_dense_solves_hold_blas_to_one_thread_and_give_it_back():
    """The scene's dense LU (artifem.scene.direct_solver) runs on one BLAS thread; the
    caller's setting is back afterwards, also when the block raises; a library already on
    one thread is left alone."""
    from threadpoolctl import threadpool_limits

    from artifem.scene.direct_solver import _BLAS, one_blas_thread

    assert _BLAS  # numpy's and scipy's BLAS were found (and any other loaded)
    with threadpool_limits(limits=2, user_api="blas"):
        before = [lib.num_threads for lib in _BLAS]
        assert 2 in before  # a library that can run two threads
        with one_blas_thread():
            assert [lib.num_threads for lib in _BLAS] == [1] * len(_BLAS)
        assert [lib.num_threads for lib in _BLAS] == before
        with pytest.raises(RuntimeError, match="inside"), one_blas_thread():
            raise RuntimeError("inside")
        assert [lib.num_threads for lib in _BLAS] == before
    with threadpool_limits(limits=1, user_api="blas"), one_blas_thread():
        assert [lib.num_threads for lib in _BLAS] == [1] * len(_BLAS)


class _FakeMumps:
    """A KSP stand-in whose MUMPS factorization reports the INFOG(1) values given, one per
    attempt (what factor_mumps reads and calls, no PETSc)."""

    def __init__(self, infog):
        self.infog, self.attempts, self.icntl14 = list(infog), 0, 20

    # the KSP
    def getPC(self):
        return self

    def setUp(self):
        self.attempts += 1

    def getOperators(self):
        return ()

    def reset(self):
        pass

    def setOperators(self, *operators):
        pass

    # its PC
    def setFactorSetUpSolverType(self):
        pass

    def getFactorMatrix(self):
        return self

    # its factor matrix
    def getMumpsInfog(self, k):
        return self.infog[self.attempts - 1]

    def getMumpsIcntl(self, k):
        return self.icntl14

    def setMumpsIcntl(self, k, value):
        if k == 14:
            self.icntl14 = value


#: the MUMPS 5 manual's INFOG(1) values of a workspace too small (its remedy: a larger
#: ICNTL(14)): -8, -9 (the main integer and real arrays of the factorization), -11, -12
#: (the real workspace of the solution and of iterative refinement), -14, -15 (the integer
#: workspace of the same), -17 (the send buffer), -20 (the receive buffer)
WORKSPACE_ERRORS = (-8, -9, -11, -12, -14, -15, -17, -20)


@pytest.mark.parametrize("code", WORKSPACE_ERRORS)
def test_every_workspace_error_of_the_manual_is_retried_with_more_room(code):
    from artifem.linear_solver import factor_mumps

    ksp = _FakeMumps([code, code, 0])
    assert factor_mumps(ksp, {}) == 0
    assert ksp.attempts == 3 and ksp.icntl14 == 80  # 20 % doubled twice


@pytest.mark.parametrize("code", [-10, -13, -1])
def test_other_mumps_errors_are_returned_at_once(code):
    """-10 (singular), -13 (an allocation failed), -1 (an error on another process)."""
    from artifem.linear_solver import factor_mumps

    ksp = _FakeMumps([code, 0])
    assert factor_mumps(ksp, {}) == code and ksp.attempts == 1
