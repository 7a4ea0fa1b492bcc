"""The coupled island's fully implicit step: backward Euler solved by Newton.

The semi-implicit step (:mod:`artifem.scene.scene`) linearizes backward Euler at
the start of the step and solves once. ``Scene(integrator="implicit")`` solves
the same equations exactly for the master velocities z_m (ArtiSynth's
implicit integrators; :class:`~artifem.integrators.ImplicitEuler` for a body on
its own):

    r(z_m) = P^T [ M (z - z_0) - h f(q_0 + h z, z) ] - G_m^T lambda = 0,
    phi(q_0 + h z) = 0,                 z = P z_m + z_k,

q_0 + h z the configuration at the end of the step (FEM u_0 + h v, roots
p_0 + h v and exp(h [w]x) R_0, prescribed bodies at their targets, slaves set
exactly from their roots), f every applied force (elastic, gravity, damping,
gyroscopic, force and path elements, loads) at that configuration and those
velocities. Newton at a trial z_t solves the step's KKT system at the trial
state (artifem.scene.scene docstring: A = M + h D + h^2 K there):

    [ J      -G_m^T ] [ z_new  ]   [ J z_t - r(z_t)         ]
    [ G_x     0     ] [ lambda ] = [ G_x z_t - phi(q_t) / h ],     J, G_x below,

with the joint limits by the same active set (a contact whose rows change between
iterates, a point crossing its margin, fails the step: it is halved), then
z_t += s (z_new - z_t), s the largest of 1, 1/2, ... whose configuration inverts no
element and lowers the merit |r - G_m^T lambda| + m |phi| / h (m the mean master mass:
one unit). It stops when the merit falls below ``rtol`` times its first value or
``atol``, or when a full step is at round-off.

The Jacobian is the exact derivative of these equations as formed
(:class:`NewtonSystem`; tests/test_scene_implicit_jacobian.py checks it against
finite differences). With P_t the prolongation at the trial state and T the
rotation update's derivative (identity but dexp(h w) on each root's rotation:
exp(h [w + dw]x) R_0 = exp(h [dexp(h w) dw]x) exp(h [w]x) R_0), the configuration
moves by h P_t T dz_m, so

    J   = P^T (A - M(q_t) + M_0) P + P^T A_pos (P_t T - P) - h^2 P^T K_gyro P_t T
          - h P^T K_lambda P_t T,
    G_x = G(q_t) P_t T                  (the rows of d(phi / h)/dz_m),

A_pos the part of A from the forces' position derivatives (h^2 K), K_gyro the
gyroscopic wrench's turn with the body, K_lambda = d(G^T lambda)/dq the constraint
rows' geometric stiffness at the iterate's impulses (each row block's ``stiffness``:
``Joint.constraint_stiffness``, ``Joint.limit_stiffness``; the last step's on the first
iteration), and the KKT
system's first row takes G_m^T (the residual's forces), its second G_x. The
attachments' K_geo of the semi-implicit step is not a derivative of this residual
(its P is the one at the start of the step) and is left out (it took Newton from 3
to 5-6 iterations); ``Scene.geometric_stiffness`` does not change this step. Left
out: the derivative of a path's damping D(q) by the configuration (the bodies' Rayleigh
damping D = alpha M + beta K_0 is constant). Measured at h = 10 ms: a hinged rod,
merit 0.1 -> 4e-5 -> 2e-11 (before: linear, 0.1 -> 4e-5 -> 4e-8 -> 5e-11).

As in the semi-implicit step, M and the velocity map P are taken at the start of
the step (a rigid body's world inertia turns with it).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from artifem.errors import SingularSystem, StepFailed
from artifem.scene.constraints import StepRows, impulses_by_constraint, solve_constrained
from artifem.scene.layout import STEP_ADVICE

__all__ = ["NewtonSystem", "implicit_step"]


class NewtonSystem:
    """The residual of the step from t to t + h and its exact Jacobian (module docstring),
    at trial master velocities z_m; builds on ``L`` (the layout) at the start of the step.
    ``place(z_m)`` puts the scene at the trial state, ``residual(z_m)`` places and gives
    (r, A_all, f_all, constraint rows) there, ``jacobian(z_m, A, rows, lam)`` (at the placed
    trial state) the KKT blocks of Newton's step."""

    def __init__(self, scene, L, h: float):
        self.scene, self.L, self.h = scene, L, h
        self.t1 = scene.t + h
        self.targets = L.kinematic_targets(self.t1)
        for body, (_, _, twist) in self.targets.items():
            body.set_twist(twist)
        self.P = L.prolongation()
        self.z_k = L.known_velocities(h, self.targets)
        self.M0 = L.mass_matrix()
        self.z0 = L.current_velocities()
        self.Mz0 = self.M0 @ self.z0
        self.start = L.save()
        self._A_pos = None

    def place(self, z_m):
        L = self.L
        L.restore(self.start)
        L.advance(self.P @ z_m + self.z_k, self.h, self.targets)

    def residual(self, z_m):
        """(r_m, A_all, f_all, constraint rows with c = -phi / h) at the trial state of z_m
        (placed)."""
        L, P, h = self.L, self.P, self.h
        self.place(z_m)
        A, _, f_all, self._A_pos = L.dynamics(h, self.t1, linearized=False, positional=True)
        r = P.T @ (self.M0 @ (P @ z_m + self.z_k) - self.Mz0 - h * f_all)
        rows = L.constraint_map.rows(P, np.zeros(L.n_all), h, 1.0)
        return np.asarray(r).ravel(), A, f_all, rows

    def jacobian(self, z_m, A, rows, lam):
        """(J, constraint rows) of Newton's KKT system at the trial state of z_m (the last
        one :meth:`residual` placed) for the impulses ``lam``: J = d(r - G_m^T lam)/dz_m and
        the rows d(phi / h)/dz_m, one block per entry of ``rows``."""
        L, P, h = self.L, self.P, self.h
        # the master displacements per unit h dz_m at the trial state: P_t T
        PT = L.fmt(L.prolongation() @ L.rotation_jacobian(z_m, h))
        # r = P^T [M0 (P z_m + z_k) - M0 z0 - h f(q_0 + h P_t T z_m, P z_m + z_k)]:
        # the velocity part of A on P, its position part on P_t T, M0 for A's M(q_t)
        J = (
            P.T @ (A - L.mass_matrix() + self.M0) @ P
            + P.T @ self._A_pos @ (PT - P)
            - h * h * (P.T @ L.gyroscopic_stiffness() @ PT)
        )
        if len(lam) and np.any(lam):  # the rows turn with the bodies
            J = J - h * (P.T @ L.constraint_map.stiffness(rows, lam) @ PT)
        return L.fmt(J), [g.G for g in L.constraint_map.rows(PT, np.zeros(L.n_all), h, 1.0)]


