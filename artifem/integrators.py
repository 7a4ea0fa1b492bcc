"""Time integrators and the static solver for FEM bodies.

Notation: M mass, D = alpha M + beta K_0 Rayleigh damping (K_0 the stiffness at rest,
``FemBody.rest_stiffness``: always dissipative), K = d^2 Pi/du^2 the tangent, R = dPi/du
(so f = -R is the internal-plus-external force), h the step. Fixed dofs are eliminated (rows and
columns dropped, velocity kept 0).

- :class:`SemiImplicitEuler` (ArtiSynth's ConstrainedBackwardEuler): backward
  Euler linearized at the start of the step, one linear solve per step,

      (M + h D + h^2 K) dv = h f(u_k) - h D v_k - h^2 K v_k,
      v_{k+1} = v_k + dv,   u_{k+1} = u_k + h v_{k+1}.

- :class:`ImplicitEuler`: the same equations solved exactly for v_{k+1} by
  Newton's method with a backtracking line search on the residual

      r(v) = M (v - v_k) + h R(u_k + h v) + h D v,
      J(v) = M + h D + h^2 K(u_k + h v),

  the exact Jacobian (D is constant).
- :func:`solve_static`: Newton with line search on R(u) = 0, optionally in
  load increments of the load factor lambda.

Reduced bodies (:class:`~artifem.reduction.reduced_body.ReducedFemBody`,
u = u_bar + U q) have dense r x r versions of each: ``advance_reduced(body, h)``
and :func:`solve_static_reduced`, the same equations with M~, K~(q) =
d^2 Pi~/dq^2, f~(q) = -dPi~/dq, D~ = U^T D U and q, q' in place of
M, K, f, D, u, v (numpy, no PETSc).

An integrator raises :class:`StepFailed` when it cannot complete the step
(an inverted element in every line-search trial, a Newton that does not
converge); the system then retries with a halved step.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from artifem.errors import InputError, SingularSystem, StepFailed
from artifem.fem_body import FemBody
from artifem.incompressibility import hold_linearized
from artifem.linear_solver import LinearSolver

if TYPE_CHECKING:  # reduced_body may import this module: no runtime import
    from artifem.reduction.reduced_body import ReducedFemBody


#: Pressure iterations per Newton iteration of a hard-incompressible body (its linearized
#: constraint only as good as the iterate; the Uzawa updates around Newton finish the job).
NEWTON_PRESSURE_ITERATIONS = 10


def _update_ghosts(*vecs: PETSc.Vec) -> None:
    for vec in vecs:
        vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)


def _reduced_inverted(body: ReducedFemBody) -> bool:
    """True when q or q' is non-finite or det F <= 0 at an integration point."""
    if not all(np.all(np.isfinite(a)) for a in body.state()):
        return True
    bad, min_det = body.inverted_elements()
    return bool(bad.size) or not min_det > 0


def _dense_solve(A: np.ndarray, b: np.ndarray, what: str) -> np.ndarray:
    """x = A^-1 b for the small dense reduced systems; StepFailed if singular or non-finite."""
    try:
        x = np.linalg.solve(A, b)
    except np.linalg.LinAlgError as exc:
        raise StepFailed(f"{what}: singular reduced matrix ({exc})") from exc
    if not np.all(np.isfinite(x)):
        raise StepFailed(f"{what}: non-finite solution of the reduced system")
    return x


def _round_off(correction: np.ndarray, value: np.ndarray, tol: float = 1e-12) -> bool:
    """:func:`_at_round_off` for numpy arrays."""
    return np.abs(correction).max() <= tol * max(np.abs(value).max(), np.finfo(float).tiny)


def _has_inversion(body: FemBody) -> bool:
    detF = body.det_F()
    local = bool(detF.size) and bool(np.nanmin(detF) <= 0 or np.isnan(detF).any())
    return body.mesh.comm.allreduce(local, op=MPI.LOR)


def step_system(
    body: FemBody, h: float, linearized: bool = True
) -> tuple[PETSc.Mat, PETSc.Vec, PETSc.Vec]:
    """The semi-implicit step of an FEM body at its current state, A v+ = b (the one place
    it is formed: this integrator, the coupled island's direct and Schur solves):

        A = M + h D + h^2 K,    b = M v + h f,    f = -R,

    and the applied force f - D v (Rayleigh damping D = alpha M + beta K_0, K_0 the
    stiffness at rest: ``FemBody.rest_stiffness``; the slaves' loads in K_geo). A is
    ``body.K`` scaled in place: valid until the body is assembled again. The caller destroys the
    two vectors. Fixed rows of A hold (1 + h alpha) M_ii.
    ``linearized=False`` (Newton's Jacobian at a trial state) takes the exact tangent of
    a hard-incompressible body (``FemBody.assemble``).
    """
    body.assemble(tangent=True, linearized=linearized)
    v = body.v.x.petsc_vec
    b, d = v.duplicate(), v.duplicate()
    body.mass_mult(v, b)  # b = M v, then + h f
    body.damping_mult(v, d)
    d.axpy(1.0, body.R)
    d.scale(-1.0)  # f - D v = -R - D v
    b.axpy(-h, body.R)
    body.K.scale(h * h)  # K becomes the step matrix A
    body.add_damping(body.K, h)
    body.add_mass(body.K, 1.0)
    return body.K, b, d


