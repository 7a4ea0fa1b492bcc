"""Finite differences of a coupled scene's static master forces and of the implicit step's
equations (shared by the tests)."""

import numpy as np
from scipy import sparse

from artifem.scene.implicit_step import NewtonSystem


def master_force_difference(scene, dq, eps):
    """(F_m(eps dq) - F_m(-eps dq)) / (2 eps), the scene restored after each evaluation;
    compare with -K dq, K = scene.static_tangent()."""
    layout = scene._ready()
    saved = layout.save()

    def forces(step):
        scene.displace_masters(step)
        F = scene.master_forces()
        layout.restore(saved)
        layout.place_slaves()
        return F

    return (forces(eps * dq) - forces(-eps * dq)) / (2 * eps)


def _dense(X):
    return np.asarray(X.toarray() if sparse.issparse(X) else X, dtype=float)


def implicit_jacobian_check(scene, h, z_m, lam, eps=1e-6):
    """(finite differences, Jacobian) of the implicit step's equations at trial master
    velocities z_m and impulses lam (artifem.scene.implicit_step), each stacked as
    [d(r - G_m^T lam)/dz_m; d(phi / h)/dz_m]; the scene is left at its start.

    The equations are those Newton solves: r(z_m) - G_m(z_m)^T lam = 0 (G_m = G(q) P, P at
    the start of the step) and phi(q(z_m)) / h = 0 (-c of the constraint rows, c = -phi / h).
    """
    layout = scene._ready()
    system = NewtonSystem(scene, layout, h)

    def equations(z):
        r, A, _, rows = system.residual(z)
        GP = np.vstack([_dense(g.G) for g in rows]) if rows else np.zeros((0, z.size))
        c = np.concatenate([g.c for g in rows]) if rows else np.zeros(0)
        return np.concatenate([r - GP.T @ lam, -c]), A, rows

    n = z_m.size
    columns = []
    for j in range(n):
        e = np.zeros(n)
        e[j] = eps
        columns.append((equations(z_m + e)[0] - equations(z_m - e)[0]) / (2 * eps))
    FD = np.column_stack(columns)
    _, A, rows = equations(z_m)
    J, G_x = system.jacobian(z_m, A, rows, lam)
    Jac = np.vstack([_dense(J)] + [_dense(G) for G in G_x])
    layout.restore(system.start)
    layout.place_slaves()
    return FD, Jac
