"""Compressible (uncoupled) Mooney-Rivlin material."""

from dataclasses import KW_ONLY, dataclass
from typing import ClassVar

import ufl

from .errors import InputError
from .kinematics import isochoric_invariants, jacobian
from .parameters import require_choice, require_finite, require_nonnegative, require_positive

BULK_POTENTIALS = ("quadratic", "log")


@dataclass(frozen=True)
class MooneyRivlin:
    """Five-parameter Mooney-Rivlin energy with a volumetric penalty (ArtiSynth's
    MooneyRivlinMaterial).

    W = C10 (I1bar - 3) + C01 (I2bar - 3) + C11 (I1bar - 3)(I2bar - 3)
        + C20 (I1bar - 3)^2 + C02 (I2bar - 3)^2 + U(J)

    with U(J) = kappa/2 (J - 1)^2 (bulk="quadratic") or kappa/2 (ln J)^2 (bulk="log").
    Small-strain shear modulus 2 (C10 + C01), bulk modulus kappa. Units: Pa.
    """

    C10: float
    _: KW_ONLY
    kappa: float
    C01: float = 0.0
    C11: float = 0.0
    C20: float = 0.0
    C02: float = 0.0
    bulk: str = "quadratic"
    #: Fields that enter the energy only as factors (a form compiler may pass them as
    #: run-time constants instead of literals: one compiled kernel for every value).
    form_constants: ClassVar[tuple[str, ...]] = ("C10", "C01", "C11", "C20", "C02", "kappa")

    def __post_init__(self):
        name = type(self).__name__
        for param in ("C10", "C01", "C20", "C02"):
            object.__setattr__(self, param, require_nonnegative(name, param, getattr(self, param)))
        object.__setattr__(self, "C11", require_finite(name, "C11", self.C11))
        object.__setattr__(self, "kappa", require_positive(name, "kappa", self.kappa))
        require_choice(name, "bulk", self.bulk, BULK_POTENTIALS)
        if not self.C10 + self.C01 > 0.0:
            raise InputError(
                f"{name}: C10 + C01 must be > 0 (shear modulus 2 (C10 + C01)), "
                f"got C10={self.C10}, C01={self.C01}"
            )

    @classmethod
    def tongue(cls, bulk="quadratic"):
        """Tongue tissue as in ArtiSynth's tongue models (Buchaillard et al. 2009): C10=1037,
        C20=486, kappa=10370 Pa."""
        return cls(1037.0, C20=486.0, kappa=10370.0, bulk=bulk)

    def volumetric_energy(self, J):
        """U(J) = kappa/2 (J - 1)^2 or kappa/2 (ln J)^2."""
        if self.bulk == "quadratic":
            return 0.5 * self.kappa * (J - 1.0) ** 2
        return 0.5 * self.kappa * ufl.ln(J) ** 2

    def strain_energy(self, F):
        """W(F) per unit reference volume (see class docstring)."""
        I1bar, I2bar = isochoric_invariants(F)
        d1, d2 = I1bar - 3.0, I2bar - 3.0
        return (
            self.C10 * d1
            + self.C01 * d2
            + self.C11 * d1 * d2
            + self.C20 * d1**2
            + self.C02 * d2**2
            + self.volumetric_energy(jacobian(F))
        )