def reduced_step_system(body: ReducedFemBody, h: float, linearized: bool = False):
    """:func:`step_system` in reduced coordinates (dense r x r): (A, b, f~ - D~ q') with
    A = M~ + h D~ + h^2 K~, D~ = U^T D U, b = M~ q' + h f~ (``linearized``: a hard body's
    geometric tangent with its multipliers, as in :func:`step_system`)."""
    K, f, M, D, v = body.tangent(linearized), body.force(), body.M, body.damping, body.qdot
    return M + h * D + h * h * K, M @ v + h * f, f - D @ v


class SemiImplicitEuler:
    """Linearized backward Euler: one linear solve per step (see module docstring)."""

    name = "semi-implicit"

    def advance(self, body: FemBody, h: float, solver: LinearSolver) -> None:
        """A dv = b - A v (:func:`step_system`; the increment, so that an iterative
        solver's tolerance bounds the change, not the velocity), v += dv, u += h v."""
        A, b, applied = step_system(body, h)
        v, u = body.v.x.petsc_vec, body.u.x.petsc_vec
        dv = v.duplicate()
        A.mult(v, dv)
        b.axpy(-1.0, dv)
        body.zero_fixed(b)
        solver.solve(A, b, dv)
        body.zero_fixed(dv)  # exact, not to the iterative solver's tolerance
        if body.volume_constraint is not None:
            _hold_volumes(body, h, A, dv, solver, base=v)
        v.axpy(1.0, dv)
        u.axpy(h, v)
        _update_ghosts(u, v)
        if body.volume_constraint is not None:
            _project_volumes(body, h, A, dv, solver)
        for vec in (b, applied, dv):
            vec.destroy()

    def advance_reduced(self, body: ReducedFemBody, h: float) -> None:
        """The same step in reduced coordinates (dense r x r, :func:`reduced_step_system`):
        A dq' = b - A q', q' += dq', q += h q'."""
        A, b, _ = reduced_step_system(body, h, linearized=True)
        q, qdot = body.q.copy(), body.qdot.copy()
        dv = _dense_solve(A, b - A @ qdot, "semi-implicit Euler (reduced)")
        if body.volume_constraint is not None:
            dv = body.volume_constraint.hold_linearized(A, dv, h, base=qdot)
        qdot = qdot + dv
        q = q + h * qdot
        body.set_state((q, qdot))
        vc = body.volume_constraint
        for _ in range(vc.spec.projections if vc is not None else 0):
            if vc.violation() <= vc.spec.step_tol:  # post-stabilization: _project_volumes
                break
            dv = vc.hold_linearized(A, np.zeros_like(qdot), h, exact=False)
            q, qdot = q + h * dv, qdot + dv
            body.set_state((q, qdot))


def _hold_volumes(
    body: FemBody,
    h: float,
    A: PETSc.Mat,
    dv: PETSc.Vec,
    solver: LinearSolver,
    base: PETSc.Vec | None = None,
    inexact: int | None = None,
    stop_when_indefinite: bool = False,
) -> int | None:
    """The linearized volume constraint of a linear solve A dv = b whose displacement
    change is h (base + dv) (the semi-implicit step: base = v; a Newton iteration of the
    implicit step: no base; of statics: h = 1), g + h G (base + dv) = 0 with A kept:
    :func:`~artifem.incompressibility.hold_linearized` corrects dv and the pressures;
    StepFailed when it does not reach the tolerance (``inexact``, ``stop_when_indefinite``
    and the return value: see there)."""
    vc = body.volume_constraint
    v_new, w, y = dv.duplicate(), dv.duplicate(), dv.duplicate()
    dv.copy(v_new)
    if base is not None:
        v_new.axpy(1.0, base)

    def respond(d):
        vc.force_of(d[0], h, w)
        body.zero_fixed(w)
        solver.solve(A, w, y)
        body.zero_fixed(y)
        return [vc.rate_of(y, h)]

    try:
        return hold_linearized(
            [vc],
            [vc.linearized(v_new, h)],
            respond,
            lambda alpha: dv.axpy(alpha, y),
            body.mesh.comm,
            inexact,
            stop_when_indefinite,
        )
    finally:
        for vec in (v_new, w, y):
            vec.destroy()


def _project_volumes(
    body: FemBody, h: float, A: PETSc.Mat, dv: PETSc.Vec, solver: LinearSolver
) -> None:
    """Post-stabilization of a semi-implicit step that left the volumes off by more than
    ``step_tol`` (its constraint held linearized at the start of the step: off by
    O(h^2 |v|^2), up to 8 % in a few tongue elements during fast motion): Newton on the
    nonlinear constraint over further pressure impulses dp with the step matrix kept,

        g(u) + h^2 G A^-1 G^T dp = 0,    v += h A^-1 G^T dp,    u += h (that change),

    (G at the step's end; :func:`_hold_volumes` with no base), at most
    ``Incompressible.projections`` times. The step stays the backward Euler step with the pressures
    changed, at the cost of a few solves with the factorization already made, instead of
    the implicit fallback's Newton. What it does not bring under ``step_tol`` the scene's
    health check still sees. ``dv`` is scratch."""
    vc = body.volume_constraint
    u, v = body.u.x.petsc_vec, body.v.x.petsc_vec
    for _ in range(vc.spec.projections):
        vc.at_current_state()
        if vc.violation() <= vc.spec.step_tol:
            return
        vc.at_current_state(rows=True)
        dv.zeroEntries()
        if _hold_volumes(body, h, A, dv, solver, stop_when_indefinite=True) is None:
            return
        v.axpy(1.0, dv)
        u.axpy(h, dv)
        _update_ghosts(u, v)


