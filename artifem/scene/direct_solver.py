"""The scene's direct linear solver for its (indefinite, unsymmetric) KKT systems."""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc
from scipy import sparse

from artifem.errors import StepFailed


class DirectSolver:
    """x = K^-1 b by a MUMPS LU factorization (petsc4py, one process); systems of at most
    ``DENSE_MAX`` unknowns (reduced and rigid bodies only) by dense LAPACK LU instead, which
    costs microseconds where building the PETSc matrix alone costs a millisecond."""

    DENSE_MAX = 400

    def __init__(self):
        self.ksp = PETSc.KSP().create(PETSc.COMM_SELF)
        self.ksp.setType("preonly")
        pc = self.ksp.getPC()
        pc.setType("lu")
        pc.setFactorSolverType("mumps")
        self._mat = None
        self._pattern = None

    def solve(self, K: sparse.csr_matrix, b: np.ndarray, what: str) -> np.ndarray:
        if K.shape[0] <= self.DENSE_MAX:
            try:
                out = np.linalg.solve(K.toarray(), b)
            except np.linalg.LinAlgError as exc:
                raise StepFailed(f"{what}: the dense LU failed ({exc}); a singular "
                                        "system: redundant joints, or a free body with no "
                                        "mass?") from exc
            if not np.all(np.isfinite(out)):
                raise StepFailed(f"{what}: the dense solve gave non-finite values; a "
                                        "singular system: redundant joints, or a free body "
                                        "with no mass?")
            return out
        K = K.tocsr()
        K.sort_indices()
        n = K.shape[0]
        indptr = K.indptr.astype(PETSc.IntType)
        indices = K.indices.astype(PETSc.IntType)
        pattern = (n, indptr.tobytes(), indices.tobytes())
        if self._mat is not None and pattern == self._pattern:
            self._mat.setValuesCSR(indptr, indices, K.data)    # same pattern: keep the analysis
            self._mat.assemble()
        else:
            if self._mat is not None:
                self.ksp.reset()                # a new pattern (or size): a new analysis
                self._mat.destroy()
            self._mat = PETSc.Mat().createAIJ(size=(n, n), csr=(indptr, indices, K.data),
                                              comm=PETSc.COMM_SELF)
            self._mat.assemble()
            self._pattern = pattern
        self.ksp.setOperators(self._mat)
        rhs = self._mat.createVecLeft()
        x = self._mat.createVecRight()
        rhs.array[:] = b
        try:
            self.ksp.solve(rhs, x)
        except PETSc.Error as exc:
            raise StepFailed(f"{what}: the LU factorization failed ({exc}); a singular "
                                    "system: redundant joints, or a free body with no mass?") \
                from exc
        reason = self.ksp.getConvergedReason()
        out = x.array.copy()
        rhs.destroy()
        x.destroy()
        if reason < 0 or not np.all(np.isfinite(out)):
            raise StepFailed(f"{what}: the direct solve failed (KSP reason {reason}, "
                                    "finite: " f"{bool(np.all(np.isfinite(out)))}); a singular "
                                    "system: redundant joints, or a free body with no mass?")
        return out
