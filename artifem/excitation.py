"""Muscle excitation schedules: piecewise-linear a_m(t), applied as a controller.

A schedule holds knot times t_0 < t_1 < ... and, per muscle, the excitation at
each knot; between knots the excitation is interpolated linearly and after the
last knot it is held. It is applied at the end time t1 of each step (the time
at which backward Euler evaluates the forces).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from artifem.errors import InputError, InputFileNotFoundError, UnknownNameError


@dataclass(frozen=True)
class ExcitationSchedule:
    times: np.ndarray
    values: dict[str, np.ndarray]

    def __post_init__(self):
        times = np.asarray(self.times, dtype=float)
        if times.ndim != 1 or times.size == 0 or np.any(np.diff(times) <= 0):
            raise InputError(
                f"excitation schedule: times must be a non-empty increasing list, "
                f"got {self.times!r}"
            )
        for name, vals in self.values.items():
            vals = np.asarray(vals, dtype=float)
            if vals.shape != times.shape:
                raise InputError(
                    f"excitation schedule: muscle {name!r} has {vals.size} values "
                    f"for {times.size} times"
                )
            if np.any(~np.isfinite(vals)) or vals.min() < 0 or vals.max() > 1:
                raise InputError(f"excitation schedule: values of {name!r} must be in [0, 1]")
        object.__setattr__(self, "times", times)
        object.__setattr__(
            self, "values", {k: np.asarray(v, float) for k, v in self.values.items()}
        )

    @classmethod
    def ramp_and_hold(cls, targets: dict[str, float], ramp_time: float) -> ExcitationSchedule:
        """a_m(t) = target_m min(t / ramp_time, 1): the seed paper's ramp over [0, 0.5] s."""
        return cls(
            np.array([0.0, ramp_time]),
            {name: np.array([0.0, value]) for name, value in targets.items()},
        )

    @classmethod
    def from_file(cls, path: str | Path) -> ExcitationSchedule:
        """Read ``{"times": [...], "excitations": {"MUSCLE": [...], ...}}`` (JSON)."""
        path = Path(path)
        if not path.is_file():
            raise InputFileNotFoundError(f"excitation schedule file not found: {path}")
        try:
            data = json.loads(path.read_text())
            return cls(np.asarray(data["times"]), dict(data["excitations"]))
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            raise InputError(
                f"{path}: not an excitation schedule ({exc}); expected "
                '{"times": [...], "excitations": {"NAME": [...]}}'
            ) from exc

    def at(self, t: float) -> dict[str, float]:
        """Excitations at time t."""
        return {name: float(np.interp(t, self.times, vals)) for name, vals in self.values.items()}

    def controller(self, body):
        """A scene controller that sets ``body``'s muscle excitations at each step's end time."""
        unknown = sorted(set(self.values) - set(body.muscles))
        if unknown:
            raise UnknownNameError(
                f"excitation schedule names unknown muscles {unknown}; "
                f"{body.name!r} defines {sorted(body.muscles)}"
            )

        def apply(system, t0: float, t1: float) -> None:
            for name, value in self.at(t1).items():
                body.set_excitation(name, value)

        return apply