class ImplicitEuler:
    """Fully implicit backward Euler: Newton on v_{k+1} with a line search.

    The line search is an Armijo backtracking on the incremental potential

        E(v) = 1/2 (v - v_k)^T M (v - v_k) + Pi(u_k + h v) + h/2 v^T D v,

    whose gradient is r(v), so every accepted step decreases E.
    """

    name = "implicit"

    def __init__(self, rtol: float = 1e-8, atol: float = 1e-12, max_iterations: int = 25):
        self.rtol, self.atol, self.max_iterations = rtol, atol, max_iterations
        self.iterations = 0

    def advance(self, body: FemBody, h: float, solver: LinearSolver) -> None:
        u, v = body.u.x.petsc_vec, body.v.x.petsc_vec
        u0, v0 = u.copy(), v.copy()
        r, w, dv = v.duplicate(), v.duplicate(), v.duplicate()

        def set_velocity(values) -> None:
            v.array[:] = values
            u.array[:] = u0.array + h * v.array
            _update_ghosts(u, v)

        def incremental_potential() -> float:
            w.array[:] = v.array - v0.array
            Mw = w.duplicate()
            body.mass_mult(w, Mw)
            E = 0.5 * Mw.dot(w) + body.potential_energy()
            body.damping_mult(v, Mw)
            E += 0.5 * h * Mw.dot(v)
            Mw.destroy()
            return E

        tangent_at_v = [False]  # whether body.K holds the tangent at the current v

        def residual(tangent: bool) -> float:
            """Assemble at the current v and return ||r(v)|| (r stored in r)."""
            body.assemble(tangent=tangent)
            tangent_at_v[0] = tangent
            w.array[:] = v.array - v0.array
            body.mass_mult(w, r)
            r.axpy(h, body.R)
            body.damping_mult(v, w)
            r.axpy(h, w)
            body.zero_fixed(r)
            return r.norm()

        set_velocity(v0.array)  # initial guess v = v_k, so u = u_k + h v_k ...
        if _has_inversion(body):
            set_velocity(0.0 * v0.array)  # ... unless that inverts: then u = u_k

        scale = []  # |r| at the start of the step: the reference of rtol

        def newton() -> int:
            """Newton from the current v to r(v) = 0; the iteration count."""
            norm = residual(tangent=True)
            if not scale:
                scale.append(max(norm, self.atol))
            norm0 = scale[0]
            for it in range(1, self.max_iterations + 1):
                if norm <= self.rtol * norm0 or norm <= self.atol:
                    return it - 1
                if not tangent_at_v[0]:  # assembled only when a solve needs it
                    residual(tangent=True)
                A = body.K
                A.scale(h * h)
                body.add_damping(A, h)
                body.add_mass(A, 1.0)
                r.scale(-1.0)
                solver.solve(A, r, dv)
                body.zero_fixed(dv)
                slope = -r.dot(dv)  # dE/ds at s = 0 (r holds -gradient)
                if body.volume_constraint is not None:
                    # Newton-Lagrange: the pressures that hold g + h G dv = 0 (so Newton
                    # converges in u and p together), then r and the slope with them
                    _hold_volumes(
                        body,
                        h,
                        A,
                        dv,
                        solver,
                        inexact=min(
                            NEWTON_PRESSURE_ITERATIONS, body.volume_constraint.spec.max_updates
                        ),
                    )
                    norm = residual(tangent=False)
                    slope = r.dot(dv)  # r holds the gradient again
                E0 = incremental_potential()
                v_start = v.array.copy()
                step = _backtrack(
                    lambda s: set_velocity(v_start + s * dv.array),
                    lambda: _has_inversion(body),
                    incremental_potential,
                    E0,
                    slope,
                    lambda: residual(tangent=False),
                    norm,
                )
                if step is None:
                    raise StepFailed(f"implicit Euler: line search failed at Newton iteration {it}")
                norm = residual(tangent=False)
                if step == 1.0 and _at_round_off(dv, v):
                    return it
            if norm <= self.rtol * norm0 or norm <= self.atol:  # the last iteration converged
                return self.max_iterations
            raise StepFailed(
                f"implicit Euler: Newton did not converge in {self.max_iterations} "
                f"iterations (|r| = {norm:.3e}, |r0| = {norm0:.3e})"
            )

        try:
            self.iterations = newton()
            if body.volume_constraint is not None:  # Uzawa around Newton
                self.iterations += _hold_volumes_newton(body, newton)
        finally:
            for vec in (u0, v0, r, w, dv):
                vec.destroy()

    def advance_reduced(self, body: ReducedFemBody, h: float) -> None:
        """The same Newton iteration in reduced coordinates (dense r x r), on

            r(v) = M~ (v - q'_k) - h f~(q_k + h v) + h D~ v,
            J(v) = M~ + h D~ + h^2 K~(q_k + h v),   D~ = U^T D U,

        with the Armijo line search on E(v) = 1/2 (v - q'_k)^T M~ (v - q'_k)
        + Pi~(q_k + h v) + h/2 v^T D~ v. A hard-incompressible body: Newton-Lagrange (its
        multipliers solved with each iteration) and the Uzawa updates around Newton, as
        for the full body.
        """
        q0, v0 = body.q.copy(), body.qdot.copy()
        M, D = body.M, body.damping

        def set_velocity(v: np.ndarray) -> None:
            body.set_state((q0 + h * v, v))

        def incremental_potential() -> float:
            v = body.qdot
            w = v - v0
            return 0.5 * w @ M @ w + body.potential_energy() + 0.5 * h * v @ D @ v

        def residual() -> np.ndarray:
            v = body.qdot
            return M @ (v - v0) - h * body.force() + h * (D @ v)

        set_velocity(v0)  # initial guess v = q'_k, so q = q_k + h q'_k ...
        if _reduced_inverted(body):
            set_velocity(np.zeros_like(v0))  # ... unless that inverts: then q = q_k
        vc = body.volume_constraint
        scale = []  # |r| at the start of the step: the reference of rtol

        def newton() -> int:
            """Newton from the current v to r(v) = 0; the iteration count."""
            r = residual()
            norm = float(np.linalg.norm(r))
            if not scale:
                scale.append(max(norm, self.atol))
            norm0 = scale[0]
            for it in range(1, self.max_iterations + 1):
                if norm <= self.rtol * norm0 or norm <= self.atol:
                    return it - 1
                A = M + h * D + h * h * body.tangent()
                dv = _dense_solve(A, -r, "implicit Euler (reduced)")
                slope = float(r @ dv)  # dE/ds at s = 0
                if vc is not None:
                    # Newton-Lagrange: the multipliers that hold c + h C dv = 0 (exact, the
                    # system is small), then r and the slope with them
                    dv = vc.hold_linearized(A, dv, h, exact=False)
                    r = residual()
                    norm = float(np.linalg.norm(r))
                    slope = float(r @ dv)
                E0 = incremental_potential()
                v_start = body.qdot.copy()
                step = _backtrack(
                    lambda s: set_velocity(v_start + s * dv),
                    lambda: _reduced_inverted(body),
                    incremental_potential,
                    E0,
                    slope,
                    lambda: float(np.linalg.norm(residual())),
                    norm,
                )
                if step is None:
                    raise StepFailed(
                        f"implicit Euler (reduced): line search failed at Newton iteration {it}"
                    )
                r = residual()
                norm = float(np.linalg.norm(r))
                if step == 1.0 and _round_off(dv, body.qdot):
                    return it
            if norm <= self.rtol * norm0 or norm <= self.atol:  # the last one converged
                return self.max_iterations
            raise StepFailed(
                f"implicit Euler (reduced): Newton did not converge in "
                f"{self.max_iterations} iterations (|r| = {norm:.3e}, "
                f"|r0| = {norm0:.3e})"
            )

        self.iterations = newton()
        if vc is not None:  # Uzawa around Newton
            self.iterations += _hold_volumes_newton(body, newton)


