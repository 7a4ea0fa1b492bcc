"""Excitation schedules that train and test reduced models.

- :func:`each_alone`: the seed paper's training design (section 2.3), every exciter alone
  ramped to one level and held.
- :func:`random_schedules`: several exciters together, rising and releasing, the numbers
  space-filling over their ranges. In schedule i, k_i exciters are active (k_i in
  ``active``); active exciter e follows

      a_e(t) = a_e min(max((t - t_on) / T_ramp, 0), 1)                  t <= t_off,
      a_e(t) = a_e max(1 - (t - t_off) / T_release, 0)                  t >  t_off,

  t_on in [0, onset], T_ramp in ``ramp``, t_off = t_on + T_ramp + x T (x in [0, 1], T the
  duration: about half the exciters release within the run), T_release in ``release``,
  a_e in [min, max] excitation. The numbers of a set of schedules are one scrambled Latin
  hypercube (scipy.stats.qmc), so N schedules cover each range evenly instead of
  clumping; which exciters are active is a draw of the same seeded generator. A test set
  drawn with a seed that no training set used is held out from it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.stats import qmc

from artifem.errors import InputError
from artifem.excitation import ExcitationSchedule

__all__ = ["each_alone", "random_schedules"]


def each_alone(
    exciters: Sequence[str], level: float, ramp_time: float
) -> dict[str, ExcitationSchedule]:
    """{exciter: that exciter alone ramped to ``level`` over ``ramp_time``, then held}."""
    return {e: ExcitationSchedule.ramp_and_hold({e: level}, ramp_time) for e in exciters}


def _range(value, name: str, low: float = 0.0) -> tuple[float, float]:
    a, b = (float(v) for v in value)
    if not (np.isfinite(a) and np.isfinite(b) and low <= a <= b):
        raise InputError(
            f"random_schedules: {name} must be a range (low, high) with "
            f"{low} <= low <= high, got {value!r}"
        )
    return a, b


def random_schedules(
    exciters: Sequence[str],
    count: int,
    *,
    seed: int,
    duration: float,
    excitation: tuple[float, float] = (0.1, 1.0),
    active: tuple[int, int] = (2, 5),
    ramp: tuple[float, float] = (0.1, 0.5),
    onset: float = 0.2,
    release: tuple[float, float] = (0.1, 0.4),
    prefix: str = "random",
) -> dict[str, ExcitationSchedule]:
    """``count`` schedules over ``exciters`` (module docstring), named
    ``{prefix}-{seed}-{i}``; the same arguments give the same schedules."""
    exciters = list(exciters)
    if not exciters or len(set(exciters)) != len(exciters):
        raise InputError(f"random_schedules: exciters must be distinct names, got {exciters}")
    if int(count) != count or count < 1:
        raise InputError(f"random_schedules: count must be a positive integer, got {count!r}")
    if not np.isfinite(duration) or duration <= 0:
        raise InputError(f"random_schedules: duration must be positive, got {duration!r}")
    lo, hi = _range(excitation, "excitation")
    if hi > 1.0:
        raise InputError(f"random_schedules: excitations are in [0, 1], got {excitation!r}")
    k_lo, k_hi = (int(k) for k in active)
    if not 1 <= k_lo <= k_hi:
        raise InputError(
            f"random_schedules: active must be (low, high) with 1 <= low <= high, got {active!r}"
        )
    k_hi = min(k_hi, len(exciters))
    k_lo = min(k_lo, k_hi)
    ramp, release = _range(ramp, "ramp", 1e-6), _range(release, "release", 1e-6)
    n = len(exciters)
    rng = np.random.default_rng(seed)
    # per schedule: the active count, then per exciter (level, onset, ramp, hold, release)
    x = qmc.LatinHypercube(d=1 + 5 * n, seed=rng).random(int(count))
    schedules = {}
    for i, row in enumerate(x):
        k = k_lo + min(int(row[0] * (k_hi - k_lo + 1)), k_hi - k_lo)
        chosen = sorted(rng.choice(n, size=k, replace=False))
        knots, curves = [np.array([0.0, duration])], {}
        for e in chosen:
            level, t_on, T_ramp, hold, T_release = row[1 + 5 * e : 6 + 5 * e]
            a = lo + (hi - lo) * level
            t_on = onset * duration * t_on
            t_full = t_on + ramp[0] + (ramp[1] - ramp[0]) * T_ramp
            t_off = t_full + hold * duration
            t_zero = t_off + release[0] + (release[1] - release[0]) * T_release
            t = np.array([0.0, t_on, t_full, t_off, t_zero])
            curves[exciters[e]] = (t, np.array([0.0, 0.0, a, a, 0.0]))
            knots.append(t[t < duration])
        times = np.unique(np.round(np.concatenate(knots), 12))
        schedules[f"{prefix}-{seed}-{i}"] = ExcitationSchedule(
            times, {name: np.interp(times, t, a) for name, (t, a) in curves.items()}
        )
    return schedules
