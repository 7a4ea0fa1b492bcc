"""Reduced bases U (3n x r) for reduced-coordinate FEM bodies (Lloyd et al. 2019, section 2).

Every basis returned here is mass-orthonormal,

    U^T M U = I,

and respects the body's fixed nodes: the rows of fixed dofs are exactly zero,
so any reduced displacement u = U q keeps them at rest.

* ``linear_modes``: the lowest vibration modes at rest, K phi = lambda M phi
  (omega = sqrt(lambda)), solved with SLEPc (generalized Hermitian problem,
  shift-and-invert about 0, MUMPS).
* ``extended_modes``: modes extended by linear transformations (von Tycowicz,
  Schulz, Seidel & Hildebrandt 2013, "An efficient construction of reduced
  deformable objects", ACM TOG 32(6)): each mode phi is mapped node-wise by the
  nine elementary linear maps E_ij = e_i e_j^T, then the set is
  M-orthonormalized.
* ``pod_basis``: mass-weighted proper orthogonal decomposition of training
  snapshots (the paper's best basis).

Arrays are numpy arrays of the *owned* dof entries of the body's vector space,
in dolfinx blocked order (node-major: [u_x, u_y, u_z] of node 0, node 1, ...).
In serial that is every dof. The functions here were written for, and tested
in, serial; the numpy helpers accept an optional ``comm`` (mpi4py) to reduce
inner products across ranks, and ``linear_modes`` uses distributed PETSc/SLEPc
objects, but no parallel test exists yet.
"""

from __future__ import annotations

import numpy as np

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from petsc4py import PETSc

import artifem.jit  # noqa: F401  (waits for another process's compile of a form)
from artifem.errors import InputError, SolverError
from artifem.linear_solver import factor_mumps

__all__ = [
    "linear_modes",
    "linear_mode_residuals",
    "extended_modes",
    "pod_basis",
    "modal_derivatives",
    "modal_derivative_basis",
    "mass_orthonormality_error",
    "mass_matrix",
    "body_mass",
]

# ---- mass helpers ---------------------------------------------------------------------------


def _mass_apply(mass, X: np.ndarray) -> np.ndarray:
    """M X for a diagonal mass (1-D array of the owned entries) or a callable x -> M x."""
    X = np.asarray(X, dtype=float)
    if callable(mass):
        if X.ndim == 1:
            return np.asarray(mass(X), dtype=float)
        return (
            np.column_stack([np.asarray(mass(X[:, k]), dtype=float) for k in range(X.shape[1])])
            if X.shape[1]
            else np.zeros_like(X)
        )
    m = np.asarray(mass, dtype=float)
    if m.ndim != 1 or m.shape[0] != X.shape[0]:
        raise InputError(
            f"mass must be a 1-D diagonal of length {X.shape[0]} (the rows of U) "
            f"or a callable x -> M x; got an array of shape {m.shape}"
        )
    return m * X if X.ndim == 1 else m[:, None] * X


def _allreduce(value, comm):
    if comm is None or comm.size == 1:
        return value
    from mpi4py import MPI

    return comm.allreduce(value, op=MPI.SUM)


def _gram(A: np.ndarray, MB: np.ndarray, comm=None) -> np.ndarray:
    """A^T (M B), summed over ranks."""
    return _allreduce(A.T @ MB, comm)


def mass_orthonormality_error(U: np.ndarray, mass, comm=None) -> float:
    """max |U^T M U - I| (entry-wise), the departure of U from M-orthonormality.

    ``mass`` is the lumped mass diagonal (owned entries) or a callable x -> M x.
    """
    U = np.atleast_2d(np.asarray(U, dtype=float).T).T
    G = _gram(U, _mass_apply(mass, U), comm)
    return float(np.max(np.abs(G - np.eye(G.shape[0])))) if G.size else 0.0


