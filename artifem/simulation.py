"""Run a system over time and record what people look at.

:func:`simulate` steps a :class:`~artifem.system.System` with a progress bar,
records the displacement of named landmark nodes of one FEM body, per-step
wall times and the smallest det F, keeps copies of the displacement at chosen
snapshot times (for renders), and writes a VTX time series for ParaView.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dolfinx import fem

from artifem.errors import InputError
from artifem.fem_body import FemBody
from artifem.io.results import ResultWriter
from artifem.system import System


@dataclass
class Trajectory:
    """What a run recorded (landmark displacements in metres, times in seconds)."""

    times: np.ndarray
    landmarks: dict[str, np.ndarray]            # name -> (len(times), 3)
    step_ms: np.ndarray                         # wall time of each step
    min_det_F: float
    halvings: int
    snapshots: dict[float, fem.Function] = field(default_factory=dict)

    @property
    def ms_per_step(self) -> float:
        """Median wall time per step."""
        return float(np.median(self.step_ms)) if self.step_ms.size else float("nan")


def simulate(system: System, body: FemBody, *, duration: float, dt: float,
             landmarks: dict[str, int] | None = None, snapshot_times=(),
             vtx_path: str | Path | None = None, write_every: int = 1,
             progress: bool = True, label: str = "simulate") -> Trajectory:
    """Step ``system`` from its current time for ``duration`` seconds.

    Args:
        landmarks: name -> input node index of ``body`` to track.
        snapshot_times: times at which a copy of ``body.u`` is kept.
        vtx_path: where to write the VTX (.bp) series of ``body.u``; None for none.
        write_every: write every k-th step to the series.
    """
    if duration <= 0 or dt <= 0:
        raise InputError(f"duration and dt must be > 0, got {duration}, {dt}")
    steps = int(round(duration / dt))
    landmarks = landmarks or {}
    names = list(landmarks)
    nodes = [landmarks[n] for n in names]
    t_start = system.time

    def record():
        return body.displacement_at(nodes) if nodes else np.zeros((0, 3))

    def keep_snapshot():
        copy = fem.Function(body.V, name="displacement")
        copy.x.array[:] = body.u.x.array
        return copy

    wanted = sorted(float(t) for t in snapshot_times)
    snapshots = {t: keep_snapshot() for t in wanted if abs(t - system.time) < 0.5 * dt}
    times, positions, step_ms = [system.time], [record()], []
    writer = ResultWriter(vtx_path, [body.u]) if vtx_path is not None else None
    try:
        if writer is not None:
            writer.write(system.time)
        show = progress and body.mesh.comm.rank == 0
        for k in tqdm(range(1, steps + 1), desc=label, unit="step", disable=not show):
            body.mesh.comm.Barrier()
            tic = time.perf_counter()
            system.step(dt)
            body.mesh.comm.Barrier()
            step_ms.append(1e3 * (time.perf_counter() - tic))
            system.time = t_start + k * dt     # no drift from repeated addition
            times.append(system.time)
            positions.append(record())
            for t in wanted:
                if t not in snapshots and abs(t - system.time) < 0.5 * dt:
                    snapshots[t] = keep_snapshot()
            if writer is not None and k % write_every == 0:
                writer.write(system.time)
    finally:
        if writer is not None:
            writer.close()
    track = np.array(positions)
    return Trajectory(times=np.array(times),
                      landmarks={n: track[:, i] for i, n in enumerate(names)},
                      step_ms=np.array(step_ms), min_det_F=float(system.min_det_F),
                      halvings=system.halvings, snapshots=snapshots)