def _hold_volumes_newton(body, newton) -> int:
    """Uzawa on the volume constraint of a full or reduced body around a Newton solve that
    has just converged (a full body's last residual assembled g at the solution): while
    max |g| / V > tol, p <- pi and Newton again from there. The Newton iterations it took."""
    vc = body.volume_constraint
    iterations = 0
    for updates in range(1, vc.spec.max_updates + 1):
        vc.updates = updates
        violation = vc.update()
        if violation <= vc.spec.tol:
            return iterations
        iterations += newton()
    raise StepFailed(f"{vc.describe()} after {vc.spec.max_updates} pressure updates")


def _backtrack(
    apply_step,
    inverted,
    merit,
    merit0: float,
    slope: float,
    residual_norm,
    norm0: float,
    min_step: float = 1e-4,
    correction_ratio=None,
) -> float | None:
    """Backtracking line search: the largest s in {1, 1/2, ...} with no inverted element
    (``inverted()`` false) that passes one of

    - Armijo on the merit (``merit`` not None: an energy whose gradient is the residual):
      merit(s) <= merit0 + 1e-4 s slope;
    - a decrease of the residual norm: |r(s)| <= (1 - 1e-4 s) |r(0)|;
    - (``correction_ratio`` not None: statics of a body without a potential) Deuflhard's
      natural monotonicity test theta(s) = |K_0^-1 R(s)| / |du| <= 1 - s/4, the next
      Newton correction with the same tangent, small when Newton converges. It is affine
      invariant: a full Newton step of a bending beam raises |R| (the linear step stretches
      the rotating fibers: large stiff forces, small displacements) by orders of magnitude
      while it is an excellent step, so the residual norm alone refuses the steps that
      make Newton quadratic;

    None below min_step. The energy is the natural merit of these potential problems, but
    near the solution its changes fall below its round-off (it is a sum of terms much
    larger than their differences); the residual norm then decides.
    """
    step = 1.0
    while step >= min_step:
        apply_step(step)
        if not inverted() and _acceptable(
            step, merit, merit0, slope, residual_norm, norm0, correction_ratio
        ):
            return step
        step *= 0.5
    return None


def _acceptable(
    step: float,
    merit,
    merit0: float,
    slope: float,
    residual_norm,
    norm0: float,
    correction_ratio=None,
) -> bool:
    """Whether the step just applied passes one of :func:`_backtrack`'s tests."""
    if merit is not None:
        value = merit()
        if np.isfinite(value) and value <= merit0 + 1e-4 * step * slope:
            return True
    trial = residual_norm()
    if np.isfinite(trial) and trial <= (1.0 - 1e-4 * step) * norm0:
        return True
    if correction_ratio is not None:
        theta = correction_ratio()
        if np.isfinite(theta) and theta <= 1.0 - 0.25 * step:
            return True
    return False


def _extrapolation_weights(nodes, x: float) -> np.ndarray:
    """The Lagrange weights w_j of the polynomial through the values at ``nodes``,
    evaluated at ``x``: p(x) = sum_j w_j y_j, w_j = prod_{m != j} (x - x_m) / (x_j - x_m)."""
    nodes = np.asarray(nodes, dtype=float)
    return np.array(
        [
            np.prod([(x - xm) / (xj - xm) for m, xm in enumerate(nodes) if m != j])
            for j, xj in enumerate(nodes)
        ]
    )


