"""Stress response of a material at homogeneous deformations: single points and test curves.

Works for every material in ``artifem.forms`` (and any object with
``strain_energy(F, **fields)``); fields such as a0 and excitation are passed
as numpy values. The energy is compiled once per material and fields
(:func:`artifem.pointwise.evaluator_for`, FFCx), so prototyping a material
needs no mesh. Its own module, not ``artifem.forms``: forms/ holds UFL only and
imports nothing of artifem.
"""

import numpy as np

from artifem.errors import SolverError
from artifem.pointwise import evaluator_for


def point_response(material, F, **fields):
    """(psi, P, dPdF) at the homogeneous deformation gradient F (numpy 3x3).

    psi = W(F), P = dW/dF (first Piola-Kirchhoff), dPdF[i, J, k, L] = dP_iJ/dF_kL.
    """
    return evaluator_for(material, **fields)(F, **fields)


def _solve_lateral(response, stretch, free, guess):
    """Find the stretches F[d, d] for d in ``free`` that make P[d, d] = 0.

    Newton-type solve (MINPACK hybr) in s = ln(stretch) so stretches stay
    positive, with the exact Jacobian dP_dd/dF_ee from the tangent.
    """
    from scipy.optimize import root

    def deformation(s):
        F = np.diag(np.full(3, stretch))
        F[free, free] = np.exp(s)
        return F

    def residual(s):
        _, P, A = response(deformation(s))
        jacobian = np.array([[A[d, d, e, e] for e in free] for d in free]) * np.exp(s)
        return P[free, free], jacobian

    s = root(residual, np.log(guess), jac=True, method="hybr").x
    for _ in range(3):  # polish to round-off with exact Newton steps
        value, jacobian = residual(s)
        if np.linalg.cond(jacobian) > 1e12:
            break
        step = np.linalg.solve(jacobian, value)
        s = s - step
    if np.linalg.cond(jacobian) > 1e12 or not np.linalg.norm(step) < 1e-10:
        raise SolverError(
            f"no traction-free lateral stretch found at stretch {stretch}: the lateral stiffness "
            "is singular or the solve diverged; a material without lateral stiffness (e.g. a fiber "
            "alone) needs a matrix: use CombinedMaterial(matrix, fiber)"
        )
    return np.exp(s)


def _continued(solve, stretches) -> list:
    """``solve(stretch, guess)`` along ``stretches`` outward from the one nearest 1, each from
    its neighbour's solution (guess None at the first); a side ends at its first stretch
    without a solution (None from there: no traction-free state, e.g. St Venant-Kirchhoff
    stretched equibiaxially beyond sqrt(1 + (1 - nu) / (2 nu))). A SolverError at the
    stretch nearest 1 is raised: no traction-free state even there."""
    out = [None] * len(stretches)
    if not len(stretches):
        return out
    start = int(np.argmin(np.abs(np.log(stretches))))
    out[start] = solve(stretches[start], None)
    for side in (range(start + 1, len(stretches)), range(start - 1, -1, -1)):
        previous = out[start]
        for k in side:
            try:
                previous = out[k] = solve(stretches[k], previous)
            except SolverError:
                break
    return out


def _nominal(response, diagonal) -> np.ndarray:
    """P of F = diag(``diagonal``); NaN where a stretch is (a curve that ended)."""
    if np.isnan(diagonal).any():
        return np.full((3, 3), np.nan)
    return response(np.diag(diagonal))[1]