def mass_matrix(body) -> PETSc.Mat:
    """The body's mass as a PETSc Mat with the fixed rows and columns zeroed (0 on the diagonal).

    Lumped: a diagonal AIJ matrix of ``body.M_lumped``; consistent: a copy of
    ``body.M_consistent``. Zero rows at fixed dofs make them invisible to the
    eigenproblem K phi = lambda M phi (their eigenvalues are infinite).
    """
    body.compile()
    K = body.K
    fixed_rows = _fixed_global_rows(body)
    if body.M_consistent is not None:
        M = body.M_consistent.copy()
        M.zeroRowsColumns(fixed_rows, diag=0.0)
        return M
    d = body.M_lumped.copy()
    body.zero_fixed(d)
    M = PETSc.Mat().createAIJ(K.getSizes(), bsize=3, nnz=1, comm=K.getComm())
    M.setUp()
    rstart, rend = M.getOwnershipRange()
    dv = PETSc.Vec().createMPI((rend - rstart, PETSc.DECIDE), comm=K.getComm())
    dv.array[:] = d.array_r[: rend - rstart]
    M.setDiagonal(dv)
    M.assemble()
    dv.destroy()
    d.destroy()
    return M


def _fixed_global_rows(body) -> np.ndarray:
    """Global scalar row indices of the owned fixed dofs."""
    imap = body.V.dofmap.index_map
    fixed = body.fixed_dofs[body.fixed_dofs < imap.size_local]
    blocks = imap.local_to_global(fixed.astype(np.int32)).astype(np.int64)
    bs = body.V.dofmap.index_map_bs
    return (bs * blocks[:, None] + np.arange(bs)[None, :]).ravel().astype(PETSc.IntType)


def _owned_fixed_rows(body) -> np.ndarray:
    """Local (owned) scalar row indices of fixed dofs in the owned numpy arrays."""
    n_owned = body.V.dofmap.index_map.size_local
    fixed = body.fixed_dofs[body.fixed_dofs < n_owned].astype(np.int64)
    return (3 * fixed[:, None] + np.arange(3)[None, :]).ravel()


def body_mass(body):
    """The body's mass in the form the numpy helpers take, fixed rows and columns zeroed.

    Lumped: the diagonal m (owned entries, 0 at fixed dofs); consistent: a
    callable x -> M x on owned numpy vectors.
    """
    body.compile()
    fixed = _owned_fixed_rows(body)
    if body.M_consistent is None:
        m = body.M_lumped.array_r.copy()
        m[fixed] = 0.0
        return m
    M = mass_matrix(body)
    x, y = M.createVecs()

    def apply(v):
        x.array[:] = v
        M.mult(x, y)
        return y.array_r.copy()

    return apply


# ---- linear modes ---------------------------------------------------------------------------


def _rest_stiffness(body) -> PETSc.Mat:
    """A copy of K at u = 0 with fixed rows/columns eliminated (1 on their diagonal).

    The body's displacement is restored; body.K and body.R keep the rest assembly.
    """
    u_saved = body.u.x.array.copy()
    try:
        body.u.x.array[:] = 0.0
        body.assemble(tangent=True, diag=1.0)
        return body.K.copy()
    finally:
        body.u.x.array[:] = u_saved


