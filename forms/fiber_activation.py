"""Blemker's active + passive muscle fiber energy.

Blemker S.S., Pinsky P.M., Delp S.L. (2005), "A 3D model of muscle reveals the
causes of nonuniform strains in the biceps brachii", J Biomech 38:657-665.
"""

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import ufl

from .errors import InputError
from .kinematics import fiber_stretch
from .parameters import require_greater, require_nonnegative, require_positive


def _numpy_select(condition, if_true, if_false):
    return np.where(condition, if_true, if_false)


def _ufl_select(condition, if_true, if_false):
    return ufl.conditional(condition, if_true, if_false)


def _passive_linear_coefficients(P1, P2, l_star):
    """P3, P4 of the linear branch P3 l + P4, chosen so f_P is C1 at l = l_star."""
    P3 = P1 * P2 * np.exp(P2 * (l_star - 1.0))
    P4 = P1 * (np.exp(P2 * (l_star - 1.0)) - 1.0) - P3 * l_star
    return P3, P4


def _force_length(l, select):
    """Blemker's active force-length curve f_L(l), written once for numpy and UFL."""
    return select(
        l < 0.4,
        0.0 * l,
        select(
            l < 0.6,
            9.0 * (l - 0.4) ** 2,
            select(
                l < 1.4, 1.0 - 4.0 * (1.0 - l) ** 2, select(l < 1.6, 9.0 * (l - 1.6) ** 2, 0.0 * l)
            ),
        ),
    )


# Antiderivative G_L(l) = int_0^l f_L at the breakpoints 0.6, 1.4 and 1.6.
_G_L_06 = 3.0 * 0.2**3
_G_L_14 = _G_L_06 + 0.8 - 4.0 / 3.0 * 2.0 * 0.4**3
_G_L_16 = _G_L_14 + 3.0 * 0.2**3


def _force_length_integral(l, select):
    """G_L(l) = int_0^l f_L(s) ds in closed form (piecewise cubic)."""
    return select(
        l < 0.4,
        0.0 * l,
        select(
            l < 0.6,
            3.0 * (l - 0.4) ** 3,
            select(
                l < 1.4,
                _G_L_06 + (l - 0.6) + 4.0 / 3.0 * ((1.0 - l) ** 3 - 0.4**3),
                select(l < 1.6, _G_L_14 + 3.0 * ((l - 1.6) ** 3 + 0.2**3), _G_L_16 + 0.0 * l),
            ),
        ),
    )


def _passive(l, select, exp, P1, P2, l_star):
    """Blemker's passive curve f_P(l): 0, exponential toe, then the C1 linear continuation."""
    P3, P4 = _passive_linear_coefficients(P1, P2, l_star)
    return select(
        l <= 1.0, 0.0 * l, select(l < l_star, P1 * (exp(P2 * (l - 1.0)) - 1.0), P3 * l + P4)
    )


def _passive_integral(l, select, exp, P1, P2, l_star):
    """G_P(l) = int_0^l f_P(s) ds in closed form (requires P2 > 0)."""
    P3, P4 = _passive_linear_coefficients(P1, P2, l_star)
    G_star = P1 * ((np.exp(P2 * (l_star - 1.0)) - 1.0) / P2 - (l_star - 1.0))
    return select(
        l <= 1.0,
        0.0 * l,
        select(
            l < l_star,
            P1 * ((exp(P2 * (l - 1.0)) - 1.0) / P2 - (l - 1.0)),
            G_star + 0.5 * P3 * (l**2 - l_star**2) + P4 * (l - l_star),
        ),
    )


def force_length(l):
    """Active force-length curve f_L(l) of Blemker et al. 2005 (numpy, l = lambda/optimal_stretch).

    f_L = 9 (l - 0.4)^2 on [0.4, 0.6], 1 - 4 (1 - l)^2 on [0.6, 1.4], 9 (l - 1.6)^2 on [1.4, 1.6],
    0 otherwise.
    """
    return _force_length(np.asarray(l, dtype=float), _numpy_select)