def _guess(scene, rows, h):
    """The last step's impulses (scaled to h) in the order of ``rows``: the first
    Jacobian's constraint stiffness (the merit starts from lambda = 0)."""
    out, seen = [], {}
    last = scene._impulses or {}
    ratio = h / scene._last_h if scene._last_h else 0.0
    for g in rows:
        owner = g.block.owner
        k = seen.get(owner, 0)
        seen[owner] = k + 1
        parts = last.get(owner, [])
        lam = parts[k][1] if k < len(parts) and len(parts[k][1]) == len(g.c) else np.zeros(len(g.c))
        out.append(ratio * np.asarray(lam, dtype=float))
    return np.concatenate(out) if out else np.zeros(0)


def _structure(rows) -> list:
    """(constraint, row count) of each block: the rows Newton's iterates must share."""
    return [(id(g.block.owner), len(g.c)) for g in rows]


def implicit_step(scene, L, h: float, rtol: float, atol: float, max_iterations: int):
    """Advance the coupled island of ``scene`` (layout ``L``) from t to t + h; returns
    (constraint impulses as the step gives them, the merit after each Newton iteration, the
    first value included). Raises StepFailed when the line search or Newton fails (the
    scene then halves the step)."""
    system = NewtonSystem(scene, L, h)
    z_k, targets, M0, z0 = system.z_k, system.targets, system.M0, system.z0
    diag = (M0.diagonal() if sparse.issparse(M0) else np.diag(M0))[L.master_rows]
    mass = float(diag[diag > 0].mean()) if np.any(diag > 0) else 1.0

    if L.n_masters == 0:  # everything fixed, prescribed or attached
        L.advance(z_k, h, targets)
        return {}, []

    place, residual = system.place, system.residual

    def merit(r, rows, lam):
        force = r.copy()
        start_row = 0
        for g in rows:
            m = len(g.c)
            force -= np.asarray(g.G.T @ lam[start_row : start_row + m]).ravel()
            start_row += m
        # phi / h on every free row, the crossed part of a bounded one
        gap = np.concatenate([g.block.gap() for g in rows]) / h if rows else np.zeros(0)
        return float(np.linalg.norm(force) + mass * np.linalg.norm(gap))

    z_m = z0[L.master_rows].copy()  # first guess: the velocities at the start
    place(z_m)
    if L.inverted():
        z_m[:] = 0.0  # ... unless that inverts: then the start
        place(z_m)
    r, A, f_all, rows = residual(z_m)
    lam = np.zeros(sum(len(g.c) for g in rows))
    lam_jacobian = _guess(scene, rows, h)
    norm = merit(r, rows, lam)
    norm0 = max(norm, atol)
    history = [norm]
    where = f"implicit step at t = {scene.t:g}"
    constrained = [vc for _, vc in L.volume_constraints]
    updates = 0
    while True:
        converged = False
        for it in range(1, max_iterations + 1):
            if norm <= rtol * norm0 or norm <= atol:
                converged = True
                break
            J, G_x = system.jacobian(z_m, A, rows, lam_jacobian)
            shifted = [
                StepRows(g.block, G, g.c + np.asarray(G @ z_m).ravel(), g.compliance)
                for g, G in zip(rows, G_x)
            ]
            try:
                z_new, lam_new, _ = solve_constrained(
                    scene._solver,
                    J,
                    J @ z_m - r,
                    shifted,
                    where,
                    force_rows=[g.G for g in rows],
                    memory=scene._active_sets,
                )
            except SingularSystem as error:
                raise L.unresisted(error, J, STEP_ADVICE) from error
            dz = z_new - z_m
            step, z_start = 1.0, z_m
            while step >= 1e-4:
                z_m = z_start + step * dz
                place(z_m)
                if not L.inverted():
                    trial = residual(z_m)
                    if _structure(trial[3]) != _structure(rows):
                        raise StepFailed(
                            f"{where}: the constraint rows changed within the "
                            "step (a contact point crossed its margin)"
                        )
                    norm_trial = merit(trial[0], trial[3], lam_new)
                    if np.isfinite(norm_trial) and norm_trial <= (1.0 - 1e-4 * step) * norm:
                        break
                step *= 0.5
            else:
                raise StepFailed(
                    f"{where}: line search failed at Newton iteration {it} (|r| = {norm:.3e})"
                )
            r, A, f_all, rows = trial
            lam, norm = lam_new, norm_trial
            lam_jacobian = lam
            history.append(norm)
            if step == 1.0 and np.abs(dz).max() <= 1e-14 * max(np.abs(z_m).max(), 1e-300):
                converged = True
                break
        if not (converged or norm <= rtol * norm0 or norm <= atol):
            raise StepFailed(
                f"{where}: Newton did not converge in {max_iterations} "
                f"iterations (merit {norm:.3e}, first {norm0:.3e})"
            )
        # Uzawa around Newton for hard-incompressible bodies: p <- pi until g(u) holds
        # (their g was assembled at this configuration by the last residual)
        violations = [vc.update() for vc in constrained]
        if all(v <= vc.spec.tol for v, vc in zip(violations, constrained)):
            for vc in constrained:
                vc.updates = updates
            return impulses_by_constraint(rows, lam), history
        updates += 1
        if updates > min(vc.spec.max_updates for vc in constrained):
            off = "; ".join(
                vc.describe() for v, vc in zip(violations, constrained) if v > vc.spec.tol
            )
            raise StepFailed(f"{where}: {off} after {updates - 1} pressure updates")
        r, A, f_all, rows = residual(z_m)
        norm = merit(r, rows, lam)
