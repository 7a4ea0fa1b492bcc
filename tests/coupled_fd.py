"""Finite differences of a coupled scene's static master forces (shared by the tests)."""


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
