"""``artifem study masseter``: the five masseter models compared (the model:
:mod:`artifem.models.masseter.model`).

Measurement (:func:`simulate`): ``steps`` semi-implicit coupled steps (dt) with the
excitation ramped linearly from 0 to a (ms per step: the median), then the static
equilibrium at a (Newton, :meth:`Scene.solve_static`), then one step at equilibrium
whose weld reaction gives the force the muscle transmits to the jaw,
F_jaw = -(the weld's force on the jaw) (and the same for the arch: F_jaw + F_arch = 0).

Measured (2.5 mm cells, excitation 0.1, serial; docs/masseter.md): jaw force 2.35 N
(embedding) and 2.41 N (conforming) without aponeuroses, 1.94 / 2.02 N with the embedded
membranes and 1.97 N with conforming slabs (aponeuroses: -16 to -18 % in every
representation); 4,221 / 3,057 masters, and 28,644 with the slabs (about 2.2 s per step
against 0.05-0.26 s).

``artifem study masseter --out DIR [--excitation A] [--steps N] [--coarse]`` writes
DIR/masseter.png and DIR/masseter.json; the measured table is in docs/masseter.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from artifem.arguments import fraction, positive_int
from artifem.errors import InputError
from artifem.excitation import ExcitationSchedule
from artifem.models.masseter.model import (
    COARSE,
    MODELS,
    MasseterConfig,
    MasseterModel,
    build_model,
    dof_counts,
)
from artifem.models.masseter.render import render
from artifem.scene import Run, simulate as simulate_scene


def jaw_forces(model: MasseterModel, h: float) -> dict:
    """One step h at the current state; the forces the muscle transmits to the jaw and the
    arch, F = -(the weld's force on the body), and their sum (0 at equilibrium)."""
    model.scene.step(h)
    f_jaw = -model.scene.reaction(model.jaw_joint)[0][:3]
    f_arch = -model.scene.reaction(model.arch_joint)[0][:3]
    return {
        "jaw_force_N": f_jaw.tolist(),
        "jaw_force_magnitude_N": float(np.linalg.norm(f_jaw)),
        "arch_force_N": f_arch.tolist(),
        "force_balance_N": float(np.linalg.norm(f_jaw + f_arch)),
    }


def ramp(model: MasseterModel, excitation: float, steps: int) -> Run:
    """``steps`` coupled steps of ``config.dt`` from the scene's time, the excitation ramped
    linearly from 0 to ``excitation`` over them (a controller: ``excitation * k / steps``
    at the end of step k, then held), timed by :func:`artifem.scene.simulate`."""
    dt, t = model.config.dt, model.scene.t
    schedule = ExcitationSchedule(
        np.array([t, t + steps * dt]), {"masseter": np.array([0.0, excitation])}
    )
    control = schedule.controller(model.primary)
    model.scene.add_controller(control)  # for this ramp only
    try:
        run = simulate_scene(model.scene, steps * dt, dt, progress=False)
    finally:
        model.scene.controllers.remove(control)
    model.primary.set_excitation("masseter", excitation)  # held (no round-off in t)
    return run


def simulate(
    model: MasseterModel, *, excitation: float | None = None, steps: int | None = None
) -> dict:
    """Ramp the excitation over ``steps`` coupled steps (timed), solve the statics at the
    final excitation, and measure the jaw force (module docstring)."""
    c = model.config
    a = c.excitation if excitation is None else excitation
    n = c.steps if steps is None else steps
    if not 0.0 <= a <= 1.0:
        raise InputError(f"masseter: excitation must be in [0, 1], got {a!r}")
    run = ramp(model, a, n)
    t0 = time.perf_counter()
    iterations = model.scene.solve_static()
    static_s = time.perf_counter() - t0
    out = {
        "model": model.label,
        "excitation": a,
        "steps": n,
        "dt": c.dt,
        "ms_per_step": run.ms_per_step,
        "ms_per_step_all": run.step_ms.tolist(),
        "static_newton_iterations": iterations,
        "static_s": static_s,
        **dof_counts(model),
        **jaw_forces(model, c.dt),
    }
    u = model.primary.u.x.array.reshape(-1, 3)
    out["max_displacement_mm"] = 1e3 * float(np.linalg.norm(u, axis=1).max())
    out["min_det_F"] = float(np.nanmin(model.primary.det_F()))
    out["mass_kg"] = float(model.primary.total_mass())
    out.update(model.info)
    return out


def benchmark(steps: int = 5, config: MasseterConfig | None = None, quick: bool = False) -> dict:
    """Milliseconds per coupled step (median of ``steps``, excitation ramp) of the embedding
    and conforming masseter models, with and without aponeuroses, and their masters.
    ``quick``: on the coarse setting (:data:`COARSE`) unless ``config`` is given."""
    config = config or MasseterConfig(**(COARSE if quick else {}))
    cases = {}
    for primary, apo in MODELS:
        model = build_model(config, primary, apo)
        cases[f"{primary}/{apo}"] = {
            "ms_per_step": ramp(model, config.excitation, steps).ms_per_step,
            **dof_counts(model),
        }
    return {
        "benchmark": "masseter",
        "steps": steps,
        "dt": config.dt,
        "cases": cases,
        "geometry": "synthetic",
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--excitation", type=fraction, default=MasseterConfig.excitation)
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=MasseterConfig.steps,
        help="timed coupled steps (excitation ramp) before the statics",
    )
    parser.add_argument(
        "--coarse", action="store_true", help="5 mm voxels and tets (the test setting): quick"
    )


def run(args: argparse.Namespace) -> int:
    report(args)
    return 0


def report(args: argparse.Namespace) -> dict:
    """All models: simulate, render (masseter.png) and write masseter.json."""
    config = MasseterConfig(
        excitation=args.excitation,
        steps=args.steps,
        **({k: v for k, v in COARSE.items() if k != "steps"} if args.coarse else {}),
    )
    args.out.mkdir(parents=True, exist_ok=True)
    results, models = {}, []
    for primary, apo in MODELS:
        model = build_model(config, primary, apo)
        results[model.label] = simulate(model)
        print(
            f"{model.label}: {results[model.label]['masters']} masters, "
            f"{results[model.label]['ms_per_step']:.0f} ms/step, jaw force "
            f"{results[model.label]['jaw_force_magnitude_N']:.3f} N",
            flush=True,
        )
        models.append(model)
    png = render(models, args.out / "masseter.png")
    summary = {
        "geometry": "synthetic (no public masseter data; see models/masseter.py)",
        "config": dataclasses.asdict(config),
        "models": results,
        "png": str(png),
    }
    (args.out / "masseter.json").write_text(json.dumps(summary, indent=2))
    return summary
