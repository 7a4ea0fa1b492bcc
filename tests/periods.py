"""The period of a sampled oscillation, shared by the pendulum and spring tests."""

import numpy as np


def zero_crossing_period(t, x) -> float:
    """Mean period from the upward zero crossings of x(t), each linearly interpolated
    between its two samples (an O(h^2) error in place of the O(h) of the sample index)."""
    t, x = np.asarray(t), np.asarray(x)
    i = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    crossings = t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])
    assert crossings.size >= 3, "too few oscillations to measure a period"
    return float(np.diff(crossings).mean())
