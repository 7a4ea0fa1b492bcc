"""Running a scene: ``simulate(scene, duration, dt)`` steps it, records what you name,
writes ParaView series, and reports speed and robustness.

    run = simulate(scene, 1.0, 0.01, record={"tip": lambda s: tip.position()},
                   vtx="out/")
    run.records["tip"], run.ms_per_step, run.halvings, run.min_det_F
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm

from artifem.errors import InputError
from artifem.io.results import ResultWriter

__all__ = ["Run", "simulate"]


@dataclass
class Run:
    """What :func:`simulate` recorded: the times, each named quantity at every time (the
    start included), the wall time of each step, and the scene's health figures."""

    times: np.ndarray
    records: dict[str, np.ndarray]
    step_ms: np.ndarray
    halvings: int
    min_det_F: float

    @property
    def ms_per_step(self) -> float:
        """Median wall time per step (ms)."""
        return float(np.median(self.step_ms)) if self.step_ms.size else float("nan")


def simulate(scene, duration: float, dt: float, *,
             record: dict[str, Callable] | None = None, vtx: str | Path | None = None,
             write_every: int = 1, progress: bool = True, label: str = "simulate") -> Run:
    """Step ``scene`` from its current time for ``duration`` seconds in steps of ``dt``.

    Args:
        record: name -> ``f(scene)`` returning a number or an array, evaluated at the
            start and after every step.
        vtx: a directory: every FEM body's displacement is written as a VTX (.bp) series
            ``<dir>/<body name>.bp`` (a reduced body's through its full body, rebuilt
            only for the output), every ``write_every`` steps.
    Raises the scene's ElementInversionError or StepFailed when a step cannot be completed
    even after halving (the series written so far are closed and kept).
    """
    if not (np.isfinite(duration) and duration > 0 and np.isfinite(dt) and dt > 0):
        raise InputError(f"simulate: duration and dt must be finite and > 0, got {duration}, "
                         f"{dt}")
    if int(write_every) != write_every or write_every < 1:
        raise InputError(f"simulate: write_every must be a positive integer, got {write_every}")
    record = dict(record or {})
    for name, f in record.items():
        if not callable(f):
            raise InputError(f"simulate: record[{name!r}] must be a callable f(scene)")
    steps = int(round(duration / dt))
    t0 = scene.t
    writers = []
    if vtx is not None:
        for body in scene.fem_bodies:
            writers.append((None, ResultWriter(Path(vtx) / f"{body.name}.bp", [body.u])))
        for body in scene.reduced_bodies:
            writers.append((body, ResultWriter(Path(vtx) / f"{body.name}.bp", [body.full.u])))

    def write():
        for reduced, writer in writers:
            if reduced is not None:
                reduced.to_full()
            writer.write(scene.t)

    values = {name: [np.asarray(f(scene), dtype=float)] for name, f in record.items()}
    times, step_ms = [scene.t], []
    try:
        write()
        for k in tqdm(range(1, steps + 1), desc=label, unit="step", disable=not progress):
            tic = time.perf_counter()
            scene.step(dt)
            step_ms.append(1e3 * (time.perf_counter() - tic))
            scene.t = t0 + k * dt                   # no drift from repeated addition
            times.append(scene.t)
            for name, f in record.items():
                values[name].append(np.asarray(f(scene), dtype=float))
            if k % write_every == 0:
                write()
    finally:
        for _, writer in writers:
            writer.close()
    return Run(np.array(times), {name: np.array(v) for name, v in values.items()},
               np.array(step_ms), int(scene.halvings), float(scene.min_det_F))
