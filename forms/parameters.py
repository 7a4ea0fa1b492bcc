"""Validation of material parameters: one clear InputError (a ValueError) naming class,
parameter and value."""

import math
from dataclasses import dataclass
from typing import ClassVar

from .errors import InputError


def require_finite(owner, name, value):
    """Check that ``value`` is a finite real number and return it as float."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{owner}: {name} must be a real number, got {value!r}") from None
    if not math.isfinite(number):
        raise InputError(f"{owner}: {name} must be finite, got {number}")
    return number


def require_positive(owner, name, value):
    """Check value > 0 (and finite); return it as float."""
    number = require_finite(owner, name, value)
    if not number > 0.0:
        raise InputError(f"{owner}: {name} must be > 0, got {number}")
    return number


def require_nonnegative(owner, name, value):
    """Check value >= 0 (and finite); return it as float."""
    number = require_finite(owner, name, value)
    if not number >= 0.0:
        raise InputError(f"{owner}: {name} must be >= 0, got {number}")
    return number


def require_greater(owner, name, value, bound, bound_text):
    """Check value > bound (and finite); ``bound_text`` explains the bound in the message."""
    number = require_finite(owner, name, value)
    if not number > bound:
        raise InputError(f"{owner}: {name} must be > {bound_text}, got {number}")
    return number


def require_choice(owner, name, value, choices):
    """Check that value is one of ``choices``."""
    if value not in choices:
        allowed = ", ".join(repr(c) for c in choices)
        raise InputError(f"{owner}: {name} must be one of {allowed}, got {value!r}")
    return value


def lame_from_young_poisson(owner, E, nu):
    """Lame parameters (mu, lmbda) from Young's modulus E > 0 and Poisson ratio -1 < nu < 1/2.

    mu = E / (2 (1 + nu)),  lmbda = E nu / ((1 + nu)(1 - 2 nu)).
    """
    E = require_positive(owner, "E", E)
    nu = require_finite(owner, "nu", nu)
    if not -1.0 < nu < 0.5:
        raise InputError(f"{owner}: nu must be in (-1, 0.5), got {nu}")
    return E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))


def check_lame(owner, mu, lmbda):
    """Check mu > 0 and a positive bulk modulus lmbda + 2 mu / 3 > 0."""
    require_positive(owner, "mu", mu)
    require_greater(
        owner,
        "lmbda",
        lmbda,
        -2.0 * float(mu) / 3.0,
        f"-2 mu / 3 = {-2.0 * float(mu) / 3.0:g} (positive bulk modulus)",
    )


@dataclass(frozen=True)
class LameParameters:
    """Base of the isotropic materials parameterized by Lame's mu and lmbda.

    Validates mu > 0 and a positive bulk modulus, and builds from (E, nu).
    """

    mu: float
    lmbda: float
    #: Fields that enter the energy only as factors (see MooneyRivlin.form_constants).
    form_constants: ClassVar[tuple[str, ...]] = ("mu", "lmbda")

    def __post_init__(self):
        check_lame(type(self).__name__, self.mu, self.lmbda)
        object.__setattr__(self, "mu", float(self.mu))
        object.__setattr__(self, "lmbda", float(self.lmbda))

    @classmethod
    def from_young_poisson(cls, E, nu):
        """Build from Young's modulus E and Poisson ratio nu."""
        return cls(*lame_from_young_poisson(cls.__name__, E, nu))
