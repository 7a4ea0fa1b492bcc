"""Linear solvers for the FEM step matrices (PETSc KSP configurations).

The step matrix of a semi-implicit or Newton step, A = (1 + h alpha) M +
(h beta + h^2) K, is symmetric and, away from instabilities, positive definite.
Three configurations are offered:

- ``"mumps"``: Cholesky (LDL^T) factorization with MUMPS; the symbolic
  analysis is reused because the sparsity pattern never changes.
- ``"cg-gamg"``: conjugate gradients preconditioned by PETSc's smoothed
  aggregation AMG, with the six rigid-body modes as near-nullspace.
- ``"cg-hypre"``: conjugate gradients with hypre BoomerAMG.
"""

from __future__ import annotations

from petsc4py import PETSc

from dolfinx import fem, la
from dolfinx.la.petsc import create_vector_wrap

METHODS = ("mumps", "cg-gamg", "cg-hypre")


def rigid_body_modes(V: fem.FunctionSpace) -> PETSc.NullSpace:
    """The six rigid-body modes (3 translations, 3 rotations) of a vector space.

    Used as the near-nullspace of smoothed-aggregation AMG for elasticity.
    """
    index_map, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    if bs != 3:
        raise ValueError(f"rigid_body_modes: expected a 3D vector space, got block size {bs}")
    n_local = index_map.size_local
    x = V.tabulate_dof_coordinates()[:n_local]
    basis = [la.vector(index_map, bs=bs, dtype=PETSc.ScalarType) for _ in range(6)]
    b = [v.array.reshape(-1, 3) for v in basis]
    for k in range(3):
        b[k][:n_local, k] = 1.0
    b[3][:n_local, 0], b[3][:n_local, 1] = -x[:, 1], x[:, 0]
    b[4][:n_local, 0], b[4][:n_local, 2] = x[:, 2], -x[:, 0]
    b[5][:n_local, 2], b[5][:n_local, 1] = x[:, 1], -x[:, 2]
    la.orthonormalize(basis)
    vecs = [create_vector_wrap(v) for v in basis]
    return PETSc.NullSpace().create(vectors=vecs, comm=V.mesh.comm)


class LinearSolver:
    """A reusable KSP for repeated solves with matrices of one sparsity pattern."""

    def __init__(self, comm, method: str = "mumps", V: fem.FunctionSpace | None = None,
                 rtol: float = 1e-10):
        if method not in METHODS:
            raise ValueError(f"unknown linear solver {method!r}; choose one of {METHODS}")
        self.method = method
        self.ksp = PETSc.KSP().create(comm)
        pc = self.ksp.getPC()
        self._near_nullspace = None
        if method == "mumps":
            self.ksp.setType("preonly")
            pc.setType("cholesky")
            pc.setFactorSolverType("mumps")
        else:
            self.ksp.setType("cg")
            self.ksp.setTolerances(rtol=rtol, atol=1e-50, max_it=1000)
            if method == "cg-gamg":
                pc.setType("gamg")
                if V is not None:
                    self._near_nullspace = rigid_body_modes(V)
            else:
                pc.setType("hypre")
                pc.setHYPREType("boomeramg")
            self.ksp.setInitialGuessNonzero(False)
        self.ksp.setOptionsPrefix("artifem_")
        self.ksp.setFromOptions()
        self.iterations = 0

    def solve(self, A: PETSc.Mat, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """Solve A x = b; A's values may change between calls, not its pattern."""
        A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        if self._near_nullspace is not None:
            A.setNearNullSpace(self._near_nullspace)
        self.ksp.setOperators(A)
        self.ksp.solve(b, x)
        reason = self.ksp.getConvergedReason()
        if reason < 0:
            raise RuntimeError(
                f"linear solve ({self.method}) failed: KSP reason {reason}, "
                f"{self.ksp.getIterationNumber()} iterations")
        self.iterations = self.ksp.getIterationNumber()
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def destroy(self):
        self.ksp.destroy()

