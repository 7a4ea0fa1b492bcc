"""The scene's direct linear solver: factor a sparse matrix once, solve for many columns.

The step matrix of a coupled scene is unsymmetric (gyroscopic and geometric terms)
and the static KKT matrix indefinite, so both are factored by LU: MUMPS through
petsc4py on one process, or LAPACK (scipy) for systems of at most ``DENSE_MAX``
unknowns (reduced and rigid bodies), where it costs microseconds and building the
PETSc matrix alone a millisecond. A factorization of the same sparsity pattern as
the previous one reuses MUMPS' analysis.
"""

from __future__ import annotations

import warnings
from contextlib import contextmanager

import numpy as np
import scipy.linalg
from petsc4py import PETSc
from scipy import sparse
from threadpoolctl import ThreadpoolController

from artifem.errors import SingularSystem, StepFailed
from artifem.linear_solver import configure_mumps, factor_mumps

__all__ = ["DirectSolver"]

#: Systems of at most this many unknowns are dense (LAPACK), larger ones sparse (MUMPS).
DENSE_MAX = 400
#: The BLAS libraries loaded (numpy's and scipy's OpenBLAS), found once.
_BLAS = ThreadpoolController().select(user_api="blas").lib_controllers


@contextmanager
def one_blas_thread():
    """One BLAS thread inside the block, for the small dense systems: faster alone (0.9
    against 2.8 ms for a 300 x 300 LU on 2 cores) and 70x faster when another process
    holds the other core (6 x 6: 7.8 ms against 0.12). It sets the libraries' threads
    itself, only where they are not one already: threadpoolctl's ``limit()`` queries every
    library's description on each call (46 us), longer than a rigid scene's whole LU."""
    changed = [(lib, n) for lib in _BLAS if (n := lib.num_threads) != 1]
    for lib, _ in changed:
        lib.set_num_threads(1)
    try:
        yield
    finally:
        for lib, n in changed:
            lib.set_num_threads(n)


SINGULAR = "a singular system: redundant joints, or a free body with no mass?"
#: MUMPS ICNTL settings of the sparse LU beyond MUMPS' own defaults (none).
MUMPS_ICNTL: dict = {}


class DirectSolver:
    """x = K^-1 b by LU: :meth:`factor` once, then :meth:`apply` to any right-hand sides."""

    def __init__(self):
        self.ksp = PETSc.KSP().create(PETSc.COMM_SELF)
        self.ksp.setType("preonly")
        pc = self.ksp.getPC()
        pc.setType("lu")
        pc.setFactorSolverType("mumps")
        self._mat = None
        self._pattern = None
        self._dense = None
        self._what = ""

    def solve(self, K, b: np.ndarray, what: str) -> np.ndarray:
        """K^-1 b (one factorization)."""
        return self.factor(K, what).apply(b)

    def factor(self, K, what: str) -> DirectSolver:
        """LU of K (dense or sparse); StepFailed (naming ``what``) when it fails, a
        :class:`~artifem.errors.SingularSystem` at a zero pivot (the dense K on it)."""
        self._what = what
        if K.shape[0] <= DENSE_MAX:
            dense = K.toarray() if sparse.issparse(K) else np.asarray(K, dtype=float)
            with (
                np.errstate(all="ignore"),
                warnings.catch_warnings(),
                one_blas_thread(),
            ):
                warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)  # checked below
                lu, piv = scipy.linalg.lu_factor(dense, check_finite=False)
            pivots = np.abs(np.diag(lu))
            if not np.all(np.isfinite(lu)) or (
                pivots.size and pivots.min() <= 1e-14 * max(pivots.max(), 1e-300)
            ):
                raise SingularSystem(
                    f"{what}: the dense LU found a zero pivot; {SINGULAR}", matrix=dense
                )
            self._dense = (lu, piv)
            return self
        self._dense = None
        K = sparse.csr_matrix(K)
        K.sort_indices()
        n = K.shape[0]
        indptr = K.indptr.astype(PETSc.IntType)
        indices = K.indices.astype(PETSc.IntType)
        pattern = (n, indptr.tobytes(), indices.tobytes())
        if self._mat is not None and pattern == self._pattern:
            self._mat.setValuesCSR(indptr, indices, K.data)  # same pattern: keep the analysis
            self._mat.assemble()
            self.ksp.setOperators(self._mat)
        else:
            if self._mat is not None:
                self.ksp.reset()  # a new pattern (or size): a new analysis
                self._mat.destroy()
            self._mat = PETSc.Mat().createAIJ(
                size=(n, n), csr=(indptr, indices, K.data), comm=PETSc.COMM_SELF
            )
            self._mat.assemble()
            self._pattern = pattern
            self.ksp.setOperators(self._mat)
            configure_mumps(self.ksp.getPC(), MUMPS_ICNTL)
        info = factor_mumps(self.ksp, MUMPS_ICNTL)
        if info < 0:
            self.ksp.reset()  # the next factorization starts afresh
            self._pattern = None
            error = SingularSystem if info == -10 else StepFailed
            raise error(
                f"{what}: the LU factorization failed (MUMPS INFOG(1) = {info}"
                f"{', a zero pivot' if info == -10 else ''}); {SINGULAR}"
            )
        return self

    def apply(self, B: np.ndarray) -> np.ndarray:
        """K^-1 B for the last factored K; B (n,) or (n, k)."""
        B = np.asarray(B, dtype=float)
        if self._dense is not None:
            with one_blas_thread():
                out = scipy.linalg.lu_solve(self._dense, B, check_finite=False)
        else:
            columns = np.asfortranarray(B.reshape(B.shape[0], -1))
            n, k = columns.shape
            # all right-hand sides in one blocked MUMPS solve (KSPMatSolve)
            rhs = PETSc.Mat().createDense((n, k), array=columns, comm=PETSc.COMM_SELF)
            x = PETSc.Mat().createDense((n, k), comm=PETSc.COMM_SELF)
            x.setUp()
            try:
                self.ksp.matSolve(rhs, x)
                reason = self.ksp.getConvergedReason()
                if reason < 0:
                    raise StepFailed(
                        f"{self._what}: the direct solve failed (KSP reason {reason}); {SINGULAR}"
                    )
                out = x.getDenseArray().copy().reshape(B.shape)
            except PETSc.Error as exc:
                raise StepFailed(
                    f"{self._what}: the direct solve failed ({exc}); {SINGULAR}"
                ) from exc
            finally:
                rhs.destroy()
                x.destroy()
        if not np.all(np.isfinite(out)):
            raise StepFailed(f"{self._what}: the direct solve gave non-finite values; {SINGULAR}")
        return out
