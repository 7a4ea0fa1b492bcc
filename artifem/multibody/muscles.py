"""Point-to-point axial springs and Thelen (2003) Hill-type muscles acting on points.

Everything here acts on *points*: whatever can report world positions and
velocities (rigid-body markers, FEM nodes, points attached to full or reduced
FEM bodies) can carry a spring or a muscle; the caller maps the point forces
and Jacobians to its own coordinates (f_m = G^T f_a, K_m = G^T K G, ...; Lloyd
et al. 2019, section 3).

A *path* is a polyline through n >= 2 points x_0 ... x_{n-1}: the two ends and,
in between, optional frictionless via points (fixed or moving; ArtiSynth's
MultiPointSpring, OpenSim's path points). With unit segment directions
u_i = (x_{i+1} - x_i)/l_i the path length, its rate and their derivatives are

    L = sum_i l_i,   Ldot = sum_i u_i . (v_{i+1} - v_i) = g . v,   g = dL/dx,
    H = d2L/dx2,     block (I - u_i u_i^T)/l_i for segment i,

and an element with tension T(L, Ldot) (positive pulls the points together)
puts the forces f = -T g on the points. Its Jacobians, used by a linearised
implicit step (ArtiSynth's M - h D - h^2 K), are the derivatives of the
*forces* (not of -f):

    K = df/dx = -g (T_L g + T_Ldot H v)^T - T H,     D = df/dv = -T_Ldot g g^T.

For two points this is f_a = T u, f_b = -T u. K is not symmetric when
T_Ldot != 0 (the muscle's force-velocity term); D is then nonzero.

Elements:

* ``AxialSpring`` -- linear spring with axial damping, T = k (L - L0) + c Ldot.
* ``ThelenMuscle`` -- Thelen D.G., "Adjustment of muscle mechanics model
  parameters to simulate dynamic contractions in older adults", J Biomech Eng
  125:70-77 (2003), as implemented in OpenSim's Thelen2003Muscle (curve
  constants, fixed-width pennation) and ArtiSynth's Thelen2003AxialMuscle
  (rigid tendon). Rigid tendon (default) and elastic tendon (fiber length as a
  state, tendon-fiber force equilibrium solved per step by a safeguarded
  Newton iteration with a backward-Euler fiber velocity). Activation from
  excitation by Thelen's first-order dynamics, or activation = excitation.

The normalized curves are pure numpy functions (``active_force_length``,
``passive_force_length``, ``force_velocity``, ``force_velocity_inverse``,
``tendon_force_strain``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from artifem.errors import InputError, SolverError

# ---------------------------------------------------------------------------------------------
# validation helpers
# ---------------------------------------------------------------------------------------------


def _real(owner: str, name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{owner}: {name} must be a real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise InputError(f"{owner}: {name} must be finite, got {value}")
    return value


def _positive(owner: str, name: str, value) -> float:
    value = _real(owner, name, value)
    if value <= 0.0:
        raise InputError(f"{owner}: {name} must be > 0, got {value}")
    return value


def _nonnegative(owner: str, name: str, value) -> float:
    value = _real(owner, name, value)
    if value < 0.0:
        raise InputError(f"{owner}: {name} must be >= 0, got {value}")
    return value


def _curve_param(curve: str, name: str, value, *, lower: float = 0.0) -> float:
    """A curve constant: finite and > lower."""
    value = float(value)
    if not math.isfinite(value) or value <= lower:
        raise InputError(f"{curve}: {name} must be finite and > {lower:g}, got {value}")
    return value


def _points(name: str, array, n: int | None = None) -> np.ndarray:
    arr = np.asarray(array, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < 2:
        raise InputError(
            f"{name} must be an (n, 3) array with n >= 2 path points "
            f"(the two ends and any via points), got shape {arr.shape}"
        )
    if n is not None and arr.shape[0] != n:
        raise InputError(f"{name} has {arr.shape[0]} points, the positions have {n}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite")
    return arr


def _result(value: np.ndarray, derivative: np.ndarray | None, scalar: bool):
    if scalar:
        value = float(value)
        derivative = None if derivative is None else float(derivative)
    return value if derivative is None else (value, derivative)


# ---------------------------------------------------------------------------------------------
# Thelen 2003 normalized curves (pure numpy)
# ---------------------------------------------------------------------------------------------


def active_force_length(fiber_length, width: float = 0.45, *, derivative: bool = False):
    """Active force-length multiplier, Thelen 2003 eq. (4): f_L = exp(-(l - 1)^2 / gamma).

    ``fiber_length`` is normalized by the optimal fiber length; ``width`` is gamma
    (OpenSim's KshapeActive, 0.45). Peak 1 at l = 1. With ``derivative`` also
    returns df_L/dl = -2 (l - 1)/gamma f_L.
    """
    gamma = _curve_param("active_force_length", "width (gamma)", width)
    x = np.asarray(fiber_length, dtype=float)
    f = np.exp(-((x - 1.0) ** 2) / gamma)
    df = -2.0 * (x - 1.0) / gamma * f if derivative else None
    return _result(f, df, x.ndim == 0)


#: |l - 1| within which a normalized fiber length is the optimal one for f_PE's slope:
#: f_PE has a kink at l = 1 (zero below, slope k_PE / (eps0M (e^k_PE - 1)) above), and a
#: muscle whose optimal length is its starting length sits on it at round-off (a jump of
#: f_PE below 1e-11 of F0 here).
REST_STRAIN = 1e-10


def passive_force_length(
    fiber_length, shape: float = 5.0, strain_at_one: float = 0.6, *, derivative: bool = False
):
    """Passive force-length multiplier, Thelen 2003 eq. (3):

        f_PE = (exp(k_PE (l - 1)/eps0M) - 1) / (exp(k_PE) - 1)   for l > 1, 0 otherwise,

    so f_PE = 1 at strain eps0M (l = 1 + eps0M). ``shape`` is k_PE (OpenSim's
    KshapePassive, 5), ``strain_at_one`` eps0M (FmaxMuscleStrain, 0.6 young /
    0.5 old). Zero below the optimal length as in OpenSim's Thelen2003Muscle
    (the paper's formula would dip to -1/(e^k_PE - 1) there), and up to
    :data:`REST_STRAIN` above it.
    """
    kpe = _curve_param("passive_force_length", "shape (k_PE)", shape)
    e0 = _curve_param("passive_force_length", "strain_at_one (eps0M)", strain_at_one)
    x = np.asarray(fiber_length, dtype=float)
    # at the optimal length (where models often start) the slope jumps from 0: within
    # REST_STRAIN of it the fiber counts as unstretched, whatever the round-off's sign
    stretched = x > 1.0 + REST_STRAIN
    with np.errstate(over="ignore"):
        ex = np.exp(kpe * (np.where(stretched, x, 1.0) - 1.0) / e0)
    denom = math.expm1(kpe)
    f = np.where(stretched, (ex - 1.0) / denom, 0.0)
    df = np.where(stretched, kpe / e0 * ex / denom, 0.0) if derivative else None
    return _result(f, df, x.ndim == 0)


#: |v| below which a normalized fiber velocity is rest for f_V's slope (1e-10 of the maximum
#: shortening velocity). Thelen's f_V has a kink at v = 0 (the lengthening slope is twice
#: the shortening one), so the damping a step linearizes with jumps there; a scene at rest
#: has fiber velocities at round-off (measured: 1e-17 to 6e-15) whose sign is the
#: machine's (its BLAS kernels), and the first step from rest took one slope or the other:
#: the jaw-tongue's opener turned the jaw 2.6 % more in 0.1 s on one machine than on
#: another. At rest the slope is the shortening one, f_V's left slope at v = 0 (as at an
#: exact 0 before).
REST_VELOCITY = 1e-10


def _fv_lengthening_slope(af: float, c1_at_zero: bool) -> float:
    return (1.0 + 1.0 / af) if c1_at_zero else (2.0 + 2.0 / af)


def force_velocity(
    velocity,
    af: float = 0.25,
    flen: float = 1.4,
    *,
    c1_at_zero: bool = False,
    derivative: bool = False,
):
    """Force-velocity multiplier f_V(v), the inverse of Thelen 2003 eqs. (6)-(7).

    ``velocity`` is the fiber velocity normalized by the activation-scaled
    maximum, v = v_M / ((0.25 + 0.75 a) v_max l_0): -1 is the maximum shortening
    velocity. Thelen writes v(f) with f = F_M/(a f_L); solved for f:

        shortening  (-1 <= v <= 0):  f = (1 + v) / (1 - v/A_f)
        lengthening (v > 0):         f = (k v F_len + F_len - 1) / (k v + F_len - 1),
                                     k = 2 + 2/A_f

    f(-1) = 0, f(0) = 1, f -> F_len as v -> inf; f = 0 below -1. The lengthening
    slope at 0 is twice the shortening slope (1 + 1/A_f), by Thelen's design (the
    derivative for |v| <= :data:`REST_VELOCITY` is the shortening one: rest);
    ``c1_at_zero`` uses k = 1 + 1/A_f instead (ArtiSynth's Thelen2003AxialMuscle
    modification, continuous slope). Defaults: A_f = 0.25, F_len = 1.4 (young
    adults; OpenSim's default is 1.8).
    """
    af = _curve_param("force_velocity", "af", af)
    flen = _curve_param("force_velocity", "flen", flen, lower=1.0)
    k = _fv_lengthening_slope(af, c1_at_zero)
    d = flen - 1.0
    v = np.asarray(velocity, dtype=float)
    vs = np.clip(v, -1.0, 0.0)
    vl = np.maximum(v, 0.0)
    short = (1.0 + vs) / (1.0 - vs / af)
    length = (k * vl * flen + d) / (k * vl + d)
    f = np.where(v <= -1.0, 0.0, np.where(v <= 0.0, short, length))
    df = None
    if derivative:
        dshort = (1.0 + 1.0 / af) / (1.0 - vs / af) ** 2
        dlength = k * d * d / (k * vl + d) ** 2
        df = np.where(v <= -1.0, 0.0, np.where(v <= REST_VELOCITY, dshort, dlength))
    return _result(f, df, v.ndim == 0)


def force_velocity_inverse(force, af: float = 0.25, flen: float = 1.4, *, c1_at_zero: bool = False):
    """Normalized fiber velocity for a force-velocity multiplier f in [0, F_len): Thelen 2003
    eqs. (6)-(7),

        v = (f - 1)/(1 + f/A_f)                          for f <= 1,
        v = (f - 1)(F_len - 1) / (k (F_len - f))        for 1 < f < F_len,  k = 2 + 2/A_f,

    in units of (0.25 + 0.75 a) v_max l_0. Raises ValueError outside [0, F_len).
    """
    af = _curve_param("force_velocity_inverse", "af", af)
    flen = _curve_param("force_velocity_inverse", "flen", flen, lower=1.0)
    k = _fv_lengthening_slope(af, c1_at_zero)
    f = np.asarray(force, dtype=float)
    if np.any(~np.isfinite(f)) or np.any(f < 0.0) or np.any(f >= flen):
        raise InputError(
            f"force_velocity_inverse: multipliers must lie in [0, flen={flen}), "
            f"got range [{np.min(f)}, {np.max(f)}]"
        )
    fs = np.minimum(f, 1.0)
    fl = np.maximum(f, 1.0)
    v = np.where(
        f <= 1.0, (fs - 1.0) / (1.0 + fs / af), (fl - 1.0) * (flen - 1.0) / (k * (flen - fl))
    )
    return _result(v, None, f.ndim == 0)


def tendon_toe_constants(
    strain_at_one: float = 0.04, k_toe: float = 3.0, f_toe: float = 0.33
) -> tuple[float, float]:
    """(eps_toe, k_lin) of the tendon curve: the toe ends at eps_toe with force F_toe and the
    linear part has slope k_lin; both chosen so that f_T(eps0T) = 1 and the slope is
    continuous at eps_toe:

        c = F_toe k_toe e^k_toe/(e^k_toe - 1),  eps_toe = c eps0T/(1 - F_toe + c),
        k_lin = (1 - F_toe)/(eps0T - eps_toe).

    For k_toe = 3, F_toe = 0.33 these are OpenSim's exact values
    eps_toe = 99 e^3 eps0T/(166 e^3 - 67) = 0.6086 eps0T and k_lin = 0.67/(eps0T - eps_toe)
    = 1.712/eps0T, the paper's rounded 0.609 eps0T and 1.712/eps0T.
    """
    e0 = _curve_param("tendon_force_strain", "strain_at_one (eps0T)", strain_at_one)
    k = _curve_param("tendon_force_strain", "k_toe", k_toe)
    ft = float(f_toe)
    if not (0.0 < ft < 1.0):
        raise InputError(f"tendon_force_strain: f_toe must be in (0, 1), got {f_toe}")
    c = ft * k * math.exp(k) / math.expm1(k)
    eps_toe = c * e0 / (1.0 - ft + c)
    return eps_toe, (1.0 - ft) / (e0 - eps_toe)


def tendon_force_strain(
    strain,
    strain_at_one: float = 0.04,
    k_toe: float = 3.0,
    f_toe: float = 0.33,
    *,
    derivative: bool = False,
):
    """Normalized tendon force, Thelen 2003 eq. (5):

        f_T = F_toe/(e^k_toe - 1) (exp(k_toe eps/eps_toe) - 1)   0 < eps <= eps_toe
        f_T = k_lin (eps - eps_toe) + F_toe                       eps > eps_toe
        f_T = 0                                                   eps <= 0

    with eps_toe, k_lin from ``tendon_toe_constants`` (f_T(eps0T) = 1). Default
    eps0T = 0.04 (ArtiSynth's default; Thelen and OpenSim use 0.033).
    """
    eps_toe, k_lin = tendon_toe_constants(strain_at_one, k_toe, f_toe)
    e = np.asarray(strain, dtype=float)
    et = np.clip(e, 0.0, eps_toe)
    scale = f_toe / math.expm1(k_toe)
    toe = scale * np.expm1(k_toe * et / eps_toe)
    f = np.where(e <= 0.0, 0.0, np.where(e <= eps_toe, toe, k_lin * (e - eps_toe) + f_toe))
    df = None
    if derivative:
        dtoe = scale * k_toe / eps_toe * np.exp(k_toe * et / eps_toe)
        df = np.where(e <= 0.0, 0.0, np.where(e <= eps_toe, dtoe, k_lin))
    return _result(f, df, e.ndim == 0)


# ---------------------------------------------------------------------------------------------
# path geometry and point forces
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PathGeometry:
    """Length L, rate Ldot, gradient g = dL/dx (n, 3), Hessian H = d2L/dx2 (3n, 3n) and
    dLdot/dx = H v (3n,) of a polyline through n points."""

    length: float
    length_rate: float
    gradient: np.ndarray
    hessian: np.ndarray
    rate_gradient: np.ndarray

    @classmethod
    def of(cls, positions, velocities=None) -> PathGeometry:
        x = _points("positions", positions)
        v = np.zeros_like(x) if velocities is None else _points("velocities", velocities, len(x))
        n = len(x)
        d = np.diff(x, axis=0)
        seg = np.linalg.norm(d, axis=1)
        scale = max(1.0, float(np.max(np.abs(x))))
        short = np.flatnonzero(seg <= 1e-12 * scale)
        if short.size:
            i = int(short[0])
            raise InputError(
                f"path points {i} and {i + 1} coincide (segment length {seg[i]:.3g}): "
                "the force direction is undefined"
            )
        u = d / seg[:, None]
        g = np.zeros((n, 3))
        g[:-1] -= u
        g[1:] += u
        hess = np.zeros((3 * n, 3 * n))
        eye = np.eye(3)
        for i in range(n - 1):
            a = (eye - np.outer(u[i], u[i])) / seg[i]
            s, t = slice(3 * i, 3 * i + 3), slice(3 * i + 3, 3 * i + 6)
            hess[s, s] += a
            hess[t, t] += a
            hess[s, t] -= a
            hess[t, s] -= a
        return cls(float(seg.sum()), float(np.sum(g * v)), g, hess, hess @ v.ravel())


@dataclass(frozen=True, eq=False)
class PathForces:
    """Forces on the path points and their Jacobians.

    ``forces`` (n, 3): the force on each point (tension T pulls the points
    together; they sum to zero). ``stiffness`` = d forces / d positions and
    ``damping`` = d forces / d velocities, (3n, 3n), point-major ([x0 y0 z0 x1 ...]);
    ``block(matrix, i, j)`` gives the 3x3 block of point i's force by point j.
    ``fiber`` carries the muscle's fiber state (None for springs).
    """

    forces: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    tension: float
    dtension_dlength: float
    dtension_drate: float
    length: float
    length_rate: float
    fiber: FiberState | None = None

    @classmethod
    def from_tension(
        cls,
        geometry: PathGeometry,
        tension: float,
        dt_dl: float,
        dt_dldot: float,
        fiber: FiberState | None = None,
    ) -> PathForces:
        g = geometry.gradient.ravel()
        forces = -tension * geometry.gradient
        stiffness = (
            -np.outer(g, dt_dl * g + dt_dldot * geometry.rate_gradient) - tension * geometry.hessian
        )
        damping = -dt_dldot * np.outer(g, g)
        return cls(
            forces,
            stiffness,
            damping,
            float(tension),
            float(dt_dl),
            float(dt_dldot),
            geometry.length,
            geometry.length_rate,
            fiber,
        )

    @staticmethod
    def block(matrix: np.ndarray, i: int, j: int) -> np.ndarray:
        return matrix[3 * i : 3 * i + 3, 3 * j : 3 * j + 3]


# ---------------------------------------------------------------------------------------------
# linear spring
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AxialSpring:
    """Linear axial spring-damper along a point path (two ends, optional via points):

        T = k (L - L0) + c Ldot,   E = k (L - L0)^2 / 2,   f = -T dL/dx.

    ``stiffness`` k [N/m] >= 0, ``rest_length`` L0 [m] >= 0, ``damping`` c [N s/m] >= 0.
    Compression (L < L0) pushes the points apart; the element is stateless.
    ``tension_only`` (a ligament, a cable): slack below its rest length, T = 0 and E = 0
    for L <= L0; with a ``toe`` region of length t > 0 (m) the tension rises smoothly from
    slack (Blankevoort & Huiskes 1991, OpenSim's Blankevoort1991Ligament), d = L - L0:

        T = k d^2 / (2 t) + c Ldot d / t   for 0 < d < t,   T = k (d - t/2) + c Ldot  beyond,

    so T and dT/dL are continuous (a linearized step does not flip between slack and taut
    across a kink); without a toe dT/dL jumps from 0 to k at L0.
    """

    stiffness: float
    rest_length: float = 0.0
    damping: float = 0.0
    tension_only: bool = False
    toe: float = 0.0

    def __post_init__(self):
        object.__setattr__(
            self, "stiffness", _nonnegative("AxialSpring", "stiffness", self.stiffness)
        )
        object.__setattr__(
            self, "rest_length", _nonnegative("AxialSpring", "rest_length", self.rest_length)
        )
        object.__setattr__(self, "damping", _nonnegative("AxialSpring", "damping", self.damping))
        if not isinstance(self.tension_only, (bool, np.bool_)):
            raise TypeError(
                f"AxialSpring: tension_only must be True or False, got {self.tension_only!r}"
            )
        object.__setattr__(self, "toe", _nonnegative("AxialSpring", "toe", self.toe))
        if self.toe > 0 and not self.tension_only:
            raise InputError("AxialSpring: a toe region needs tension_only=True")

    def tension(self, length: float, length_rate: float = 0.0) -> tuple[float, float, float]:
        """(T, dT/dL, dT/dLdot)."""
        k, c, t = self.stiffness, self.damping, self.toe
        d = length - self.rest_length
        if not self.tension_only:
            return k * d + c * length_rate, k, c
        if d <= 0.0:
            return 0.0, 0.0, 0.0
        if d < t:
            return (
                k * d * d / (2 * t) + c * length_rate * d / t,
                (k * d + c * length_rate) / t,
                c * d / t,
            )
        return k * (d - t / 2) + c * length_rate, k, c

    def energy(self, positions) -> float:
        """Elastic energy: k (L - L0)^2 / 2; tension only, k d^3 / (6 t) in the toe and
        k t^2 / 6 + k ((d - t/2)^2 - t^2/4) / 2 beyond (d = L - L0 > 0)."""
        k, t = self.stiffness, self.toe
        d = PathGeometry.of(positions).length - self.rest_length
        if not self.tension_only:
            return 0.5 * k * d * d
        if d <= 0.0:
            return 0.0
        if d < t:
            return k * d**3 / (6 * t)
        return k * t * t / 6 + 0.5 * k * ((d - t / 2) ** 2 - t * t / 4)

    def evaluate(self, positions, velocities=None, dt: float | None = None) -> PathForces:
        """Forces and Jacobians at the given point positions (n, 3) and velocities (n, 3)."""
        geometry = PathGeometry.of(positions, velocities)
        return PathForces.from_tension(
            geometry, *self.tension(geometry.length, geometry.length_rate)
        )

    def commit(self, result: PathForces) -> None:
        """Nothing to store (same interface as ThelenMuscle)."""


# ---------------------------------------------------------------------------------------------
# Thelen 2003 muscle
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ThelenParameters:
    """Thelen 2003 muscle parameters (SI units, angles in radians); names follow OpenSim's
    Thelen2003Muscle. Defaults: the paper's young-adult values, eps0T = 0.04 as in ArtiSynth.

    Attributes:
        max_isometric_force: F0 [N]
        optimal_fiber_length: l0 [m]
        tendon_slack_length: lTS [m] (> 0 for an elastic tendon)
        pennation_angle: alpha0 at l0, in [0, pi/2); fixed-width model
            l_M sin(alpha) = h = l0 sin(alpha0)
        max_contraction_velocity: v_max in optimal lengths per second (10)
        activation_time_constant: [s] (0.015)
        deactivation_time_constant: [s] (0.050)
        active_width: gamma of f_L (KshapeActive, 0.45)
        passive_shape: k_PE (KshapePassive, 5)
        fmax_muscle_strain: eps0M, passive strain at F0 (0.6)
        af: A_f, force-velocity shape (0.25)
        flen: F_len, lengthening plateau (1.4; OpenSim default 1.8)
        fmax_tendon_strain: eps0T, tendon strain at F0 (0.04)
        tendon_k_toe: k_toe (3)
        tendon_f_toe: F_toe (0.33)
        min_activation: lower bound on activation (0; OpenSim uses 0.01)
        max_pennation_angle: elastic tendon: the fiber length is kept above
            h / sin(this) (OpenSim/ArtiSynth acos(0.1))
        force_velocity: False ignores f_V (f_V = 1, no damping)
        fv_c1_at_zero: ArtiSynth's continuous-slope f_V at v = 0
    """

    max_isometric_force: float
    optimal_fiber_length: float
    tendon_slack_length: float
    pennation_angle: float = 0.0
    max_contraction_velocity: float = 10.0
    activation_time_constant: float = 0.015
    deactivation_time_constant: float = 0.050
    active_width: float = 0.45
    passive_shape: float = 5.0
    fmax_muscle_strain: float = 0.6
    af: float = 0.25
    flen: float = 1.4
    fmax_tendon_strain: float = 0.04
    tendon_k_toe: float = 3.0
    tendon_f_toe: float = 0.33
    min_activation: float = 0.0
    max_pennation_angle: float = math.acos(0.1)
    force_velocity: bool = True
    fv_c1_at_zero: bool = False

    def __post_init__(self):
        owner = "ThelenParameters"
        positive = (
            "max_isometric_force",
            "optimal_fiber_length",
            "max_contraction_velocity",
            "activation_time_constant",
            "deactivation_time_constant",
            "active_width",
            "passive_shape",
            "fmax_muscle_strain",
            "af",
            "fmax_tendon_strain",
            "tendon_k_toe",
        )
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("force_velocity", "fv_c1_at_zero"):
                if not isinstance(value, (bool, np.bool_)):
                    raise TypeError(f"{owner}: {f.name} must be True or False, got {value!r}")
                object.__setattr__(self, f.name, bool(value))
            elif f.name in positive:
                object.__setattr__(self, f.name, _positive(owner, f.name, value))
            else:
                object.__setattr__(self, f.name, _nonnegative(owner, f.name, value))
        if not self.pennation_angle < math.pi / 2:
            raise InputError(
                f"{owner}: pennation_angle must be in [0, pi/2) rad, "
                f"got {self.pennation_angle} (degrees given?)"
            )
        if not self.pennation_angle <= self.max_pennation_angle < math.pi / 2:
            raise InputError(
                f"{owner}: max_pennation_angle must be in [pennation_angle, pi/2), "
                f"got {self.max_pennation_angle}"
            )
        if self.flen <= 1.0:
            raise InputError(f"{owner}: flen must be > 1, got {self.flen}")
        if not 0.0 < self.tendon_f_toe < 1.0:
            raise InputError(f"{owner}: tendon_f_toe must be in (0, 1), got {self.tendon_f_toe}")
        if self.min_activation >= 1.0:
            raise InputError(
                f"{owner}: min_activation must be in [0, 1), got {self.min_activation}"
            )

    @property
    def width(self) -> float:
        """h = l0 sin(alpha0), the constant fiber-parallelogram height."""
        return self.optimal_fiber_length * math.sin(self.pennation_angle)


@dataclass(frozen=True)
class FiberState:
    """Fiber state at one evaluation (lengths in m, velocities in m/s, forces in N).

    ``clamped``: the elastic-tendon fiber sits at its minimum length (no
    equilibrium above it). ``slack``: path too short for the tendon, no force.
    """

    length: float
    velocity: float
    cos_pennation: float
    activation: float
    active_force_length: float
    passive_force_length: float
    force_velocity: float
    fiber_force: float
    tendon_strain: float
    slack: bool = False
    clamped: bool = False

    @property
    def pennation_angle(self) -> float:
        return math.acos(min(1.0, self.cos_pennation))


class ThelenMuscle:
    """Thelen 2003 Hill-type muscle (OpenSim Thelen2003Muscle) along a point path.

    Fiber force F_M = F0 (a f_L(l_M/l0) f_V(v) + f_PE(l_M/l0)),
    v = v_M / ((0.25 + 0.75 a) v_max l0);
    path tension T = F_M cos(alpha) with the fixed-width pennation l_M sin(alpha) = l0 sin(alpha0).

    ``tendon="rigid"`` (default; ArtiSynth's Thelen2003AxialMuscle): the tendon
    keeps its slack length, so l_M cos(alpha) = L - lTS, l_M = sqrt((L - lTS)^2 + h^2),
    v_M = cos(alpha) Ldot; T depends on (L, Ldot) and the damping Jacobian comes
    from f_V. Zero force when L <= lTS (with alpha0 = 0 the active force jumps
    there from F0 a f_L(0) = 0.11 F0 a to 0, far outside the physiological range).

    ``tendon="elastic"``: the fiber length l_M is a state. ``evaluate(x, v, dt)``
    solves the equilibrium f_T((L - l_M cos(alpha))/lTS - 1) = F_M cos(alpha) for the
    l_M reached from the committed length over dt, with the backward-Euler fiber
    velocity v_M = (l_M - l_M,prev)/dt (safeguarded Newton: Newton steps inside a
    bisection bracket). T is then a function of L only (D = 0) and dT/dL is the
    total derivative through l_M (implicit function theorem), i.e. the series
    stiffness of tendon and fiber-with-its-viscosity. ``commit(result)`` stores
    the solved fiber length; ``initialize_fiber(x)`` sets it to the static
    (v_M = 0) equilibrium first.

    Activation (Thelen 2003 eqs. 1-2; OpenSim's first-order activation model):

        da/dt = (u - a)/tau(a, u),  tau = tau_act (0.5 + 1.5 a)   if u > a
                                    tau = tau_deact/(0.5 + 1.5 a)  otherwise,

    advanced by ``update_activation(dt)`` with an exponential midpoint step:
    a* = u + (a_n - u) exp(-(dt/2)/tau(a_n)), a_{n+1} = u + (a_n - u) exp(-dt/tau(a*)).
    Each stage is a convex combination of a_n and u, so the update is stable
    for any dt, monotone and never overshoots u; exact when tau is constant,
    second order otherwise. With ``activation_dynamics=False`` the activation
    equals the excitation. Activations are kept in [min_activation, 1].

    Usage in a step of size h (excitation applied at the end time, as the
    excitation schedules do): ``set_excitation(u(t1))``; ``update_activation(h)``;
    ``r = evaluate(x, v, h)`` wherever the step evaluates forces; after the
    step, ``commit(r)`` with the result at the accepted state.
    """

    def __init__(
        self,
        params: ThelenParameters,
        *,
        tendon: str = "rigid",
        activation: float | None = None,
        excitation: float = 0.0,
        activation_dynamics: bool = True,
        name: str = "muscle",
    ):
        if not isinstance(params, ThelenParameters):
            raise TypeError(
                f"ThelenMuscle {name!r}: params must be ThelenParameters, "
                f"got {type(params).__name__}"
            )
        if tendon not in ("rigid", "elastic"):
            raise InputError(
                f"ThelenMuscle {name!r}: tendon must be 'rigid' or 'elastic', got {tendon!r}"
            )
        if tendon == "elastic" and params.tendon_slack_length <= 0.0:
            raise InputError(
                f"ThelenMuscle {name!r}: an elastic tendon needs "
                f"tendon_slack_length > 0, got {params.tendon_slack_length}"
            )
        self.params = params
        self.tendon = tendon
        self.name = name
        self.activation_dynamics = bool(activation_dynamics)
        self._excitation = self._check_unit("excitation", excitation)
        if activation is None:
            activation = self._excitation if not self.activation_dynamics else params.min_activation
        self._activation = max(params.min_activation, self._check_unit("activation", activation))
        if not self.activation_dynamics:
            self._activation = max(params.min_activation, self._excitation)
        self._fiber_length: float | None = None

    # -- activation ---------------------------------------------------------------------------

    def _check_unit(self, what: str, value) -> float:
        value = _real(f"ThelenMuscle {self.name!r}", what, value)
        if not 0.0 <= value <= 1.0:
            raise InputError(f"ThelenMuscle {self.name!r}: {what} must be in [0, 1], got {value}")
        return value

    @property
    def excitation(self) -> float:
        return self._excitation

    @excitation.setter
    def excitation(self, value: float) -> None:
        self.set_excitation(value)

    def set_excitation(self, value: float) -> None:
        """Set the neural excitation u in [0, 1] (also the activation without dynamics)."""
        self._excitation = self._check_unit("excitation", value)
        if not self.activation_dynamics:
            self._activation = max(self.params.min_activation, self._excitation)

    @property
    def activation(self) -> float:
        return self._activation

    @activation.setter
    def activation(self, value: float) -> None:
        self._activation = max(self.params.min_activation, self._check_unit("activation", value))

    def activation_time_constant(self, activation: float, excitation: float) -> float:
        """Thelen 2003 eq. (2): tau_act (0.5 + 1.5 a) if u > a, else tau_deact/(0.5 + 1.5 a)."""
        p = self.params
        if excitation > activation:
            return p.activation_time_constant * (0.5 + 1.5 * activation)
        return p.deactivation_time_constant / (0.5 + 1.5 * activation)

    def update_activation(self, dt: float) -> float:
        """Advance the activation over dt toward the current excitation; returns it."""
        dt = _positive(f"ThelenMuscle {self.name!r}", "dt", dt)
        if not self.activation_dynamics:
            return self._activation
        u = max(self.params.min_activation, self._excitation)
        a0 = self._activation
        a_half = u + (a0 - u) * math.exp(-0.5 * dt / self.activation_time_constant(a0, u))
        a1 = u + (a0 - u) * math.exp(-dt / self.activation_time_constant(a_half, u))
        self._activation = min(1.0, max(self.params.min_activation, a1))
        return self._activation

    # -- curves with this muscle's constants --------------------------------------------------

    def _curves(self, ln: float, vn: float):
        p = self.params
        fl, dfl = active_force_length(ln, p.active_width, derivative=True)
        fpe, dfpe = passive_force_length(ln, p.passive_shape, p.fmax_muscle_strain, derivative=True)
        if p.force_velocity:
            fv, dfv = force_velocity(vn, p.af, p.flen, c1_at_zero=p.fv_c1_at_zero, derivative=True)
        else:
            fv, dfv = 1.0, 0.0
        return fl, dfl, fpe, dfpe, fv, dfv

    def _tendon(self, strain: float):
        p = self.params
        return tendon_force_strain(
            strain, p.fmax_tendon_strain, p.tendon_k_toe, p.tendon_f_toe, derivative=True
        )

    def _vmax(self, activation: float) -> float:
        """Activation-scaled maximum shortening speed (0.25 + 0.75 a) v_max l0 [m/s]."""
        p = self.params
        return (0.25 + 0.75 * activation) * p.max_contraction_velocity * p.optimal_fiber_length

    # -- rigid tendon -------------------------------------------------------------------------

    def _rigid(self, length: float, rate: float):
        p = self.params
        a = self._activation
        x = length - p.tendon_slack_length  # fiber length along the tendon, l_M cos(alpha)
        h = p.width
        if x <= 0.0:
            fiber = FiberState(h, 0.0, 0.0, a, 0.0, 0.0, 1.0, 0.0, 0.0, slack=True)
            return 0.0, 0.0, 0.0, fiber
        lm = math.hypot(x, h)
        c = x / lm  # cos(alpha)
        dc = h * h / lm**3  # d cos(alpha) / dL
        l0, f0 = p.optimal_fiber_length, p.max_isometric_force
        vscale = self._vmax(a)
        vm = c * rate
        fl, dfl, fpe, dfpe, fv, dfv = self._curves(lm / l0, vm / vscale)
        g = a * fl * fv + fpe
        dg_dl = (a * dfl * fv + dfpe) * c / l0 + a * fl * dfv * dc * rate / vscale
        dg_drate = a * fl * dfv * c / vscale
        tension = f0 * g * c
        fiber = FiberState(lm, vm, c, a, fl, fpe, fv, f0 * g, 0.0)
        return tension, f0 * (dg_dl * c + g * dc), f0 * c * dg_drate, fiber

    # -- elastic tendon -----------------------------------------------------------------------

    def _min_fiber_length(self) -> float:
        p = self.params
        return max(0.01 * p.optimal_fiber_length, p.width / math.sin(p.max_pennation_angle))

    def _equilibrium(self, lm: float, length: float, lm_prev: float | None, dt: float | None):
        """Residual R = F_T - F_M cos(alpha), dR/dl_M, dR/dL, and the pieces, at fiber length lm."""
        p = self.params
        a = self._activation
        h, l0, f0, lts = (
            p.width,
            p.optimal_fiber_length,
            p.max_isometric_force,
            p.tendon_slack_length,
        )
        proj = math.sqrt(max(lm * lm - h * h, 0.0))  # l_M cos(alpha)
        c = proj / lm
        dproj = lm / proj
        dc = h * h / (proj * lm * lm)
        strain = (length - proj) / lts - 1.0
        ft, dft = self._tendon(strain)
        vscale = self._vmax(a)
        vm = 0.0 if dt is None else (lm - lm_prev) / dt
        fl, dfl, fpe, dfpe, fv, dfv = self._curves(lm / l0, vm / vscale)
        g = a * fl * fv + fpe
        dg = (a * dfl * fv + dfpe) / l0 + (0.0 if dt is None else a * fl * dfv / (vscale * dt))
        residual = f0 * (ft - g * c)
        dr_dlm = f0 * (-dft * dproj / lts - dg * c - g * dc)
        dr_dl = f0 * dft / lts
        fiber = FiberState(lm, vm, c, a, fl, fpe, fv, f0 * g, strain)
        return residual, dr_dlm, dr_dl, f0 * ft, fiber

    def _solve_fiber(self, length: float, lm_prev: float | None, dt: float | None):
        """Fiber length in equilibrium with the tendon at path length L (bracketed Newton)."""
        p = self.params
        h, lts = p.width, p.tendon_slack_length
        lo = self._min_fiber_length()
        hi = math.hypot(length - lts, h) if length > lts else 0.0  # tendon exactly slack
        if hi <= lo:  # tendon slack for every admissible l_M
            _, _, _, ft, fiber = self._equilibrium(lo, length, lm_prev, dt)
            return ft, 0.0, replace(fiber, slack=True)
        r_lo, drm, drl, ft, fiber = self._equilibrium(lo, length, lm_prev, dt)
        if r_lo <= 0.0:  # fiber pulled to its minimum length
            return ft, drl, replace(fiber, clamped=True)
        tol = 1e-12 * p.max_isometric_force
        guess = lm_prev if lm_prev is not None else p.optimal_fiber_length
        lm = min(max(guess, lo), hi)
        for _ in range(100):
            r, drm, drl, ft, fiber = self._equilibrium(lm, length, lm_prev, dt)
            if r > 0.0:
                lo = lm
            else:
                hi = lm
            if abs(r) <= tol or hi - lo <= 1e-14 * max(1.0, hi):
                break
            step = lm - r / drm if drm < 0.0 else None
            lm = step if step is not None and lo < step < hi else 0.5 * (lo + hi)
        else:
            raise SolverError(
                f"ThelenMuscle {self.name!r}: fiber equilibrium did not converge "
                f"at path length {length} (residual {r:.3g} N)"
            )
        # T = F_T(L, l_M(L)): dT/dL = dF_T/dL + dF_T/dl_M dl_M/dL with dl_M/dL = -R_L/R_lM,
        # dF_T/dL = R_L and dF_T/dl_M = -R_L d(l_M cos alpha)/dl_M = -R_L l_M/(l_M cos alpha).
        dproj = fiber.length / math.sqrt(fiber.length**2 - h * h)
        dtdl = drl if drm == 0.0 else drl + drl * drl * dproj / drm
        return ft, dtdl, fiber

    def initialize_fiber(self, positions) -> FiberState:
        """Elastic tendon: set the fiber length to the static (v_M = 0) equilibrium at the
        path through ``positions`` with the current activation."""
        if self.tendon != "elastic":
            raise InputError(
                f"ThelenMuscle {self.name!r}: initialize_fiber is for the elastic tendon "
                "(the rigid-tendon fiber follows the path length)"
            )
        length = PathGeometry.of(positions).length
        _, _, fiber = self._solve_fiber(length, None, None)
        self._fiber_length = fiber.length
        return fiber

    @property
    def fiber_length(self) -> float | None:
        """Committed fiber length (elastic tendon), None before initialize_fiber."""
        return self._fiber_length

    # -- evaluation ---------------------------------------------------------------------------

    def tension(self, length: float, length_rate: float = 0.0, dt: float | None = None):
        """(T, dT/dL, dT/dLdot, FiberState) at path length L and rate Ldot."""
        length = _real(f"ThelenMuscle {self.name!r}", "length", length)
        if self.tendon == "rigid":
            return self._rigid(
                length, _real(f"ThelenMuscle {self.name!r}", "length_rate", length_rate)
            )
        if self._fiber_length is None:
            raise SolverError(
                f"ThelenMuscle {self.name!r}: elastic tendon without a fiber state; "
                "call initialize_fiber(positions) first"
            )
        if dt is None:
            raise InputError(
                f"ThelenMuscle {self.name!r}: the elastic tendon needs the step size dt "
                "(backward-Euler fiber velocity)"
            )
        dt = _positive(f"ThelenMuscle {self.name!r}", "dt", dt)
        tension, dtdl, fiber = self._solve_fiber(length, self._fiber_length, dt)
        return tension, dtdl, 0.0, fiber

    @property
    def conservative(self) -> bool:
        """Whether :meth:`energy` is the potential of the tension at rest (statics): with a
        rigid tendon; an elastic tendon's fiber state is left out."""
        return self.tendon == "rigid"

    def energy(self, positions) -> float:
        """The potential of the rigid-tendon tension at zero velocity and the current
        activation a, which statics holds fixed: with x = L - lTS and l_M = sqrt(x^2 + h^2),
        T dL = F0 g(l_M) dl_M, g = a f_L + f_PE, so

            W = F0 int_h^l_M g dl = F0 [a l0 sqrt(pi gamma)/2 erf((l/l0 - 1)/sqrt(gamma))
                + l0 ((eps0M/k_PE)(exp(k_PE (l/l0 - 1)/eps0M) - 1) - (l/l0 - 1))
                  / (exp(k_PE) - 1)]_h^l_M          (the passive term where l > l0),

        zero while the path is slack (L <= lTS)."""
        if not self.conservative:
            raise InputError(
                f"ThelenMuscle {self.name!r}: an elastic tendon has no energy "
                "(its fiber length is a state)"
            )
        p = self.params
        x = PathGeometry.of(positions).length - p.tendon_slack_length
        if x <= 0.0:
            return 0.0
        l0, h = p.optimal_fiber_length, p.width
        gamma, kpe, e0 = p.active_width, p.passive_shape, p.fmax_muscle_strain

        def primitive(lm: float) -> float:
            ln = lm / l0
            active = (
                self._activation
                * l0
                * math.sqrt(math.pi * gamma)
                / 2
                * math.erf((ln - 1.0) / math.sqrt(gamma))
            )
            passive = (
                l0 * (e0 / kpe * math.expm1(kpe * (ln - 1.0) / e0) - (ln - 1.0)) / math.expm1(kpe)
                if ln > 1.0
                else 0.0
            )
            return active + passive

        return p.max_isometric_force * (primitive(math.hypot(x, h)) - primitive(h))

    def evaluate(self, positions, velocities=None, dt: float | None = None) -> PathForces:
        """Forces on the path points (n, 3) and their Jacobians, at the current activation.

        ``velocities`` default to zero; ``dt`` is required by the elastic tendon only.
        """
        geometry = PathGeometry.of(positions, velocities)
        tension, dtdl, dtdrate, fiber = self.tension(geometry.length, geometry.length_rate, dt)
        return PathForces.from_tension(geometry, tension, dtdl, dtdrate, fiber)

    def commit(self, result: PathForces) -> None:
        """Accept a step: store the elastic-tendon fiber length of ``result``."""
        if self.tendon == "elastic":
            if result.fiber is None:
                raise InputError(f"ThelenMuscle {self.name!r}: commit needs a muscle result")
            self._fiber_length = result.fiber.length
