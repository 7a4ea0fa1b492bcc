"""The reduced foot (the seed paper's section 2.3, Fig. 7): the tissue through the reductor,
with its bones, ligaments, muscles and contacts as in the full scene.

The reductor (:mod:`artifem.reduction.reductor`) replaces the tissue by a reduced body,
x = X + U q + sum_c L_c g_c: U from POD of training snapshots, L_c the 12 lift columns of
each of the 11 bone groups that carry tissue nodes; the node attachments, the floor
contact (rows U_s^T n) and the muscle and ligament paths follow it. The paper's
configuration is 6 POD vectors and 100 random integration points (:data:`PAPER`).

Training and held-out inputs (:data:`TRAINING`, :data:`HELD_OUT`), over the scene inputs of
:func:`reducible`:

- ``standing``: the tibia carries half the weight of 50, 70 and 100 kg (the load's level,
  a fraction of :data:`LOAD_REFERENCE`, half the weight of 100 kg); held out: 90 kg;
- ``lift``: the tibialis anterior's excitation ramped to 0.1, 0.2 and 0.5 in 0.1 s (the
  paper trained on tibialis anterior excitations); held out: 0.3.

:func:`compare` runs the held-out input on the full and the reduced scene and measures the
mean node error of the tissue at every step (its maximum over the run is the figure the
issue's target is on) and the median and mean ms per step of both.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from artifem.errors import ArtifemError, InputError
from artifem.excitation import ExcitationSchedule
from artifem.reduction.reductor import Basis, Points, ReducedModel, ReducibleScene, Training, reduce
from artifem.scene.inputs import LoadLevel, PathExcitation

from . import mesh as fm
from .model import CASES, foot_case
from .muscle import MUSCLES

#: the tibialis anterior's branches (their path names): one input each, driven together
TA_BRANCHES = tuple(f"tibialis anterior to {bone}" for bone in MUSCLES["tibialis anterior"][1])


@dataclass(frozen=True)
class ReducedFootConfig:
    """A reduced foot: ``r`` POD vectors (plus the bones' lift columns), ``points``
    integration points (``sampling``: "random" or "trained"), trained on full runs of
    ``duration`` s in steps of ``dt``, a snapshot every ``snapshot_every`` steps."""

    r: int = 6
    points: int = 100
    sampling: str = "random"
    level: int = 1
    dt: float = 0.005
    duration: float = 0.3
    snapshot_every: int = 2


#: the seed paper's configuration: 6 POD vectors, 100 random integration points.
PAPER = ReducedFootConfig()
#: the same basis on 100 trained (ECSW) integration points: the accurate one
TRAINED = ReducedFootConfig(sampling="trained")
#: the configurations ``artifem study foot --reduced`` compares, by name
CONFIGS = {"paper": PAPER, "trained": TRAINED}


def _constant(values: dict, duration: float) -> ExcitationSchedule:
    return ExcitationSchedule(
        np.array([0.0, duration]), {k: np.array([v, v]) for k, v in values.items()}
    )


def _ta_ramp(level: float) -> ExcitationSchedule:
    return ExcitationSchedule(
        np.array([0.0, 0.1]), {b: np.array([0.0, level]) for b in TA_BRANCHES}
    )


#: the standing foot's load at level 1: half the weight of 100 kg (N)
LOAD_REFERENCE = 0.5 * 100.0 * 9.81
#: case -> training schedules over the case's inputs (module docstring): the load's level
#: (body mass / 100 kg), the tibialis anterior's excitation
TRAINING = {
    "standing": {f"{m:g} kg": m / 100.0 for m in (50, 70, 100)},
    "lift": {f"tibialis anterior {a:g}": a for a in (0.1, 0.2, 0.5)},
}
#: case -> the held-out input level
HELD_OUT = {"standing": 0.9, "lift": 0.3}


def schedule(case: str, level: float, duration: float) -> ExcitationSchedule:
    """The schedule of ``case`` at input ``level``: the load's level held (standing), or
    the tibialis anterior ramped to it (lift)."""
    if case == "standing":
        return _constant({"load": level}, duration)
    return _ta_ramp(level)


def reducible(case: str, level: int, mesh_cache=fm.DEFAULT_CACHE) -> ReducibleScene:
    """The foot of ``case`` as the reductor sees it: its tissue reduced; inputs the tibia's
    load level (standing) and the tibialis anterior's branches' excitations. The lift is
    built unexcited: the schedules drive the muscle."""
    if case not in TRAINING:
        raise InputError(
            f"reduced foot: no training for case {case!r}; the reduced cases are {sorted(TRAINING)}"
        )
    loads = {b: PathExcitation(b) for b in TA_BRANCHES}
    options = dict(excitation=None)
    if CASES[case].get("load", 1.0):
        loads["load"] = LoadLevel("tibia load")
        options["load"] = LOAD_REFERENCE
    return ReducibleScene(
        f"foot {case}",
        lambda: foot_case(case, level, cache=mesh_cache, **options).scene,
        "tissue",
        {"case": case, "level": level, **options},
        exciters={},
        loads=loads,
    )


def training(case: str, config: ReducedFootConfig) -> Training:
    return Training(
        {name: schedule(case, value, config.duration) for name, value in TRAINING[case].items()},
        config.duration,
        config.dt,
        config.snapshot_every,
    )


def train(
    case: str,
    config: ReducedFootConfig,
    cache: Path,
    progress: bool = True,
    mesh_cache=fm.DEFAULT_CACHE,
) -> ReducedModel:
    """The reduced foot of ``case`` (module docstring), cached under ``cache`` (an
    interrupted training resumes); the foot's mesh from ``mesh_cache``."""
    return reduce(
        reducible(case, config.level, mesh_cache),
        training(case, config),
        basis=Basis("pod", config.r),
        points=Points(config.points, sampling=config.sampling),
        cache=cache,
        progress=progress,
    )


def _run(scene, model: ReducibleScene, drive: ExcitationSchedule, config, displacement):
    """Step ``scene`` under ``drive``: the tissue's displacement after every step and the
    wall ms of each step."""
    model.drive(scene, drive)
    steps = int(round(config.duration / config.dt))
    u, ms = [], []
    for _ in range(steps):
        tic = time.perf_counter()
        scene.step(config.dt)
        ms.append(1e3 * (time.perf_counter() - tic))
        u.append(displacement())
    return np.array(u), np.array(ms)


def compare(
    case: str, configs: dict, cache: Path, progress: bool = True, mesh_cache=fm.DEFAULT_CACHE
) -> dict:
    """Reduced feet against the full one on the held-out input of ``case``: name ->
    figures of each of ``configs`` (name -> :class:`ReducedFootConfig`, all of one level,
    dt and duration; the full foot runs once): max over the run of the tissue's mean node
    error (mm), the largest node error, and the median and mean ms per step of both (the
    mean counts the slow steps: halvings, the friction fallback); per step, the mean node
    error and the ms of both (``mean_node_error_mm``, ``reduced_ms``, ``full_ms``). A
    configuration whose run stops has its ``failure`` instead of its error."""
    first = next(iter(configs.values()))
    if any(
        (c.level, c.dt, c.duration) != (first.level, first.dt, first.duration)
        for c in configs.values()
    ):
        raise InputError(
            "reduced foot: the configurations compared need one level, dt and "
            "duration (the full foot runs once)"
        )
    models = {
        name: train(case, config, cache, progress, mesh_cache) for name, config in configs.items()
    }
    drive = schedule(case, HELD_OUT[case], first.duration)
    model = next(iter(models.values())).model
    full_scene = model.build()
    tissue = model.fem_body(full_scene)
    n = tissue.u.x.array.size
    u_full, ms_full = _run(full_scene, model, drive, first, lambda: tissue.u.x.array[:n].copy())
    return {
        name: _compare_one(case, configs[name], reduced, drive, u_full, ms_full)
        for name, reduced in models.items()
    }


def _compare_one(case, config, model: ReducedModel, drive, u_full, ms_full) -> dict:
    n = u_full.shape[1]
    figures = {
        "case": case,
        "held_out_level": HELD_OUT[case],
        "config": asdict(config),
        "r": model.r,
        "pod_vectors": config.r,
        "lift_columns": model.r - config.r,
        "points": int(model.points.m),
        "training": {
            "schedules": TRAINING[case],
            "snapshots": model.training["snapshots"],
            "seconds": sum(model.training["seconds"].values()),
        },
        "full_ms_per_step": float(np.median(ms_full)),
        "full_ms_mean": float(np.mean(ms_full)),
        "full_ms": [round(float(m), 1) for m in ms_full],
        "max_displacement_mm": float(
            1e3 * np.linalg.norm(u_full.reshape(len(u_full), -1, 3), axis=2).max()
        ),
    }
    reduced_scene = model.scene()
    reduced = next(b for b in reduced_scene.reduced_bodies if b.name == "tissue")
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            u_red, ms_red = _run(
                reduced_scene,
                model.model,
                drive,
                config,
                lambda: reduced.nodal_displacement().ravel()[:n].copy(),
            )
    except ArtifemError as exc:
        return {**figures, "failure": str(exc)}
    error = 1e3 * np.linalg.norm((u_red - u_full).reshape(len(u_full), -1, 3), axis=2)
    return {
        **figures,
        "reduced_ms_per_step": float(np.median(ms_red)),
        "reduced_ms_mean": float(np.mean(ms_red)),
        "reduced_ms": [round(float(m), 1) for m in ms_red],
        "mean_node_error_mm": [round(float(e), 4) for e in error.mean(axis=1)],
        "speedup": float(np.median(ms_full) / np.median(ms_red)),
        "max_mean_node_error_mm": float(error.mean(axis=1).max()),
        "max_node_error_mm": float(error.max()),
    }
