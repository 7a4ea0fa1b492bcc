"""Linear solvers for the FEM step matrices (PETSc KSP configurations).

The step matrix of a semi-implicit or Newton step, A = (1 + h alpha) M +
(h beta + h^2) K, is symmetric and, away from instabilities, positive definite.
Its values change from step to step, its sparsity pattern never does.
Configurations:

- ``"mumps"``: direct Cholesky (LDL^T with pivoting) factorization with MUMPS,
  refactored every solve; the symbolic analysis is reused because the
  sparsity pattern never changes. Exact, robust, and the slowest above a few
  thousand nodes.
- ``"cg-gamg"``: conjugate gradients preconditioned by PETSc's smoothed
  aggregation AMG, with the six rigid-body modes as near-nullspace.
- ``"cg-gamg-lagged"``: the same, but the AMG hierarchy is rebuilt only when
  CG needs clearly more iterations than right after the last rebuild (or
  every ``lag_max_solves`` solves). The step matrix changes little from one
  step to the next, so a slightly stale AMG is still an excellent
  preconditioner; the Galerkin products (most of the AMG setup) are skipped.
- ``"cg-mumps-lagged"``: CG preconditioned by a MUMPS Cholesky factorization of
  an earlier step matrix, refactored on the same rule.
- ``"cg-hypre"``: conjugate gradients with hypre BoomerAMG (only when the
  PETSc build has hypre; the ``dolfinx-solver-real`` wheel does not).

When CG fails (it needs a positive definite matrix, and the step matrix is
indefinite when the tangent is, e.g. under compressed active fibers), that
one system is solved by MUMPS LDL^T instead (``direct_solves`` counts them).

The iterative methods stop when the *unpreconditioned* residual satisfies
||b - A x|| <= rtol ||b|| (a test that means the same thing whatever the
preconditioner and however stale it is). The initial guess is the previous
solution scaled to minimize the A-norm of the error, alpha = (x_prev . b) /
(x_prev . A x_prev): never worse than a zero guess, and close to the answer
for consecutive time steps, whose velocity increments vary smoothly.

Every configuration reads extra PETSc options with the prefix ``artifem_``
(e.g. ``PETSC_OPTIONS="-artifem_pc_gamg_threshold 0.02"``).
"""

from __future__ import annotations

from petsc4py import PETSc

from dolfinx import fem, la
from dolfinx.la.petsc import create_vector_wrap

from artifem.errors import InputError, LinearSolveError

METHODS = ("mumps", "cg-gamg", "cg-gamg-lagged", "cg-mumps-lagged", "cg-hypre")
#: The default of :class:`~artifem.scene.Scene` for the FEM bodies it steps on their own.
DEFAULT_METHOD = "cg-gamg-lagged"
#: Relative residual of the iterative methods (see :class:`LinearSolver`).
DEFAULT_RTOL = 1e-7


def rigid_body_modes(V: fem.FunctionSpace) -> PETSc.NullSpace:
    """The six rigid-body modes (3 translations, 3 rotations) of a vector space.

    Used as the near-nullspace of smoothed-aggregation AMG for elasticity.
    """
    index_map, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    if bs != 3:
        raise InputError(f"rigid_body_modes: expected a 3D vector space, got block size {bs}")
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


#: MUMPS ICNTL defaults: 7 = 5, METIS fill-reducing ordering (measured on the
#: 3,000-node benchmark box: factor + solve 119 ms instead of 183 ms with
#: MUMPS's automatic choice). ``-artifem_mat_mumps_icntl_7 N`` overrides it.
MUMPS_ICNTL = {7: 5}


def _set_mumps(pc: PETSc.PC, symmetric: bool) -> None:
    """MUMPS LDL^T (symmetric) or LU."""
    pc.setType("cholesky" if symmetric else "lu")
    pc.setFactorSolverType("mumps")


def configure_mumps(pc: PETSc.PC, icntl: dict | None = None) -> None:
    """Create the MUMPS factor matrix and set ``icntl`` (default :data:`MUMPS_ICNTL`;
    needs the operator)."""
    pc.setFactorSetUpSolverType()
    F = pc.getFactorMatrix()
    for key, value in (MUMPS_ICNTL if icntl is None else icntl).items():
        F.setMumpsIcntl(key, value)


