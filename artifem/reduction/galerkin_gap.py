"""Why a reduced model is further from the full run than its basis allows: the Galerkin gap.

A reduced body u = u_bar + U q (U M-orthonormal) is at best the full state's M-orthogonal
projection, q* = U^T M u*. While its excitations are held, a reduced run settles at the
reduced equilibrium U^T R(u_bar + U q) = 0, whatever its time step or damping; linearized
about a full equilibrium u* that is the energy-norm (Ritz) projection

    q_K = (U^T K U)^-1 U^T K u*,            K = dR/du at u*,

which differs from q* where the tangent is lopsided against the mass. The Petrov-Galerkin
equations W^T R(u_bar + U q) = 0 with the test basis W = K^-1 M U have q* as their
linearized solution (W^T K (U q - u*) = U^T M (U q - u*)): an oracle, since W needs the
full state.

:func:`galerkin_gap` measures this on a model's runs, at the held instant (every input
constant for ``hold`` seconds) where the reduced model is furthest from the full run, in
mean node distance (mm):

- ``reduced_mm``: the reduced model (its points) in its run, against the full run u*;
- ``best_mm``: the best approximation U q*;
- ``static_mm``: the static reduced equilibrium with every integration point, solved from
  q* at the held inputs: if it equals ``reduced_mm`` the integrator, lag and damping play
  no part;
- ``energy_mm``: the energy-norm projection q_K;
- ``full_lag_mm``: the full run from the full model's own static equilibrium u_s at the
  same inputs (a slowly creeping full run is not at equilibrium: its remaining lag is
  neither the basis' nor the reduced equations');
- against u_s: ``best_static_mm``, ``galerkin_static_mm`` (the static reduced equilibrium),
  ``energy_static_mm`` and ``oracle_pg_mm`` (the Petrov-Galerkin solve with W = K(u_s)^-1 M U,
  by Newton on the full assembly, from U^T M u_s; NaN where it does not converge);
- the reduced residual at q*, U^T (R(U q*) - R(u*)), split by the energy terms of the full
  body into ``passive`` (the bulk material), ``active`` (the muscles' fiber energy) and
  ``volumetric`` (the element penalty), the rest (a hard body's pressures, external
  loads) as ``other``: the share of each in its norm, and the share of the linearized
  correction (U^T K U)^-1 U^T (R_t(U q*) - R_t(u*)) in mean node distance;
- ``without_volumetric_mm``: the static reduced equilibrium (every point, against u*) with
  the volumetric term left out of the reduced body (the penalty, or a hard body's
  constraint): if the volumetric term locked the linear span, this would close the gap;
- with training states (``training``): ``learned_pg_mm`` {p: error against u_s}, the
  Petrov-Galerkin equilibrium with the oracle's test basis learned from them. The
  oracle's columns at the training states, K(u_k)^-1 M U, span (M-weighted POD, p
  vectors, with U) a space V; the test basis at q is the oracle's Galerkin approximation
  in V,

      W(q) = V (V^T K(U q) V)^-1 V^T M U,

  exact wherever K(U q)^-1 M U lies in V (at the training states, when K(U q) = K(u_k)).
  A candidate reduced formulation measured here with the full assembly, not yet a model.

For a model whose reduced body is alone (no rigid body carries its nodes: the full static
solve is the body's own). Everything is O(n) per quantity: a diagnosis, not a model.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
import ufl
from scipy import optimize
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc
from tqdm import tqdm

from artifem.errors import InputError, SolverError, StepFailed
from artifem.excitation import ExcitationSchedule
from artifem.fem_body import FemBody
from artifem.integrators import solve_static, solve_static_reduced
from artifem.linear_solver import LinearSolver, factor_mumps
from artifem.reduction.cubature import IntegrationPoints
from artifem.reduction.evaluation import full_run, node_mean_mm, reduced_run
from artifem.reduction.quadrature_points import quadrature_points
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from artifem.reduction.reductor import ReducedModel
from artifem.reduction.training import ArtifactCache, Snapshots

__all__ = ["galerkin_gap", "held_instant", "learned_test_spaces", "write_markdown", "PARTS"]

#: The parts of the reduced residual, in report order.
PARTS = ("passive", "active", "volumetric", "other")


def held_instant(schedule: ExcitationSchedule, times: np.ndarray, hold: float) -> np.ndarray:
    """Mask of the ``times`` at which every input of ``schedule`` has been constant for
    ``hold`` seconds (and t >= hold)."""
    knots = np.asarray(schedule.times)
    held = times >= hold - 1e-12
    for values in schedule.values.values():
        values = np.asarray(values, dtype=float)
        for k, t in enumerate(times):
            if held[k]:
                inside = knots[(knots > t - hold) & (knots < t)]
                probe = np.concatenate([[t - hold, t], inside])
                v = np.interp(probe, knots, values)
                held[k] = bool(np.all(np.abs(v - v[0]) <= 1e-12 * max(1.0, abs(v[0]))))
    return held


def _part(term_name: str) -> str:
    if term_name == "incompressibility":
        return "volumetric"
    return "passive" if term_name == "material" else "active"


class _FullBody:
    """The full body's residual, tangent and per-part residuals at given displacements."""

    def __init__(self, body: FemBody, n: int):
        self.body, self.n = body, n
        body.compile()
        self.fixed = body.fixed_components
        v = ufl.TestFunction(body.V)
        forms = {}
        for name, energy in body.term_energies().items():
            part = _part(name)
            forms[part] = forms.get(part, 0) + ufl.derivative(energy, body.u, v)
        self.forms = {part: fem.form(f) for part, f in forms.items()}

    def set(self, u: np.ndarray) -> None:
        self.body.u.x.array[: self.n] = u
        self.body.u.x.scatter_forward()

    def residual(self, u: np.ndarray, tangent: bool = False) -> np.ndarray:
        """R(u) on the free dofs (zero at fixed ones); K in ``body.K`` if ``tangent``."""
        self.set(u)
        self.body.assemble(tangent=tangent, diag=1.0)
        R = self.body.R.array[: self.n].copy()
        R[self.fixed] = 0.0
        return R

    def times(self, cols: np.ndarray, mass: bool = False) -> np.ndarray:
        """K @ cols (the last assembled tangent), or M @ cols."""
        K = self.body.K
        x, y = K.createVecs()
        out = np.empty_like(cols)
        for j in range(cols.shape[1]):
            x.array[:] = cols[:, j]
            if mass:
                self.body.mass_mult(x, y)
            else:
                K.mult(x, y)
            out[:, j] = y.array
        return out

    def solve(self, cols: np.ndarray) -> np.ndarray:
        """K^-1 cols (the last assembled tangent, fixed rows identity), by LU."""
        ksp = PETSc.KSP().create(MPI.COMM_SELF)
        ksp.setOperators(self.body.K)
        ksp.setType("preonly")
        ksp.getPC().setType("lu")
        ksp.getPC().setFactorSolverType("mumps")
        if factor_mumps(ksp) < 0:
            raise SolverError("galerkin_gap: the LU factorization of the full tangent failed")
        x, y = self.body.K.createVecs()
        out = np.empty_like(cols)
        for j in range(cols.shape[1]):
            x.array[:] = cols[:, j]
            x.array[self.fixed] = 0.0
            ksp.solve(x, y)
            out[:, j] = y.array
        ksp.destroy()
        return out

    def parts(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """R split into PARTS ("other": the rest of R)."""
        total = self.residual(u)
        self.body._muscle_layers().refresh()
        out = {}
        for part, form in self.forms.items():
            vec = fem_petsc.assemble_vector(form)
            vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            out[part] = vec.array[: self.n].copy()
            out[part][self.fixed] = 0.0
            vec.destroy()
        out["other"] = total - sum(out.values())
        return out


def _static_reduced(body: ReducedFemBody, *starts: np.ndarray) -> np.ndarray | None:
    """The static reduced equilibrium at the body's inputs from the first start that
    converges (a start may invert an integration point: the projection of a strongly
    deformed state), or None."""
    for q0 in starts:
        body.set_state((q0, np.zeros_like(q0)))
        try:
            solve_static_reduced(body, rtol=1e-10)
        except StepFailed:
            continue
        return body.q.copy()
    return None


def _petrov_galerkin(
    full: _FullBody,
    U: np.ndarray,
    test: Callable[[], np.ndarray],
    q: np.ndarray,
    max_iterations: int = 40,
) -> np.ndarray | None:
    """Newton on W^T R(U q) = 0, W = ``test()`` evaluated after the tangent at U q was
    assembled and held through the iteration's backtracking (on |W^T R|), until |W^T R| is
    1e-9 of the state's stiffness force |W^T K U q| or of its start, or a step is at
    round-off; None if it does not converge (or the start inverts an element)."""
    tol = None
    for _ in range(max_iterations):
        R = full.residual(U @ q, tangent=True)
        if not np.all(np.isfinite(R)):
            return None
        W, KU = test(), full.times(U)
        g = W.T @ R
        norm = np.linalg.norm(g)
        if tol is None:
            tol = 1e-9 * max(norm, np.linalg.norm(W.T @ (KU @ q)))
        if norm <= tol:
            return q
        dq = -np.linalg.solve(W.T @ KU, g)
        if np.linalg.norm(dq) <= 1e-12 * np.linalg.norm(q):
            return q
        step = 1.0
        while step > 1e-6:
            trial = W.T @ full.residual(U @ (q + step * dq))
            if np.all(np.isfinite(trial)) and np.linalg.norm(trial) < (1 - 1e-4 * step) * norm:
                break
            step /= 2
        else:
            return None
        q = q + step * dq
    return None


def _oracle(full: _FullBody, U: np.ndarray, W: np.ndarray, q: np.ndarray) -> np.ndarray | None:
    """The equilibrium of the fixed test basis W."""
    return _petrov_galerkin(full, U, lambda: W, q)


def _learned(
    full: _FullBody, U: np.ndarray, V: np.ndarray, MU: np.ndarray, q: np.ndarray
) -> np.ndarray | None:
    """The equilibrium g(q) = W(q)^T R(U q) = 0 of the learned test basis W(q) = V Z(q),
    Z = (V^T K(U q) V)^-1 V^T M U (module docstring). Newton with Z held per iteration
    cycles (dZ/dq is missing), so MINPACK's hybrid method (scipy.optimize.root, "hybr":
    a finite-difference Jacobian, then Broyden updates) solves it; None if it fails."""

    def g(q):
        R = full.residual(U @ q, tangent=True)
        if not np.all(np.isfinite(R)):
            return np.full(q.size, 1e30)
        return np.linalg.solve(V.T @ full.times(V), V.T @ MU).T @ (V.T @ R)

    scale = np.linalg.norm(g(q))
    if not np.isfinite(scale) or scale >= 1e30:
        return None
    found = optimize.root(g, q, method="hybr", options={"xtol": 1e-10})
    return found.x if found.success else None


def galerkin_gap(
    reduced: ReducedModel,
    schedules: dict[str, ExcitationSchedule],
    duration: float,
    dt: float,
    cache: ArtifactCache,
    *,
    hold: float = 0.1,
    training: Snapshots | None = None,
    learned_sizes: Sequence[int] = (20, 40, 80),
    training_stride: int = 2,
    progress: bool = True,
) -> list[dict]:
    """The module docstring's figures for each schedule (full runs from ``cache``, computed
    there if missing); one dict per schedule. ``training``: the training snapshots of the
    learned test spaces (every ``training_stride``-th; their excitations in the order of the
    body's muscles), of ``learned_sizes`` POD vectors each."""
    if reduced.carriers:
        raise InputError(
            f"galerkin_gap: the reduced body of model {reduced.model.name!r} is "
            "carried by rigid bodies; the diagnosis solves the body alone"
        )
    times = np.arange(int(round(duration / dt)) + 1) * dt
    spaces = (
        {}
        if training is None
        else learned_test_spaces(reduced, training, learned_sizes, training_stride, progress)
    )
    rows = []
    for name, schedule in tqdm(
        schedules.items(), desc="Galerkin gap", unit="run", disable=not progress, leave=False
    ):
        u_full = full_run(reduced.model, schedule, duration, dt, cache, progress=False)["u"]
        error = node_mean_mm(reduced_run(reduced, schedule, duration, dt)[0], u_full)
        held = held_instant(schedule, times, hold) & np.isfinite(error)
        if not held.any():
            rows.append({"run": name, "held": False})
            continue
        k = int(np.flatnonzero(held)[np.argmax(error[held])])
        rows.append(
            {
                "run": name,
                "held": True,
                "time": float(times[k]),
                "reduced_mm": float(error[k]),
                **_gap_at(reduced, schedule, float(times[k]), u_full[k], spaces),
            }
        )
    return rows


def learned_test_spaces(
    reduced: ReducedModel,
    training: Snapshots,
    sizes: Sequence[int],
    stride: int = 2,
    progress: bool = True,
) -> dict[int, np.ndarray]:
    """{p: V = span [U, p M-weighted POD vectors of K(u_k)^-1 M U over the training
    states]} (module docstring; orthonormal columns)."""
    model, U = reduced.model, reduced.basis
    scene = model.build()
    body = model.fem_body(scene)
    full = _FullBody(body, U.shape[0])
    MU = full.times(U, mass=True)
    muscles = list(body.muscles.values())
    if training.excitations.shape[1] != len(muscles):
        raise InputError(
            f"galerkin_gap: the training states have {training.excitations.shape[1]}"
            f" excitations, {body.name!r} has {len(muscles)} muscles"
        )
    columns = []
    for k in tqdm(
        range(0, training.displacements.shape[0], stride),
        desc="learned test space",
        unit="state",
        disable=not progress,
        leave=False,
    ):
        for muscle, a in zip(muscles, training.excitations[k]):
            muscle.excitation.value = float(a)
        full.residual(training.displacements[k], tangent=True)
        W = full.solve(MU)
        if np.all(np.isfinite(W)):
            columns.append(W)
    # M-weighted POD (the row sums of M as the weights); W(q) depends on span V only
    weights = np.sqrt(np.maximum(full.times(np.ones((U.shape[0], 1)), mass=True)[:, 0], 0.0))
    modes = (
        np.linalg.svd(weights[:, None] * np.concatenate(columns, axis=1), full_matrices=False)[0]
        / np.where(weights > 0, weights, 1.0)[:, None]
    )
    spaces = {}
    for p in sizes:
        V = np.linalg.qr(np.concatenate([U, modes[:, :p]], axis=1))[0]
        V[full.fixed] = 0.0
        spaces[p] = V
    return spaces


def _gap_at(
    reduced: ReducedModel,
    schedule: ExcitationSchedule,
    t: float,
    u_star: np.ndarray,
    spaces: dict[int, np.ndarray],
) -> dict:
    """The figures at one held instant t of the full state u* (a freshly built scene with
    the schedule's inputs at t)."""
    model, U = reduced.model, reduced.basis
    scene = model.build()
    body = model.fem_body(scene)
    model.drive(scene, schedule)(scene, t, t)
    n = U.shape[0]
    full = _FullBody(body, n)
    MU = full.times(U, mass=True)
    gram = U.T @ MU
    every = replace(reduced, points=all_points(body), pressure_weights=None).body(body)
    terms = body.energy_terms(merged=True)
    volumetric = [term.name for term in terms if _part(term.name) == "volumetric"]
    table = quadrature_points(body)
    kept = np.unique(
        np.concatenate([table.of_term(term) for term in terms if term.name not in volumetric])
    )
    without = ReducedFemBody(
        body,
        U,
        IntegrationPoints(kept, np.ones(kept.size), "all"),
        leave_out=volumetric,
        hold_volume=False,
        name=f"{body.name}_without_volumetric",
    )

    def mm(q, target):
        if q is None:
            return float("nan")
        return float(node_mean_mm((U @ q)[None], target[None])[0])

    q_star = np.linalg.solve(gram, MU.T @ u_star)
    static = _static_reduced(every, q_star)
    row = {"best_mm": mm(q_star, u_star), "static_mm": mm(static, u_star)}
    full.residual(u_star, tangent=True)
    KU = full.times(U)
    KUU = U.T @ KU
    row["energy_mm"] = mm(np.linalg.solve(KUU, KU.T @ u_star), u_star)
    # the residual at q* by part, and each part's linearized correction
    at_best, at_full = full.parts(U @ q_star), full.parts(u_star)
    diffs = {p: U.T @ (at_best[p] - at_full[p]) for p in PARTS if p in at_best}
    total = np.linalg.norm(sum(diffs.values()))
    row["residual_share"] = {p: float(np.linalg.norm(d) / total) for p, d in diffs.items()}
    row["correction_mm"] = {p: mm(np.linalg.solve(KUU, d), np.zeros(n)) for p, d in diffs.items()}
    row["without_volumetric_mm"] = mm(_static_reduced(without, q_star), u_star)
    # the full model's own equilibrium at the held inputs, from u*
    full.set(u_star)
    try:
        solve_static(
            body, LinearSolver(MPI.COMM_SELF, "mumps", symmetric=body.conservative), rtol=1e-10
        )
    except StepFailed as exc:
        return {**row, "full_static": str(exc)}
    u_s = body.u.x.array[:n].copy()
    q_s = np.linalg.solve(gram, MU.T @ u_s)
    galerkin = _static_reduced(every, q_s, *([] if static is None else [static]))
    row.update(
        full_lag_mm=float(node_mean_mm(u_s[None], u_star[None])[0]),
        best_static_mm=mm(q_s, u_s),
        galerkin_static_mm=mm(galerkin, u_s),
    )
    full.residual(u_s, tangent=True)
    KU = full.times(U)
    row["energy_static_mm"] = mm(np.linalg.solve(U.T @ KU, KU.T @ u_s), u_s)
    W = full.solve(MU)
    oracle = _oracle(full, U, W, q_s)
    if oracle is None and galerkin is not None:  # q_s inverts an element
        oracle = _oracle(full, U, W, galerkin)
    row["oracle_pg_mm"] = mm(oracle, u_s)
    if spaces:
        row["learned_pg_mm"] = {}
    for p, V in spaces.items():
        learned = _learned(full, U, V, MU, q_s)
        if learned is None and galerkin is not None:
            learned = _learned(full, U, V, MU, galerkin)
        row["learned_pg_mm"][str(p)] = mm(learned, u_s)
    return row


def write_markdown(rows: list[dict]) -> str:
    """The table of :func:`galerkin_gap`'s rows (mean node distances in mm)."""
    lines = [
        "| run | t (s) | reduced | best in the basis | static, every point | "
        "energy projection | without the volumetric term | full run to its equilibrium "
        "| best (equilibrium) | Galerkin (equilibrium) | energy (equilibrium) | oracle "
        "Petrov-Galerkin (equilibrium) | residual share passive / active / volumetric "
        "/ other |",
        "|" + "---|" * 13,
    ]
    for r in rows:
        if not r.get("held"):
            lines.append(f"| {r['run']} | no held instant |" + " |" * 11)
            continue
        share = " / ".join(f"{r['residual_share'].get(p, 0.0):.2f}" for p in PARTS)
        cells = [
            r["reduced_mm"],
            r["best_mm"],
            r["static_mm"],
            r["energy_mm"],
            r["without_volumetric_mm"],
            r.get("full_lag_mm"),
            r.get("best_static_mm"),
            r.get("galerkin_static_mm"),
            r.get("energy_static_mm"),
            r.get("oracle_pg_mm"),
        ]
        learned = r.get("learned_pg_mm", {})
        lines.append(
            f"| {r['run']} | {r['time']:.2f} | "
            + " | ".join("-" if c is None else f"{c:.2f}" for c in cells)
            + f" | {share} |"
            + "".join(f" {v:.2f} |" for v in learned.values())
        )
    sizes = [list(r["learned_pg_mm"]) for r in rows if r.get("learned_pg_mm")]
    if sizes:
        lines[0] += "".join(f" learned test space, p = {p} (equilibrium) |" for p in sizes[0])
        lines[1] += "---|" * len(sizes[0])
    return "\n".join(lines) + "\n"