def linear_modes(
    body, r: int, *, shift: float | None = None, tol: float = 1e-12
) -> tuple[np.ndarray, np.ndarray]:
    """Lowest r vibration modes of ``body`` at rest: K phi = lambda M phi, phi^T M phi = 1.

    K is the tangent at u = 0 (the body's displacement is restored afterwards;
    ``body.K`` and ``body.R`` are left holding the rest-state assembly). The
    fixed dofs are eliminated: K has their rows and columns zeroed with 1 on the
    diagonal and M has them zeroed with 0 on the diagonal, so they only carry
    eigenvalues lambda = inf, which shift-and-invert about ``shift`` (default 0:
    SLEPc's target, smallest magnitude) never returns (theta = 1/(lambda - sigma)
    = 0). Lumped (default) or consistent mass, whichever the body uses.

    SLEPc: EPS, GHEP, Krylov-Schur, ST "sinvert" with an LU (MUMPS) factorization
    of K - sigma M. The converged vectors are then Rayleigh-Ritz projected,
    (U^T K U) y = lambda (U^T M U) y, which makes U^T M U = I to round-off even
    inside repeated eigenvalues (e.g. the two bending directions of a square beam).

    Returns (U, lambda): U of shape (owned dofs, r), eigenvalues (r,) ascending
    (omega = sqrt(lambda) in rad/s). Fixed-dof rows of U are exactly zero.
    Tested in serial; the PETSc/SLEPc objects are distributed but no parallel
    test exists yet.
    """
    from slepc4py import SLEPc

    r = _check_count(r, "r")
    body.compile()
    K = _rest_stiffness(body)
    M = mass_matrix(body)
    n_free = K.getSize()[0] - body.mesh.comm.allreduce(len(_owned_fixed_rows(body)))
    if r > n_free:
        raise InputError(
            f"linear_modes: r = {r} exceeds the {n_free} free dofs of body {body.name!r}"
        )
    sigma = 0.0 if shift is None else float(shift)

    eps = SLEPc.EPS().create(comm=K.getComm())
    eps.setOperators(K, M)
    eps.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
    eps.setDimensions(nev=r, ncv=max(2 * r + 1, r + 15))
    eps.setTolerances(tol=tol, max_it=1000)
    eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    eps.setTarget(sigma)
    st = eps.getST()
    st.setType(SLEPc.ST.Type.SINVERT)
    st.setShift(sigma)
    ksp = st.getKSP()
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.LU)
    pc.setFactorSolverType("mumps")
    eps.setUp()
    info = factor_mumps(ksp)  # a workspace too small retried (linear_solver)
    if info < 0:
        raise SolverError(
            f"linear_modes: the LU factorization of K - {sigma:g} M failed "
            f"(MUMPS INFOG(1) = {info}; body {body.name!r}); try a shift"
        )
    eps.solve()
    nconv = eps.getConverged()
    if nconv < r:
        raise SolverError(
            f"linear_modes: SLEPc converged {nconv} of {r} eigenpairs "
            f"(body {body.name!r}); try a smaller r or a shift"
        )
    vr, _ = K.createVecs()
    pairs = []
    for k in range(nconv):
        lam = eps.getEigenpair(k, vr).real
        pairs.append((lam, vr.array_r.copy()))
    eps.destroy()
    pairs.sort(key=lambda p: p[0])
    if not np.all(np.isfinite([p[0] for p in pairs[:r]])):
        raise SolverError("linear_modes: non-finite eigenvalue among the lowest modes")
    U = np.column_stack([p[1] for p in pairs[:r]])
    U[_owned_fixed_rows(body)] = 0.0

    # Rayleigh-Ritz: exact M-orthonormality (round-off), also inside repeated eigenvalues.
    comm = body.mesh.comm
    KU, MU = _mat_apply(K, U), _mat_apply(M, U)
    Kr = _allreduce(U.T @ KU, comm)
    Mr = _allreduce(U.T @ MU, comm)
    Kr, Mr = 0.5 * (Kr + Kr.T), 0.5 * (Mr + Mr.T)
    import scipy.linalg

    lam, Y = scipy.linalg.eigh(Kr, Mr)
    U = U @ Y
    # One more M-orthonormalization pass (Cholesky of the Gram), cheap and stabilizing.
    G = _allreduce(U.T @ _mat_apply(M, U), comm)
    L = np.linalg.cholesky(0.5 * (G + G.T))
    U = np.linalg.solve(L, U.T).T
    # Sign convention: the largest-magnitude entry of each mode is positive (deterministic).
    for k in range(U.shape[1]):
        i = int(np.argmax(np.abs(U[:, k]))) if U.shape[0] else -1
        local = (float(abs(U[i, k])), float(U[i, k])) if i >= 0 else (0.0, 0.0)
        best = max(comm.allgather(local)) if comm.size > 1 else local
        if best[1] < 0:
            U[:, k] *= -1.0
    K.destroy()
    M.destroy()
    return U, lam


def _mat_apply(A: PETSc.Mat, X: np.ndarray) -> np.ndarray:
    """A X for owned numpy columns X."""
    x, y = A.createVecs()
    out = np.empty_like(X)
    for k in range(X.shape[1]):
        x.array[:] = X[:, k]
        A.mult(x, y)
        out[:, k] = y.array_r
    x.destroy()
    y.destroy()
    return out