#: MUMPS INFOG(1) values of a workspace that the analysis sized too small for the
#: pivoting the numerical factorization did (pivots delayed in an indefinite or badly
#: scaled matrix); the MUMPS manual's remedy is a larger ICNTL(14), the percentage added
#: to the estimated workspace. Which pivots are delayed depends on round-off, so one
#: matrix can factor on one CPU and not on another (measured: the 144-node, 36-point
#: friction case (mu 0.5, KKT of 540 unknowns) of ``artifem bench contact --quick``
#: fails with -9 at MUMPS' 20 % on an AVX-512 Xeon, and factored on the machine the
#: suite passed on before).
MUMPS_WORKSPACE_ERRORS = frozenset({-8, -9, -11, -12, -14, -15, -17, -20})
#: ICNTL(14) doubles at most this many times after a workspace error (20 % -> 320 %).
MUMPS_WORKSPACE_RETRIES = 4


def factor_mumps(ksp: PETSc.KSP, icntl: dict | None = None) -> int:
    """Factor the MUMPS preconditioner of ``ksp`` (operators set): ``ksp.setUp()``, and
    after a workspace error (:data:`MUMPS_WORKSPACE_ERRORS`) the analysis and
    factorization again with ICNTL(14) doubled, which later factorizations of this KSP
    keep (``icntl``: the KSP's other settings, :func:`configure_mumps`). Returns MUMPS'
    INFOG(1) of the last attempt: >= 0 is a factorization (a positive value a warning),
    < 0 a failure the caller reports (-10: singular)."""
    pc = ksp.getPC()

    def factor() -> int:
        try:
            ksp.setUp()
        except PETSc.Error:
            pass  # INFOG(1) says why
        return pc.getFactorMatrix().getMumpsInfog(1)

    for _ in range(MUMPS_WORKSPACE_RETRIES):
        info = factor()
        if info not in MUMPS_WORKSPACE_ERRORS:
            return info
        relaxation = 2 * max(pc.getFactorMatrix().getMumpsIcntl(14), 10)
        operators = ksp.getOperators()
        ksp.reset()  # a failed factorization is not refactored in place
        ksp.setOperators(*operators)
        configure_mumps(pc, icntl)
        pc.getFactorMatrix().setMumpsIcntl(14, relaxation)
    return factor()