def passive_force_length(l, P1=0.05, P2=6.6, stretch_star=1.4):
    """Passive curve f_P(l) of Blemker et al. 2005 (numpy).

    f_P = 0 for l <= 1, P1 (exp(P2 (l - 1)) - 1) for 1 < l < stretch_star, P3 l + P4 above,
    with P3 = P1 P2 exp(P2 (l* - 1)) and P4 = P1 (exp(P2 (l* - 1)) - 1) - P3 l*
    (C1 at l* = stretch_star).
    """
    with np.errstate(over="ignore", invalid="ignore"):
        return _passive(np.asarray(l, dtype=float), _numpy_select, np.exp, P1, P2, stretch_star)


@dataclass(frozen=True)
class BlemkerFiber:
    """Along-fiber muscle energy of Blemker, Pinsky & Delp 2005 (J Biomech 38:657-665).

    W(F; a0, a) = max_stress * int_1^lambda [ a f_L(s/c) + f_P(s/c) ] ds,   lambda = |F a0|,

    with c = optimal_stretch, a = excitation in [0, 1] (UFL scalar, e.g. fem.Constant)
    and a0 the unit reference fiber direction. With l = s/c the integral is
    c [a (G_L(lambda/c) - G_L(1/c)) + G_P(lambda/c) - G_P(1/c)], G = closed-form
    antiderivatives of f_L and f_P, so W(lambda=1) = 0 and
    dW/dlambda = max_stress (a f_L(lambda/c) + f_P(lambda/c)),
    P = dW/dlambda * (F a0 (x) a0) / lambda.

    stretch_star is the normalized stretch l* at which f_P turns linear (Blemker's
    lambda*/lambda_ofl); P1 and P2 are dimensionless (scaled by max_stress).
    passive=False drops f_P. Unlike Blemker's W2 this uses the full fiber
    stretch |F a0|, not its isochoric part; it carries no lateral stiffness, so
    combine it with a matrix material (CombinedMaterial).
    """

    max_stress: float
    optimal_stretch: float = 1.0
    passive: bool = True
    P1: float = 0.05
    P2: float = 6.6
    stretch_star: float = 1.4
    #: Fields that enter the energy only as factors (see MooneyRivlin.form_constants);
    #: the others shape it (and are evaluated numerically at the rest length).
    form_constants: ClassVar[tuple[str, ...]] = ("max_stress",)

    def __post_init__(self):
        name = type(self).__name__
        object.__setattr__(
            self, "max_stress", require_positive(name, "max_stress", self.max_stress)
        )
        object.__setattr__(
            self, "optimal_stretch", require_positive(name, "optimal_stretch", self.optimal_stretch)
        )
        object.__setattr__(self, "P1", require_nonnegative(name, "P1", self.P1))
        object.__setattr__(self, "P2", require_nonnegative(name, "P2", self.P2))
        object.__setattr__(
            self, "stretch_star", require_greater(name, "stretch_star", self.stretch_star, 1.0, "1")
        )
        if not isinstance(self.passive, bool):
            raise InputError(f"{name}: passive must be True or False, got {self.passive!r}")

    @property
    def _has_passive(self):
        return self.passive and self.P1 > 0.0 and self.P2 > 0.0

    def fiber_stress(self, stretch, excitation):
        """Nominal fiber stress dW/dlambda = max_stress (a f_L(lambda/c) + f_P(lambda/c))
        (numpy)."""
        l = np.asarray(stretch, dtype=float) / self.optimal_stretch
        stress = excitation * force_length(l)
        if self._has_passive:
            stress = stress + passive_force_length(l, self.P1, self.P2, self.stretch_star)
        return self.max_stress * stress

    def strain_energy(self, F, a0, excitation):
        """W(F; a0, excitation) = max_stress * int_1^|F a0| [a f_L(s/c) + f_P(s/c)] ds."""
        c = self.optimal_stretch
        l = fiber_stretch(F, a0) / c
        rest = 1.0 / c
        energy = excitation * (
            _force_length_integral(l, _ufl_select)
            - float(_force_length_integral(rest, _numpy_select))
        )
        if self._has_passive:
            coeffs = (self.P1, self.P2, self.stretch_star)
            energy = energy + (
                _passive_integral(l, _ufl_select, ufl.exp, *coeffs)
                - float(_passive_integral(rest, _numpy_select, np.exp, *coeffs))
            )
        return self.max_stress * c * energy