def linear_mode_residuals(body, U: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """||K phi - lambda M phi|| / ||K phi|| per mode (K at rest, fixed dofs eliminated)."""
    K = _rest_stiffness(body)
    M = mass_matrix(body)
    KU, MU = _mat_apply(K, U), _mat_apply(M, U)
    comm = body.mesh.comm
    num = np.sqrt(_allreduce(np.sum((KU - MU * lam[None, :]) ** 2, axis=0), comm))
    den = np.sqrt(_allreduce(np.sum(KU**2, axis=0), comm))
    K.destroy()
    M.destroy()
    return num / den


# ---- extended modes -------------------------------------------------------------------------


def extended_modes(
    U: np.ndarray, M_diag_or_mult, *, fixed_dofs=None, tol: float = 1e-8, comm=None
) -> np.ndarray:
    """Modes extended by linear transformations (von Tycowicz et al. 2013), M-orthonormalized.

    Each column phi of U (node values phi_a in R^3, blocked order) gives nine
    vectors psi^(ij) with node values (psi^(ij))_a = E_ij phi_a = (phi_a)_j e_i,
    i, j in {0, 1, 2}: the images of phi under every linear map A = sum A_ij E_ij,
    so span{psi} contains A phi for every 3x3 A (in particular phi itself).
    They are M-orthonormalized by modified Gram-Schmidt, applied twice
    ("twice is enough"); a vector whose M-norm after projection falls below
    ``tol`` times the M-norm of its source mode is numerically dependent and
    dropped. r modes give at most 9 r vectors (fewer when a mode has a component
    that vanishes identically, e.g. u_x of an unwarped torsion mode, or when
    images of different modes coincide).

    Args:
        U: (3n, r) modes (owned entries, node-major).
        M_diag_or_mult: lumped mass diagonal (3n,) or a callable x -> M x.
        fixed_dofs: optional block (node) indices whose rows are zeroed in the result
            (they are already zero if they are zero in U).
        tol: relative dependence threshold.
        comm: optional mpi4py communicator to sum inner products over ranks.
    """
    U = np.asarray(U, dtype=float)
    if U.ndim != 2 or U.shape[0] % 3:
        raise InputError(
            f"extended_modes: U must be (3n, r) with node-major blocks of 3, got shape {U.shape}"
        )
    if not (tol > 0):
        raise InputError(f"extended_modes: tol must be > 0, got {tol}")
    n3, r = U.shape
    cands = np.zeros((n3, 9 * r))
    col = 0
    for k in range(r):
        phi = U[:, k].reshape(-1, 3)
        for i in range(3):
            for j in range(3):
                cands[:, col].reshape(-1, 3)[:, i] = phi[:, j]
                col += 1
    if fixed_dofs is not None:
        fixed = np.asarray(fixed_dofs, dtype=np.int64)
        rows = (3 * fixed[:, None] + np.arange(3)[None, :]).ravel()
        cands[rows[rows < n3]] = 0.0
    # Reference scale of each candidate: the M-norm of its source mode (1 for an
    # M-orthonormal U), so round-off-sized images (a component that vanishes in
    # the mode, e.g. u_x of a warping-free torsion mode) count as dependent.
    MU = _mass_apply(M_diag_or_mult, U)
    ref = np.sqrt(np.maximum(_allreduce(np.einsum("ij,ij->j", U, MU), comm), 0.0))
    return _m_orthonormalize(cands, M_diag_or_mult, tol, comm, np.repeat(ref, 9))


def _m_orthonormalize(X: np.ndarray, mass, tol: float, comm=None, ref=None) -> np.ndarray:
    """Modified Gram-Schmidt in the M inner product, two passes, dropping dependent columns.

    Column k is dropped when its M-norm after projection is below tol * ref[k]
    (ref defaults to the column's own M-norm before projection).
    """
    Q: list[np.ndarray] = []
    MQ: list[np.ndarray] = []
    for k in range(X.shape[1]):
        v = X[:, k].copy()
        Mv = _mass_apply(mass, v)
        norm0 = np.sqrt(max(_allreduce(float(v @ Mv), comm), 0.0))
        if norm0 == 0.0:
            continue
        for _ in range(2):
            for q, mq in zip(Q, MQ):
                v -= _allreduce(float(mq @ v), comm) * q
        Mv = _mass_apply(mass, v)
        norm = np.sqrt(max(_allreduce(float(v @ Mv), comm), 0.0))
        if norm < tol * (norm0 if ref is None else ref[k]):
            continue
        Q.append(v / norm)
        MQ.append(Mv / norm)
    return np.column_stack(Q) if Q else np.zeros((X.shape[0], 0))


# ---- POD ------------------------------------------------------------------------------------


def pod_basis(
    snapshots: np.ndarray, mass, *, r: int | None = None, energy_tol: float | None = None, comm=None
) -> tuple[np.ndarray, np.ndarray]:
    """Mass-weighted POD of displacement snapshots, one per row: shape (n_s, 3n).

    (Rows, as everywhere in artifem.reduction: ``Snapshots.displacements``,
    ``record_snapshots`` and ``project`` too.) Below, S = snapshots^T (3n, n_s).

    Minimizes sum_k ||s_k - U U^T M s_k||_M^2 over M-orthonormal U. With the
    lumped mass diagonal m and W = diag(sqrt(m)): W S = Phi Sigma V^T (thin SVD),
    U = W^-1 Phi[:, :r], so U^T M U = Phi^T Phi = I. With a callable mass
    (consistent M) the method of snapshots is used: S^T M S = V Sigma^2 V^T,
    U = S V Sigma^-1 (same singular values; relative accuracy ~ sqrt(eps) for the
    smallest ones, fine for truncation).

    Keep exactly one of: ``r`` vectors, or the smallest r whose captured energy
    sum_{k<r} s_k^2 / sum_k s_k^2 >= 1 - energy_tol. Rows with zero mass must be
    zero in every snapshot (fixed dofs); they stay zero in U.

    Returns (U (3n, r), singular values of W S, all of them, descending).
    """
    if (r is None) == (energy_tol is None):
        raise InputError(
            "pod_basis: give exactly one of r (number of vectors) or energy_tol "
            f"(discarded energy fraction); got r={r!r}, energy_tol={energy_tol!r}"
        )
    if r is not None:
        r = _check_count(r, "r")
    elif not (0.0 <= energy_tol < 1.0):
        raise InputError(f"pod_basis: energy_tol must be in [0, 1), got {energy_tol!r}")
    S = np.asarray(snapshots, dtype=float)
    if S.ndim != 2 or S.shape[0] == 0:
        raise InputError(
            f"pod_basis: snapshots must be a 2-D array of rows (n_snapshots, dofs) "
            f"with at least one row, got shape {S.shape}"
        )
    S = S.T
    if not np.all(np.isfinite(S)):
        raise InputError("pod_basis: snapshots contain non-finite values")
    parallel = comm is not None and comm.size > 1

    if not callable(mass) and not parallel:
        m = np.asarray(mass, dtype=float)
        if m.shape != (S.shape[0],):
            raise InputError(
                f"pod_basis: snapshots of {S.shape[0]} dofs (rows of shape "
                f"(n_snapshots, dofs) = {S.T.shape}) against a mass diagonal of "
                f"shape {m.shape}; snapshots are rows, one per snapshot"
            )
        if np.any(m < 0) or not np.all(np.isfinite(m)):
            raise InputError("pod_basis: mass diagonal must be finite and >= 0")
        zero = m == 0
        if np.any(S[zero] != 0):
            raise InputError("pod_basis: snapshots are nonzero at dofs with zero mass")
        w = np.sqrt(m)
        Phi, s, _ = np.linalg.svd(w[:, None] * S, full_matrices=False)
        winv = np.where(zero, 0.0, 1.0 / np.where(zero, 1.0, w))
        basis = lambda k: winv[:, None] * Phi[:, :k]  # noqa: E731
    else:
        G = _gram(S, _mass_apply(mass, S), comm)
        ev, V = np.linalg.eigh(0.5 * (G + G.T))
        order = np.argsort(ev)[::-1]
        ev, V = np.clip(ev[order], 0.0, None), V[:, order]
        s = np.sqrt(ev)

        def basis(k):
            if k and s[k - 1] <= s[0] * 1e-7:
                raise InputError(
                    f"pod_basis: r = {k} exceeds the numerical rank of the "
                    f"snapshots (method of snapshots, sigma_r/sigma_1 = "
                    f"{s[k - 1] / s[0]:.2e})"
                )
            return S @ (V[:, :k] / s[:k])

    energy = s**2
    total = float(energy.sum())
    if total == 0.0:
        raise InputError("pod_basis: all snapshots are zero")
    if r is None:
        captured = np.cumsum(energy) / total
        r = int(np.searchsorted(captured, 1.0 - energy_tol, side="left")) + 1
        r = min(r, s.size)
    if r > s.size:
        raise InputError(
            f"pod_basis: r = {r} exceeds the number of snapshots / rank bound {s.size}"
        )
    return basis(r), s


def _check_count(r, name: str) -> int:
    if isinstance(r, bool) or not isinstance(r, (int, np.integer)):
        raise InputError(f"{name} must be a positive integer, got {r!r}")
    if r <= 0:
        raise InputError(f"{name} must be a positive integer (>= 1), got {r}")
    return int(r)


# ---- modal derivatives ----------------------------------------------------------------------


def modal_derivatives(body, U: np.ndarray) -> np.ndarray:
    """Modal derivatives (Barbic & James 2005, "Real-time subspace integration for St.
    Venant-Kirchhoff deformable models", ACM TOG 24(3)) at rest:

        K Psi_ij = -(dK/du . U_j) U_i,   i <= j,

    with K the tangent at u = 0 and (dK/du . U_j) U_i the third derivative of the
    potential energy in the directions U_i, U_j (derived by ``ufl.derivative`` from
    the body's UFL energy, so any material works; zero for a linear material).
    Fixed dofs are eliminated (zero right-hand side and solution rows there).

    Returns Psi, shape (owned dofs, r (r + 1) / 2), columns in the order
    (0,0), (0,1), ..., (0,r-1), (1,1), ... Not normalized: combine with the modes
    and M-orthonormalize (mass-weighted Gram-Schmidt, as in ``extended_modes``)
    to build a basis. Tested in serial.
    """
    import ufl
    from dolfinx import fem
    from dolfinx.fem import petsc as fem_petsc

    U = np.asarray(U, dtype=float)
    body.compile()
    n_owned = body.V.dofmap.index_map.size_local * 3
    if U.ndim != 2 or U.shape[0] != n_owned:
        raise InputError(f"modal_derivatives: U must have shape ({n_owned}, r), got {U.shape}")
    u_saved = body.u.x.array.copy()
    try:
        body.u.x.array[:] = 0.0
        body.assemble(tangent=True, diag=1.0)
        K = body.K.copy()
        wi, wj = fem.Function(body.V), fem.Function(body.V)
        v = ufl.TestFunction(body.V)
        R = ufl.derivative(body.potential_energy_form(), body.u, v)
        H = fem.form(ufl.derivative(ufl.derivative(R, body.u, wj), body.u, wi))
        b = fem_petsc.create_vector(body.V)
        ksp = PETSc.KSP().create(K.getComm())
        ksp.setOperators(K)
        ksp.setType(PETSc.KSP.Type.PREONLY)
        pc = ksp.getPC()
        pc.setType(PETSc.PC.Type.LU)
        pc.setFactorSolverType("mumps")
        if factor_mumps(ksp) < 0:
            raise SolverError(
                f"modal derivatives: the LU factorization of the rest "
                f"stiffness failed (body {body.name!r})"
            )
        x, _ = K.createVecs()
        rhs, _ = K.createVecs()
        fixed = _owned_fixed_rows(body)
        cols = []
        r = U.shape[1]
        for i in range(r):
            wi.x.array[:n_owned] = U[:, i]
            wi.x.scatter_forward()
            for j in range(i, r):
                wj.x.array[:n_owned] = U[:, j]
                wj.x.scatter_forward()
                with b.localForm() as loc:
                    loc.set(0.0)
                fem_petsc.assemble_vector(b, H)
                b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
                rhs.array[:] = -b.array_r[:n_owned]
                rhs.array[fixed] = 0.0
                ksp.solve(rhs, x)
                col = x.array_r.copy()
                col[fixed] = 0.0
                cols.append(col)
        ksp.destroy()
        K.destroy()
    finally:
        body.u.x.array[:] = u_saved
    return np.column_stack(cols) if cols else np.zeros((n_owned, 0))


def modal_derivative_basis(body, r: int, *, tol: float = 1e-8) -> np.ndarray:
    """Linear modes and their modal derivatives, M-orthonormalized (Barbic & James 2005).

    The r lowest modes U (:func:`linear_modes`) followed by the r (r + 1) / 2
    modal derivatives Psi_ij (:func:`modal_derivatives`), scaled to unit M-norm
    and M-orthonormalized by two passes of modified Gram-Schmidt; numerically
    dependent vectors (relative M-norm below ``tol`` after projection) are
    dropped. At most r (r + 3) / 2 vectors (6 modes: 27).
    """
    U, _ = linear_modes(body, _check_count(r, "r"))
    Psi = modal_derivatives(body, U)
    mass = body_mass(body)
    norms = np.sqrt(np.maximum(np.einsum("ij,ij->j", Psi, _mass_apply(mass, Psi)), 0.0))
    Psi = Psi[:, norms > 0] / norms[norms > 0]
    return _m_orthonormalize(np.column_stack([U, Psi]), mass, tol)