def stress_stretch_curves(material, stretches, shears=None, **fields):
    """Nominal (first Piola-Kirchhoff) stress along three homogeneous tests.

    - "uniaxial": F = diag(l, t2, t3) with t2, t3 solved so P22 = P33 = 0
      (traction-free sides); keys stretch, P11, P22, P33, lateral_stretch_2, lateral_stretch_3.
    - "equibiaxial": F = diag(l, l, t3) with P33 = 0; keys stretch, P11, P22, P33,
      lateral_stretch_3.
    - "simple_shear": F = I + g e1 (x) e2 for g in ``shears`` (default stretches - 1);
      keys shear, P12, P11, P22.

    The lateral solves keep F diagonal, which is traction-free only if the
    coordinate axes stay principal (isotropic materials, fibers along an axis). They run
    outward from the stretch nearest 1; a curve ends (NaN from there) where the material
    has no traction-free state, and a SolverError is raised when even the stretch nearest
    1 has none (a material without lateral stiffness).
    """
    stretches = np.asarray(stretches, dtype=float)
    shears = stretches - 1.0 if shears is None else np.asarray(shears, dtype=float)

    def response(F):
        return point_response(material, F, **fields)

    uniaxial = {
        key: []
        for key in ("stretch", "P11", "P22", "P33", "lateral_stretch_2", "lateral_stretch_3")
    }
    equibiaxial = {key: [] for key in ("stretch", "P11", "P22", "P33", "lateral_stretch_3")}
    lateral_uniaxial = _continued(
        lambda stretch, guess: _solve_lateral(
            response, stretch, [1, 2], np.full(2, stretch**-0.5) if guess is None else guess
        ),
        stretches,
    )
    lateral_biaxial = _continued(
        lambda stretch, guess: _solve_lateral(
            response, stretch, [2], np.array([stretch**-2.0]) if guess is None else guess
        ),
        stretches,
    )
    for stretch, lateral in zip(stretches, lateral_uniaxial):
        lateral = np.full(2, np.nan) if lateral is None else lateral
        P = _nominal(response, [stretch, *lateral])
        for key, value in zip(uniaxial, (stretch, P[0, 0], P[1, 1], P[2, 2], *lateral)):
            uniaxial[key].append(value)
    for stretch, lateral in zip(stretches, lateral_biaxial):
        t3 = np.nan if lateral is None else lateral[0]
        P = _nominal(response, [stretch, stretch, t3])
        for key, value in zip(equibiaxial, (stretch, P[0, 0], P[1, 1], P[2, 2], t3)):
            equibiaxial[key].append(value)

    shear = {key: [] for key in ("shear", "P12", "P11", "P22")}
    for amount in shears:
        F = np.eye(3)
        F[0, 1] = amount
        _, P, _ = response(F)
        for key, value in zip(shear, (amount, P[0, 1], P[0, 0], P[1, 1])):
            shear[key].append(value)

    return {
        name: {key: np.asarray(values) for key, values in curve.items()}
        for name, curve in (
            ("uniaxial", uniaxial),
            ("equibiaxial", equibiaxial),
            ("simple_shear", shear),
        )
    }


def plot_stress_stretch(curves, png_path, title=None):
    """Write a three-panel PNG (uniaxial P11, equibiaxial P11, simple-shear P12/P11/P22) of
    ``curves``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(12, 4), layout="constrained")
    FigureCanvasAgg(figure)
    uniaxial, biaxial, shear = figure.subplots(1, 3)
    uniaxial.plot(curves["uniaxial"]["stretch"], curves["uniaxial"]["P11"], "o-")
    uniaxial.set(title="uniaxial (traction-free sides)", xlabel="stretch", ylabel="P11")
    biaxial.plot(curves["equibiaxial"]["stretch"], curves["equibiaxial"]["P11"], "o-")
    biaxial.set(title="equibiaxial (traction-free e3)", xlabel="stretch", ylabel="P11")
    for key, style in (("P12", "o-"), ("P11", "--"), ("P22", ":")):
        shear.plot(curves["simple_shear"]["shear"], curves["simple_shear"][key], style, label=key)
    shear.set(title="simple shear", xlabel="shear", ylabel="nominal stress")
    shear.legend()
    for axes in (uniaxial, biaxial, shear):
        axes.grid(True, alpha=0.3)
    if title:
        figure.suptitle(title)
    figure.savefig(png_path, dpi=120)
    return png_path