class LinearSolver:
    """A reusable KSP for repeated solves with matrices of one sparsity pattern.

    Args:
        comm: MPI communicator of the matrices.
        method: one of :data:`METHODS`.
        V: the vector function space (rigid-body near-nullspace for GAMG).
        rtol: relative unpreconditioned residual ||b - A x|| / ||b|| of the
            iterative methods. The error of x is bounded by rtol times the
            condition number of A, so the test alone does not fix the accuracy;
            measured against MUMPS, the default 1e-7 keeps the displacement
            within 3e-8 relative after 30 semi-implicit steps of the ArtiSynth
            tongue mesh (1e-6: 5e-7) and within 1e-8 on the benchmark boxes, at
            about 4 more CG iterations than 1e-6. Pass ``"mumps"`` when a
            comparison needs agreement to round-off.
        warm_start: start CG from the A-optimal multiple of the previous solution.
        symmetric: the matrices are symmetric (CG, MUMPS LDL^T); False for a tangent
            that is not (a follower pressure on faces with a free border:
            ``FemBody.conservative``): GMRES, right-preconditioned so that ``rtol`` is
            still the unpreconditioned residual, and MUMPS LU.
        lag_growth, lag_extra, lag_max_solves: a lagged preconditioner is rebuilt
            after a solve that needed more than ``lag_growth`` times (plus
            ``lag_extra``) the iterations of the first solve after the last
            rebuild, or after ``lag_max_solves`` solves.
    """

    def __init__(
        self,
        comm,
        method: str = DEFAULT_METHOD,
        V: fem.FunctionSpace | None = None,
        rtol: float = DEFAULT_RTOL,
        *,
        warm_start: bool = True,
        lag_growth: float = 1.5,
        lag_extra: int = 2,
        lag_max_solves: int = 50,
        symmetric: bool = True,
    ):
        if method not in METHODS:
            raise InputError(f"unknown linear solver {method!r}; choose one of {METHODS}")
        if method == "cg-hypre" and not PETSc.Sys.hasExternalPackage("hypre"):
            raise InputError(
                "linear solver 'cg-hypre': this PETSc build has no hypre "
                "(the dolfinx-solver-real wheel ships MUMPS and GAMG); "
                "use 'cg-gamg-lagged', 'cg-gamg' or 'mumps'"
            )
        if not (0.0 < rtol < 1.0):
            raise InputError(f"rtol must be in (0, 1), got {rtol}")
        self.method, self.rtol, self.symmetric = method, rtol, bool(symmetric)
        self.iterative = method != "mumps"
        self.lagged = method.endswith("-lagged")
        self.warm_start = warm_start and self.iterative
        self.lag_growth, self.lag_extra, self.lag_max_solves = lag_growth, lag_extra, lag_max_solves
        self.ksp = PETSc.KSP().create(comm)
        pc = self.ksp.getPC()
        self._near_nullspace = None
        if method == "mumps":
            self.ksp.setType("preonly")
            _set_mumps(pc, self.symmetric)
        else:
            if self.symmetric:
                self.ksp.setType("cg")
            else:
                self.ksp.setType("gmres")
                self.ksp.setPCSide(PETSc.PC.Side.RIGHT)
            self.ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
            self.ksp.setTolerances(rtol=rtol, atol=0.0, max_it=2000)
            if method in ("cg-gamg", "cg-gamg-lagged"):
                pc.setType("gamg")
                if method == "cg-gamg-lagged":
                    # The Chebyshev smoothers keep the eigenvalue bound of the matrix
                    # they were built for; as the step matrix stiffens, a bound 1.1x
                    # the estimate (PETSc's default) can fall below lambda_max and
                    # make the stale preconditioner indefinite (measured: a forced
                    # rebuild every ~10 steps of the benchmark). 1.3x leaves room.
                    opts = PETSc.Options()
                    key = "artifem_mg_levels_ksp_chebyshev_esteig"
                    if not opts.hasName(key):
                        opts.setValue(key, "0,0.1,0,1.3")
                if V is not None:
                    self._near_nullspace = rigid_body_modes(V)
            elif method == "cg-mumps-lagged":
                _set_mumps(pc, self.symmetric)
            else:
                pc.setType("hypre")
                pc.setHYPREType("boomeramg")
            self.ksp.setInitialGuessNonzero(self.warm_start)
        self.ksp.setOptionsPrefix("artifem_")
        self.ksp.setFromOptions()
        self.iterations = 0
        self.setups = 0  # preconditioner (re)builds so far
        self.direct_solves = 0  # iterative failures solved by MUMPS instead
        self._direct = None
        self._operator = None
        self._previous = None  # previous solution (warm start)
        self._work = None
        self._rebuild = True
        self._solves_since_setup = 0
        self._reference_iterations = None

    # ---- helpers ----------------------------------------------------------

    def _initial_guess(self, A: PETSc.Mat, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """x = alpha x_prev with alpha = (x_prev . b) / (x_prev . A x_prev), else 0."""
        prev = self._previous
        if prev is None or prev.getSize() != b.getSize():
            x.set(0.0)
            return
        if self._work is None:
            self._work = prev.duplicate()
        A.mult(prev, self._work)
        curvature = prev.dot(self._work)
        alpha = prev.dot(b) / curvature if curvature > 0 else 0.0
        x.set(0.0)
        x.axpy(alpha, prev)

    def _solve_once(self, A: PETSc.Mat, b: PETSc.Vec, x: PETSc.Vec, rebuild: bool) -> int:
        pc = self.ksp.getPC()
        pc.setReusePreconditioner(not rebuild)
        if rebuild and pc.getType() in ("cholesky", "lu"):
            factor_mumps(self.ksp)  # a failure other than the workspace: KSP's reason
        if self.warm_start:
            self._initial_guess(A, b, x)
        self.ksp.solve(b, x)
        if rebuild:
            self.setups += 1
        return self.ksp.getConvergedReason()

    # ---- public ------------------------------------------------------------

    def solve(self, A: PETSc.Mat, b: PETSc.Vec, x: PETSc.Vec, rtol: float | None = None) -> None:
        """Solve A x = b; A's values may change between calls, not its pattern.

        ``rtol`` (iterative methods): this solve's relative residual instead of the
        solver's, e.g. the forcing term of an inexact Newton iteration that must stay
        quadratic (:func:`artifem.integrators.solve_static`); ignored by ``"mumps"``."""
        if rtol is not None and self.iterative and rtol != self.rtol:
            self.ksp.setTolerances(rtol=rtol)
            try:
                return self.solve(A, b, x)
            finally:
                self.ksp.setTolerances(rtol=self.rtol)
        if A is not self._operator:
            A.setOption(PETSc.Mat.Option.SYMMETRIC, self.symmetric)
            A.setOption(PETSc.Mat.Option.SYMMETRY_ETERNAL, self.symmetric)
            if self._near_nullspace is not None:
                A.setNearNullSpace(self._near_nullspace)
            self._operator = A
            self._rebuild = True
            self.ksp.setOperators(A)
            if self.ksp.getPC().getType() in ("cholesky", "lu"):
                configure_mumps(self.ksp.getPC())
        self.ksp.setOperators(A)
        rebuild = self._rebuild or not self.lagged
        reason = self._solve_once(A, b, x, rebuild)
        if reason < 0 and not rebuild:
            # A stale preconditioner (e.g. from before the matrix lost definiteness): rebuild.
            rebuild = True
            reason = self._solve_once(A, b, x, rebuild)
        if reason < 0 and self.iterative:
            # CG needs a positive definite matrix. The step matrix loses definiteness
            # when the tangent does (compressed active fibers, and stiffness damping
            # beta K keeps it so however small the step): solve this one directly.
            reason = self._direct_solve(A, b, x)
        if reason < 0:
            raise LinearSolveError(
                f"linear solve ({self.method}) failed: KSP reason {reason}, "
                f"{self.ksp.getIterationNumber()} iterations"
            )
        self.iterations = self.ksp.getIterationNumber()
        if self.lagged:
            self._update_lag(rebuild)
        if self.warm_start:
            if self._previous is None or self._previous.getSize() != x.getSize():
                self._previous = x.duplicate()
                self._work = None
            x.copy(self._previous)
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def _direct_solve(self, A: PETSc.Mat, b: PETSc.Vec, x: PETSc.Vec) -> int:
        """MUMPS LDL^T with pivoting (symmetric indefinite) or LU, created on first use."""
        if self._direct is None:
            self._direct = PETSc.KSP().create(A.getComm())
            self._direct.setType("preonly")
            _set_mumps(self._direct.getPC(), self.symmetric)
            self._direct.setOperators(A)
            configure_mumps(self._direct.getPC())
        self._direct.setOperators(A)
        factor_mumps(self._direct)
        self._direct.solve(b, x)
        self.direct_solves += 1
        self._rebuild = True  # the AMG hierarchy is stale: rebuild next time
        return self._direct.getConvergedReason()

    def _update_lag(self, rebuilt: bool) -> None:
        """Decide (from iteration counts, the same on every rank) whether to rebuild next time.

        The reference is the first solve with the preconditioner of an *earlier*
        matrix (a fresh factorization solves its own matrix in one iteration).
        """
        if rebuilt:
            self._solves_since_setup = 0
            self._reference_iterations = None
        elif self._reference_iterations is None:
            self._reference_iterations = self.iterations
        self._solves_since_setup += 1
        reference = self._reference_iterations
        too_many = (
            reference is not None and self.iterations > self.lag_growth * reference + self.lag_extra
        )
        self._rebuild = too_many or self._solves_since_setup >= self.lag_max_solves

    def destroy(self) -> None:
        """Free its PETSc objects now (the KSPs, the warm start); unusable afterwards."""
        self.ksp.destroy()
        if self._direct is not None:
            self._direct.destroy()
        for vec in (self._previous, self._work):
            if vec is not None:
                vec.destroy()
