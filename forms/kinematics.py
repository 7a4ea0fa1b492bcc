"""Kinematic quantities of a 3x3 deformation gradient F (UFL expressions).

Every function takes a UFL 3x3 expression F (a ``ufl.variable`` is fine, so
``ufl.diff`` can differentiate through it) and returns a UFL expression.
"""

import ufl


def right_cauchy_green(F):
    """Right Cauchy-Green tensor C = F^T F."""
    return F.T * F


def jacobian(F):
    """Volume ratio J = det F."""
    return ufl.det(F)


def invariants(F):
    """Principal invariants of C = F^T F: I1 = tr C, I2 = (tr(C)^2 - tr(C^2))/2, I3 = det C."""
    C = right_cauchy_green(F)
    I1 = ufl.tr(C)
    I2 = 0.5 * (I1**2 - ufl.tr(C * C))
    I3 = ufl.det(C)
    return I1, I2, I3


def isochoric_invariants(F):
    """Isochoric invariants I1bar = J^(-2/3) I1 and I2bar = J^(-4/3) I2, J = det F."""
    I1, I2, _ = invariants(F)
    J = jacobian(F)
    return J ** (-2.0 / 3.0) * I1, J ** (-4.0 / 3.0) * I2


def fiber_stretch(F, a0):
    """Stretch of the reference direction a0 (unit vector): lambda = sqrt(a0 . C a0) = |F a0|."""
    return ufl.sqrt(ufl.dot(a0, right_cauchy_green(F) * a0))


def green_lagrange(F):
    """Green-Lagrange strain E = (C - I)/2."""
    return 0.5 * (right_cauchy_green(F) - ufl.Identity(3))


def small_strain(F):
    """Small (infinitesimal) strain eps = sym(F) - I = sym(grad u) for F = I + grad u."""
    return ufl.sym(F) - ufl.Identity(3)
