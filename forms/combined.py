"""Sum of materials, e.g. a Mooney-Rivlin matrix plus a Blemker fiber."""

import inspect
from dataclasses import dataclass

from .errors import InputError


def field_names(material):
    """Names of the fields (arguments after F) that ``material.strain_energy`` accepts."""
    if hasattr(material, "field_names"):
        return frozenset(material.field_names)
    parameters = list(inspect.signature(material.strain_energy).parameters.values())[1:]
    return frozenset(
        p.name for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
    )


@dataclass(frozen=True, init=False)
class CombinedMaterial:
    """W(F; fields) = sum_k W_k(F; fields accepted by part k).

    Each part receives only the keyword fields its ``strain_energy`` names
    (found with inspect.signature), so ``CombinedMaterial(MooneyRivlin(...),
    BlemkerFiber(...)).strain_energy(F, a0=a0, excitation=a)`` passes a0 and
    the excitation to the fiber only.
    """

    parts: tuple

    def __init__(self, *parts):
        if not parts:
            raise InputError("CombinedMaterial: needs at least one part")
        for index, part in enumerate(parts):
            if not callable(getattr(part, "strain_energy", None)):
                raise InputError(
                    f"CombinedMaterial: part {index} ({part!r}) has no strain_energy(F, ...)"
                )
        object.__setattr__(self, "parts", tuple(parts))

    @property
    def field_names(self):
        """Union of the fields of all parts."""
        return frozenset().union(*(field_names(part) for part in self.parts))

    def strain_energy(self, F, **fields):
        """Sum of the parts' energies, each given the fields it accepts."""
        unknown = set(fields) - self.field_names
        if unknown:
            raise InputError(
                f"CombinedMaterial: no part accepts field(s) {sorted(unknown)}; "
                f"accepted: {sorted(self.field_names)}"
            )
        energies = []
        for part in self.parts:
            accepted = field_names(part)
            energies.append(
                part.strain_energy(F, **{k: v for k, v in fields.items() if k in accepted})
            )
        return sum(energies[1:], energies[0])
