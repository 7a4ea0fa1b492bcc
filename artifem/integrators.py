"""Time integrators and the static solver for FEM bodies.

Notation: M mass, D = alpha M + beta K Rayleigh damping, K = d^2 Pi/du^2 the
tangent, R = dPi/du (so f = -R is the internal-plus-external force), h the
step. Fixed dofs are eliminated (rows and columns dropped, velocity kept 0).

- :class:`SemiImplicitEuler` (ArtiSynth's ConstrainedBackwardEuler): backward
  Euler linearized at the start of the step, one linear solve per step,

      (M + h D + h^2 K) dv = h f(u_k) - h D v_k - h^2 K v_k,
      v_{k+1} = v_k + dv,   u_{k+1} = u_k + h v_{k+1}.

- :class:`ImplicitEuler`: the same equations solved exactly for v_{k+1} by
  Newton's method with a backtracking line search on the residual

      r(v) = M (v - v_k) + h R(u_k + h v) + h D_k v,
      J(v) = M + h D_k + h^2 K(u_k + h v),

  with the damping matrix D_k taken at the start of the step.
- :func:`solve_static`: Newton with line search on R(u) = 0, optionally in
  load increments of the load factor lambda.

An integrator raises :class:`StepFailed` when it cannot complete the step
(an inverted element in every line-search trial, a Newton that does not
converge); the system then retries with a halved step.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from artifem.fem_body import FemBody
from artifem.linear_solver import LinearSolver


class StepFailed(RuntimeError):
    """A step could not be completed at this step size."""


def _update_ghosts(*vecs: PETSc.Vec) -> None:
    for vec in vecs:
        vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)


def _has_inversion(body: FemBody) -> bool:
    detF = body.det_F()
    local = bool(detF.size) and bool(np.nanmin(detF) <= 0 or np.isnan(detF).any())
    return body.mesh.comm.allreduce(local, op=MPI.LOR)


class SemiImplicitEuler:
    """Linearized backward Euler: one linear solve per step (see module docstring)."""

    name = "semi-implicit"

    def advance(self, body: FemBody, h: float, solver: LinearSolver) -> None:
        body.assemble(tangent=True)
        K, R = body.K, body.R
        v, u = body.v.x.petsc_vec, body.u.x.petsc_vec
        c = h * body.beta + h * h
        b = R.copy()
        b.scale(-h)
        w = v.duplicate()
        K.mult(v, w)
        b.axpy(-c, w)
        if body.alpha:
            body.mass_mult(v, w)
            b.axpy(-h * body.alpha, w)
        body.zero_fixed(b)
        K.scale(c)                      # K becomes the step matrix A (reassembled next step)
        body.add_mass(K, 1.0 + h * body.alpha)
        dv = w
        solver.solve(K, b, dv)
        v.axpy(1.0, dv)
        u.axpy(h, v)
        _update_ghosts(u, v)
        b.destroy()
        dv.destroy()


class ImplicitEuler:
    """Fully implicit backward Euler: Newton on v_{k+1} with a line search."""

    name = "implicit"

    def __init__(self, rtol: float = 1e-8, atol: float = 1e-12, max_iterations: int = 20):
        self.rtol, self.atol, self.max_iterations = rtol, atol, max_iterations
        self.iterations = 0

    def advance(self, body: FemBody, h: float, solver: LinearSolver) -> None:
        u, v = body.u.x.petsc_vec, body.v.x.petsc_vec
        u0, v0 = u.copy(), v.copy()
        body.assemble(tangent=body.beta > 0)
        K0 = body.K.copy() if body.beta > 0 else None
        r, w, dv = v.duplicate(), v.duplicate(), v.duplicate()

        def residual(tangent: bool) -> float:
            """Set u = u0 + h v, assemble, and return ||r(v)||."""
            u.array[:] = u0.array + h * v.array
            _update_ghosts(u)
            body.assemble(tangent=tangent)
            w.array[:] = v.array - v0.array
            body.mass_mult(w, r)
            r.axpy(h, body.R)
            if body.alpha:
                body.mass_mult(v, w)
                r.axpy(h * body.alpha, w)
            if K0 is not None:
                K0.mult(v, w)
                r.axpy(h * body.beta, w)
            body.zero_fixed(r)
            return r.norm()

        norm = residual(tangent=True)
        norm0 = max(norm, self.atol)
        try:
            for it in range(1, self.max_iterations + 1):
                if norm <= self.rtol * norm0 or norm <= self.atol:
                    self.iterations = it - 1
                    return
                A = body.K
                A.scale(h * h)
                if K0 is not None:
                    A.axpy(h * body.beta, K0, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
                body.add_mass(A, 1.0 + h * body.alpha)
                r.scale(-1.0)
                solver.solve(A, r, dv)
                v_start = v.copy()
                step = 1.0
                while True:
                    v.array[:] = v_start.array + step * dv.array
                    _update_ghosts(v)
                    u.array[:] = u0.array + h * v.array
                    _update_ghosts(u)
                    if not _has_inversion(body):
                        trial = residual(tangent=False)
                        if np.isfinite(trial) and trial <= (1.0 - 1e-4 * step) * norm:
                            break
                    step *= 0.5
                    if step < 1e-3:
                        raise StepFailed(f"implicit Euler: line search failed at Newton iteration {it}")
                v_start.destroy()
                norm = residual(tangent=True)
            raise StepFailed(f"implicit Euler: Newton did not converge in {self.max_iterations} "
                             f"iterations (|r| = {norm:.3e}, |r0| = {norm0:.3e})")
        finally:
            for vec in (u0, v0, r, w, dv):
                vec.destroy()
            if K0 is not None:
                K0.destroy()


def solve_static(body: FemBody, solver: LinearSolver, *, load_steps: int = 1,
                 rtol: float = 1e-10, atol: float = 1e-12, max_iterations: int = 30,
                 progress=None) -> list[int]:
    """Static equilibrium R(u) = 0 by Newton with a line search, in load increments.

    Fixed dofs keep their prescribed displacement. Returns the Newton iteration
    count of each load step. Raises :class:`StepFailed` if an increment fails.
    """
    u = body.u.x.petsc_vec
    du = u.duplicate()
    counts = []
    for k in range(1, load_steps + 1):
        body.load_factor.value = k / load_steps
        body.assemble(tangent=True, diag=1.0)
        norm0 = body.R.norm()  # includes fixed rows: a scale for the tolerance
        r = body.R.copy()
        body.zero_fixed(r)
        norm = r.norm()
        scale = max(norm0, atol)
        it = 0
        while norm > max(rtol * scale, atol):
            it += 1
            if it > max_iterations:
                raise StepFailed(f"static solve: Newton did not converge in {max_iterations} "
                                 f"iterations at load factor {k / load_steps:g} (|R| = {norm:.3e})")
            r.scale(-1.0)
            solver.solve(body.K, r, du)
            u_start = u.copy()
            step = 1.0
            while True:
                u.array[:] = u_start.array + step * du.array
                _update_ghosts(u)
                if not _has_inversion(body):
                    body.assemble(tangent=False)
                    body.zero_fixed(body.R)
                    trial = body.R.norm()
                    if np.isfinite(trial) and trial <= (1.0 - 1e-4 * step) * norm:
                        break
                step *= 0.5
                if step < 1e-4:
                    raise StepFailed(f"static solve: line search failed at load factor "
                                     f"{k / load_steps:g}, Newton iteration {it}")
            u_start.destroy()
            body.assemble(tangent=True, diag=1.0)
            r.destroy()
            r = body.R.copy()
            body.zero_fixed(r)
            norm = r.norm()
        counts.append(it)
        r.destroy()
        if progress is not None:
            progress.update(1)
    du.destroy()
    return counts