def _at_round_off(correction: PETSc.Vec, value: PETSc.Vec, tol: float = 1e-12) -> bool:
    """True when a Newton correction is at round-off relative to the value it corrects."""
    return correction.norm(PETSc.NormType.INFINITY) <= tol * max(
        value.norm(PETSc.NormType.INFINITY), np.finfo(float).tiny
    )


class StaticCounts(list):
    """The Newton iteration count of each load increment a static solve took (a list of
    ints), with ``factors``: the load factor each increment reached, ``failed``: the
    Newton iterations spent on increments that failed and were cut, and ``residuals``:
    |R| at each Newton iterate of each increment that converged (when the solve records
    them; a coupled island's: its merit, ``Scene._merit``)."""

    def __init__(self, counts=(), factors=(), failed: int = 0, residuals=()):
        super().__init__(int(c) for c in counts)
        self.factors = [float(f) for f in factors]
        self.failed = int(failed)
        self.residuals = [list(r) for r in residuals]


#: The watchdog of the static Newton solve of a body without a potential (Chamberlain et
#: al. 1982, adapted): a full step that fails the line search's tests, but inverts no
#: element, is taken anyway, and Newton goes on with full steps; if after this many of
#: them (the first included) |R| is not below its value where the watch began, Newton
#: returns there and backtracks instead. Newton's first step on a bending beam under a
#: follower pressure raises |R| a hundredfold and fails every test while the steps after
#: it converge quadratically; backtracking it costs two iterations. A conservative body
#: has no watchdog: its energy is a merit that such steps do pass, and a full step that
#: raises it climbs away from the minimum (the compressible membrane of
#: scripts/static_newton_counts.py: 9 iterations in the first increment with the
#: watchdog, 6 without).
WATCHDOG_ITERATIONS = 3

#: The predictor of the next load increment: the polynomial in the load factor through
#: this many converged states (quadratic), extrapolated.
PREDICTOR_POINTS = 3

#: Adaptive load stepping (``load_steps="auto"``, and the cuts of a fixed schedule): an
#: increment that fails is halved, at most this many times in a row ...
MAX_CUTS = 12
#: ... an increment that converged in at most EASY_ITERATIONS Newton iterations doubles
#: the next one (``"auto"`` only) ...
EASY_ITERATIONS = 4
#: ... and under ``"auto"`` an increment that needs more than this many iterations is cut
#: (a full Newton converges in a handful from a good start; more means the increment is
#: too large, and a smaller one is cheaper than a crawl).
AUTO_MAX_ITERATIONS = 10


def load_schedule(load_steps) -> tuple[list[float] | None, float]:
    """The load factors an increment must land on (None: any, ``"auto"``) and the first
    increment."""
    if isinstance(load_steps, str):
        if load_steps != "auto":
            raise InputError(f"load_steps must be a positive integer or 'auto', got {load_steps!r}")
        return None, 1.0
    if int(load_steps) != load_steps or load_steps < 1:
        raise InputError(f"load_steps must be a positive integer or 'auto', got {load_steps!r}")
    n = int(load_steps)
    return [k / n for k in range(1, n + 1)], 1.0 / n


def ramp_load(
    solve_increment, save, restore, load_steps, max_iterations: int, what: str, progress=None
) -> StaticCounts:
    """Drive the load factor from 0 to 1 in increments, each solved by
    ``solve_increment(factor, limit)`` (Newton iterations; StepFailed when it does not
    converge in ``limit``). A failed increment is restored (``save``/``restore``) and
    halved, up to :data:`MAX_CUTS` times; a fixed schedule (``load_steps`` an integer)
    still lands on each of its factors k / n, ``"auto"`` doubles the increment after an
    easy one (:data:`EASY_ITERATIONS`) and cuts one that needs more than
    :data:`AUTO_MAX_ITERATIONS`. A tangent singular in an increment's first iteration (at
    the last converged state: :class:`~artifem.errors.SingularSystem`) is cut once, since
    the load may change it (a follower load, a path's tension); singular there again, the
    solve stops at once with that error instead of cutting on."""
    marks, increment = load_schedule(load_steps)
    auto = marks is None
    limit = min(max_iterations, AUTO_MAX_ITERATIONS) if auto else max_iterations
    counts, factors, failed = [], [], 0
    factor, cuts, singular = 0.0, 0, 0
    while factor < 1.0 - 1e-14:
        if auto:
            goal = min(1.0, factor + increment)
        else:
            mark = next(m for m in marks if m > factor + 1e-14)
            goal = min(mark, factor + increment)
        if 1.0 - goal < 1e-12:
            goal = 1.0
        state = save()
        try:
            it = solve_increment(goal, limit)
        except StepFailed as error:
            failed += error.iterations
            restore(state)
            cuts += 1
            at_start = isinstance(error, SingularSystem) and error.iterations <= 1
            singular = singular + 1 if at_start else 0
            if singular == 2:
                raise SingularSystem(
                    f"{what}: the tangent at load factor {factor:g} is singular, and a "
                    f"smaller load increment does not change that ({error})",
                    iterations=error.iterations,
                ) from error
            if cuts > MAX_CUTS:
                raise StepFailed(
                    f"{what}: the load increment {factor:g} -> {goal:g} failed "
                    f"after {MAX_CUTS} cuts ({error})"
                ) from error
            increment = 0.5 * (goal - factor)
            continue
        counts.append(it)
        factors.append(goal)
        if progress is not None and (auto or goal in marks):
            progress.update(1)
        cuts = singular = 0
        if auto:
            if it <= EASY_ITERATIONS:
                increment *= 2.0
        elif goal in marks:
            increment = 1.0 / len(marks)  # back to the schedule after a cut
        factor = goal
    return StaticCounts(counts, factors, failed)


def solve_static(
    body: FemBody,
    solver: LinearSolver,
    *,
    load_steps: int | str = 1,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    max_iterations: int = 30,
    progress=None,
) -> StaticCounts:
    """Static equilibrium R(u) = 0 by Newton, in load increments of the load factor.

    ``load_steps``: n (increments 1/n; one that fails is halved and retried, and the
    solve still passes through every k/n) or ``"auto"`` (the full load first; an
    increment that fails or needs more than :data:`AUTO_MAX_ITERATIONS` iterations is
    halved, one that converges in at most :data:`EASY_ITERATIONS` doubles the next):
    :func:`ramp_load`.

    Newton is exact: the tangent is dR/du (unsymmetric under a follower pressure: the
    solver must then be built with ``symmetric=False``), an iterative linear solve is
    tightened as |R| approaches the tolerance (its residual stays below a tenth of the
    Newton target), and full steps are taken whenever they pass one of the tests of
    :func:`_backtrack` (energy for a conservative body; otherwise the residual
    norm or the natural monotonicity test), or, for a body without a potential, under the
    watchdog (:data:`WATCHDOG_ITERATIONS`) when the steps after them pay off. Each increment
    starts from the quadratic extrapolation of the last three converged states
    (:data:`PREDICTOR_POINTS`). A hard-incompressible body takes a Newton
    step on its multipliers too (the linearized constraint g + G du = 0 through the Schur
    complement S = G K^-1 G^T: :func:`_hold_volumes` with h = 1), so u and p converge
    together quadratically, in every iteration that follows a full step (inside Newton's
    region). Elsewhere, or where S is indefinite (so is K: e.g. a large prescribed
    displacement applied at once shears the elements next to it, whose tension
    pi = p - kappa g / V makes the geometric tangent dominate), the saddle point in p has
    no merit that the line search could trust: the iteration is a Newton step on the
    augmented energy at fixed p (a minimization), with Uzawa p <- pi once that converged.

    Prescribed displacements that :meth:`FemBody.fix_nodes` wrote since the body last moved
    are ramped with the load factor (:class:`~artifem.fem_body.PrescribedRamp`), so that a
    cut increment cuts them too; an increment whose prescribed step inverts an element is
    cut. A solve that fails leaves them written and ramps them from there the next time.

    Newton stops when |R| on the free dofs falls below rtol times the size of the loads
    (|R| with the reactions, at the start of the increment) or below atol, and the
    volumes hold to their tolerance; or when a full correction is at round-off relative
    to u. Fixed dofs keep their prescribed displacement. Returns the Newton iteration
    count of each load increment (:class:`StaticCounts`; with a fixed schedule and no
    cut, one per load step). Raises :class:`StepFailed` if an increment fails
    :data:`MAX_CUTS` times.
    """
    u = body.u.x.petsc_vec
    du = u.duplicate()
    ds = u.duplicate()
    r = u.duplicate()
    vc = body.volume_constraint

    tangent_at_u = [False]  # whether body.K holds the tangent at the current u

    def residual(tangent: bool = False) -> float:
        """R at the current u into r (K too with ``tangent``: only a solve needs it)."""
        body.assemble(tangent=tangent, diag=1.0)
        tangent_at_u[0] = tangent
        body.R.copy(r)
        body.zero_fixed(r)
        return r.norm()

    def holds() -> bool:  # the volumes as last assembled
        return vc is None or vc.violation() <= vc.spec.tol

    def merit() -> float:  # a conservative body's energy, else |R|
        return body.potential_energy() if body.conservative else residual(tangent=False)

    def keep_if_lower(start_u: np.ndarray, start: float) -> None:
        """Move u to the candidate start ``start_u`` of Newton, and back where it inverts
        an element or its merit is not below ``start``."""
        previous = u.array.copy()
        u.array[:] = start_u
        _update_ghosts(u)
        if _has_inversion(body) or not merit() < start:
            u.array[:] = previous
            _update_ghosts(u)

    # The last PREDICTOR_POINTS converged states (load factor, u): the polynomial through
    # them, extrapolated to the next load factor, starts Newton near the new equilibrium
    # (the first Newton step from u_k alone is the tangent predictor, which misses the
    # path's curvature: a bending beam under a follower load leaves Newton's region of
    # fast convergence with it). With fewer states Newton starts from u_k: the secant
    # through two states stretches a rotating beam's fibers (the 1,200 Pa cantilever of
    # scripts/static_newton_counts.py: 7 iterations from it, 6 from u_k; the quadratic
    # predictor's error is a quarter of the secant's there, and Newton takes 4-5).
    converged = [(0.0, u.array.copy())]

    def predict(factor: float) -> None:
        if len(converged) < PREDICTOR_POINTS:
            return
        factors = [c[0] for c in converged]
        weights = _extrapolation_weights(factors, factor)
        body.set_load_factor(factor)
        # A conservative body keeps the predictor when it lowers the energy (its merit);
        # without a potential it is kept unless it inverts an element (the residual norm
        # is no measure of closeness here: see _backtrack).
        # (the pressures of a hard constraint stay: the multiplier step finds them, and the
        # energy compares starts only at equal pressures)
        keep_if_lower(
            sum(w * c[1] for w, c in zip(weights, converged)),
            merit() if body.conservative else np.inf,
        )

    residuals = []

    def solve_increment(factor: float, limit: int) -> int:
        residuals.append([])
        try:
            it = newton(factor, limit)
        except StepFailed:
            residuals.pop()  # only the increments that converged are kept
            raise
        converged.append((factor, u.array.copy()))
        del converged[:-PREDICTOR_POINTS]
        return it

    def ramp_predict(factor: float) -> None:
        """The prescribed step with the free dofs following it to first order about the
        last converged state u_k: K(u_k) du = -(R(u_k) + dR/du_d du_d) (dR/du_d du_d by a
        difference of R), kept where it inverts nothing and lowers the energy (a body
        without a potential: |R|) below the prescribed step alone's. The prescribed step
        alone stretches only the layer of elements next to the moved nodes, whose tangent
        is then indefinite (a hard constraint's tension): the tetrahedral cube stretched by
        1.3 took 14 and 9 Newton iterations from it, 3 and 3 from this predictor
        (scripts/static_newton_counts.py, tet_stretch)."""
        body.set_load_factor(factor)
        base = ramp.current()
        body.assemble(tangent=True, diag=1.0)  # K(u_k) and R(u_k)
        body.R.copy(ds)
        body.zero_fixed(ds)
        eps = 1e-7  # of the step: a difference of R, its round-off 1e-9
        ramp.apply(factor, eps, base)
        residual(tangent=False)
        r.axpy(-1.0, ds)
        r.scale(1.0 / eps)  # dR/du_d du_d
        r.axpy(1.0, ds)
        r.scale(-1.0)
        solver.solve(body.K, r, du)
        body.zero_fixed(du)
        ramp.apply(factor)
        keep_if_lower(u.array + du.array, np.inf if _has_inversion(body) else merit())

    def newton(factor: float, limit: int) -> int:
        predict(factor)
        if ramp is not None:
            if len(converged) < PREDICTOR_POINTS:
                ramp_predict(factor)
            ramp.apply(factor)
            if _has_inversion(body):  # the prescribed step inverts: a smaller one
                raise StepFailed(
                    f"static solve: the prescribed displacement at load factor "
                    f"{factor:g} inverts elements of {body.name!r}",
                    iterations=0,
                )
        body.set_load_factor(factor)
        norm = residual()
        scale = max(body.R.norm(), atol)  # fixed rows included: the size of the loads
        target = max(rtol * scale, atol)
        it = 0
        # whether the last iteration took the multiplier step, and whether the one before
        # was a full step (inside Newton's region: docstring)
        multiplier, near = vc is None, True
        if vc is not None:
            vc.updates = 0
        # the watchdog (WATCHDOG_ITERATIONS): (iteration, state, |R|) where
        # it began, and whether this increment may start one (not after one has failed)
        watch, may_watch = None, True
        while True:
            residuals[-1].append(norm)
            if norm <= target:
                if holds():
                    return it
                if not multiplier:  # Uzawa on the converged penalty problem: p <- pi
                    vc.update()
                    vc.updates += 1
                    if vc.updates > vc.spec.max_updates:
                        raise StepFailed(
                            f"static solve: {vc.describe()} after "
                            f"{vc.spec.max_updates} pressure updates at load "
                            f"factor {factor:g}"
                        )
                    norm = residual()
                    continue
            if watch is not None:
                if norm <= (1.0 - 1e-4) * watch[2]:
                    watch = None  # the full steps paid off
                elif it - watch[0] >= WATCHDOG_ITERATIONS - 1:
                    restore(watch[1])  # they did not: backtrack from there
                    watch, may_watch, multiplier, near = None, False, vc is None, False
                    norm = residual()
                    continue
            it += 1
            if it > limit:
                raise StepFailed(
                    f"static solve: Newton did not converge in {limit} "
                    f"iterations at load factor {factor:g} (|R| = {norm:.3e})",
                    iterations=it - 1,
                )
            if not tangent_at_u[0]:
                residual(tangent=True)  # the same R, and K at this u
            r.scale(-1.0)
            # Inexact Newton stays quadratic when the linear residual is O(|R|^2); a tenth
            # of the Newton target is enough (it is never the last digits' limit).
            eta = min(getattr(solver, "rtol", 1e-7), max(0.1 * target / max(norm, 1e-300), 1e-14))
            solver.solve(body.K, r, du, rtol=eta)
            body.zero_fixed(du)
            start = save()
            u_start = start[0]
            du_norm = du.norm()

            def apply_step(s):
                u.array[:] = u_start + s * du.array
                _update_ghosts(u)

            def correction_ratio() -> float:  # |K_0^-1 R(s)| / |du|, R(s) assembled
                body.R.copy(ds)
                body.zero_fixed(ds)
                ds.scale(-1.0)
                w = ds.duplicate()
                try:
                    solver.solve(body.K, ds, w, rtol=eta)
                    body.zero_fixed(w)
                    return w.norm() / max(du_norm, 1e-300)
                finally:
                    w.destroy()

            def line_search():
                nonlocal watch
                energy = body.potential_energy() if body.conservative else 0.0
                tests = (
                    body.potential_energy if body.conservative else None,
                    energy,
                    -r.dot(du),
                    lambda: residual(tangent=False),
                    norm,
                    None if body.conservative else correction_ratio,
                )
                # the watchdog of a body without a potential: full steps first (not for
                # the multiplier step, a saddle point whose full steps from far off
                # measured worse: 10 against 7 iterations on the membrane of
                # scripts/static_newton_counts.py)
                if (watch is not None or may_watch) and not (multiplier or body.conservative):
                    apply_step(1.0)
                    if not _has_inversion(body):
                        if watch is None and not _acceptable(1.0, *tests):
                            watch = (it, start, norm)
                        return 1.0
                return _backtrack(
                    apply_step, lambda: _has_inversion(body), *tests[:5], correction_ratio=tests[5]
                )

            step = None
            if vc is not None and near:  # Newton on the multipliers too (docstring)
                plain = (du.copy(), r.copy(), norm, vc.p.x.array.copy())
                multiplier = (
                    _hold_volumes(
                        body,
                        1.0,
                        body.K,
                        du,
                        solver,
                        inexact=NEWTON_PRESSURE_ITERATIONS,
                        stop_when_indefinite=True,
                    )
                    is not None
                )
                if multiplier:
                    body.zero_fixed(du)
                    norm = residual(tangent=False)  # R at u with the new pressures
                    r.scale(-1.0)
                    du_norm = du.norm()
                    step = line_search()
                if step is None:  # S indefinite, or no step along it: plain Newton
                    multiplier = False
                    apply_step(0.0)
                    plain[0].copy(du)
                    plain[1].copy(r)
                    norm, du_norm = plain[2], du.norm()
                    vc.p.x.array[:] = plain[3]
                    vc.p.x.scatter_forward()
                    residual(tangent=False)
                    step = line_search()
                for vec in plain[:2]:
                    vec.destroy()
            else:
                multiplier = False
                step = line_search()
            if step is None:
                raise StepFailed(
                    f"static solve: line search failed at load factor "
                    f"{factor:g}, Newton iteration {it}",
                    iterations=it,
                )
            norm = residual()
            near = step == 1.0
            if step == 1.0 and _at_round_off(du, u) and holds():
                norm = 0.0  # at round-off: converged

    def save():
        return (u.array.copy(), None if vc is None else vc.p.x.array.copy())

    def restore(state):
        u.array[:] = state[0]
        _update_ghosts(u)
        if vc is not None:
            vc.p.x.array[:] = state[1]
            vc.p.x.scatter_forward()

    ramp = body.take_prescribed_ramp()
    if ramp is not None:
        ramp.apply(0.0)
        converged[0] = (0.0, u.array.copy())
    try:
        counts = ramp_load(
            solve_increment, save, restore, load_steps, max_iterations, "static solve", progress
        )
        counts.residuals = residuals
        return counts
    except StepFailed:
        if ramp is not None:
            ramp.give_back()
        raise
    finally:
        body.set_load_factor(1.0)  # a failed solve leaves the loads as the user set them
        for vec in (du, ds, r):
            vec.destroy()


def solve_static_reduced(
    body: ReducedFemBody,
    load_steps: int | str = 1,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    max_iterations: int = 30,
    progress=None,
) -> StaticCounts:
    """Static equilibrium f~(q) = 0 of a reduced body by Newton, K~(q) dq = f~(q),
    in load increments of ``body.full.load_factor`` (dense r x r; ``load_steps`` an
    integer or ``"auto"``: :func:`ramp_load`, as :func:`solve_static`).

    Each Newton step is a backtracking line search on Pi~ (see :func:`_backtrack`).
    Newton stops when |f~| falls below rtol times |f~| at the start of the
    increment, below atol, or when a full correction is at round-off relative
    to q; q' is left as it is. Returns the Newton iteration count of each load
    increment (:class:`StaticCounts`). Raises :class:`StepFailed` if an increment fails
    :data:`MAX_CUTS` times.
    """
    vc = body.volume_constraint

    def solve_increment(factor: float, limit: int) -> int:
        body.full.set_load_factor(factor)
        scale = []

        def newton() -> int:
            f = body.force()
            norm = float(np.linalg.norm(f))
            if not np.isfinite(norm):  # NaN would pass every convergence test
                bad, low = body.inverted_elements()
                raise StepFailed(
                    f"static solve (reduced): {body.name!r} starts with its force "
                    f"non-finite at load factor {factor:g}: {bad.size} inverted "
                    f"element(s) (input indices {bad[:10].tolist()}), min det F "
                    f"{low:.3g}",
                    iterations=0,
                )
            if not scale:
                scale.append(max(norm, atol))
            it = 0
            while norm > max(rtol * scale[0], atol):
                it += 1
                if it > limit:
                    raise StepFailed(
                        f"static solve (reduced): Newton did not converge in "
                        f"{limit} iterations at load factor {factor:g} "
                        f"(|f| = {norm:.3e})",
                        iterations=it - 1,
                    )
                K = body.tangent()
                dq = _dense_solve(K, f, "static solve (reduced)")
                slope = -float(f @ dq)
                if vc is not None:  # Newton-Lagrange, as in ImplicitEuler
                    dq = vc.hold_linearized(K, dq, 1.0, exact=False)
                    f = body.force()
                    norm = float(np.linalg.norm(f))
                    slope = -float(f @ dq)
                q_start = body.q.copy()
                step = _backtrack(
                    lambda s: body.set_q(q_start + s * dq),
                    lambda: _reduced_inverted(body),
                    body.potential_energy,
                    body.potential_energy(),
                    slope,
                    lambda: float(np.linalg.norm(body.force())),
                    norm,
                )
                if step is None:
                    raise StepFailed(
                        f"static solve (reduced): line search failed at load "
                        f"factor {factor:g}, Newton iteration {it}",
                        iterations=it,
                    )
                f = body.force()
                norm = float(np.linalg.norm(f))
                if step == 1.0 and _round_off(dq, body.q):
                    break
            return it

        it = newton()
        if vc is not None:
            it += _hold_volumes_newton(body, newton)
        return it

    try:
        return ramp_load(
            solve_increment,
            body.state,
            body.set_state,
            load_steps,
            max_iterations,
            "static solve (reduced)",
            progress,
        )
    finally:
        body.full.set_load_factor(1.0)  # a failed solve leaves the loads as the user set them
