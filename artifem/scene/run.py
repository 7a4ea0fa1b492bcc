"""Running a scene: ``simulate(scene, duration, dt)`` steps it, records what you name,
writes ParaView series, and reports speed and robustness.

    run = simulate(scene, 1.0, 0.01, record={"tip": lambda s: tip.position()},
                   vtx="out/")
    run.records["tip"], run.ms_per_step, run.halvings, run.fallbacks, run.min_det_F

Under ``mpiexec`` (FEM bodies on several ranks) every rank calls it; the step times
are measured between barriers and the progress bar is shown on rank 0.

The run holds NumPy's BLAS to one thread: a step's dense algebra is small (a reduced
body's r x r tangent and 9m x r products, rigid bodies, constraint rows), and a
multithreaded BLAS on a machine whose cores are busy makes such a product up to 80x
slower (measured: 8.0 against 0.10 ms for one reduced tangent product beside a test run).
PETSc's solvers use their own BLAS and are not affected.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm

from dolfinx import fem

from artifem.errors import InputError, SolverError
from artifem.io.results import ResultWriter
from artifem.scene.direct_solver import one_blas_thread

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
    #: time -> {FEM body name: a copy of its displacement} at the ``keep`` times
    snapshots: dict = field(default_factory=dict)
    #: the step failure that ended the run early (``on_failure="stop"``), else None
    failure: Exception | None = None
    #: steps the scene's fallback integrator completed after the semi-implicit step failed
    #: (``Scene.fallbacks``; like ``halvings``, counted since the scene was built or reset)
    fallbacks: int = 0

    @property
    def ms_per_step(self) -> float:
        """Median wall time per step (ms)."""
        return float(np.median(self.step_ms)) if self.step_ms.size else float("nan")


def simulate(
    scene,
    duration: float,
    dt: float,
    *,
    record: dict[str, Callable] | None = None,
    vtx: str | Path | None = None,
    write_every: int = 1,
    keep=(),
    on_failure: str = "raise",
    progress: bool = True,
    label: str = "simulate",
    leave: bool = True,
) -> Run:
    """Step ``scene`` from its current time for ``duration`` seconds in steps of ``dt``.

    Args:
        record: name -> ``f(scene)`` returning a number or an array, evaluated at the
            start and after every step (arrays whose length changes, e.g. a contact's
            forces per pair ``lambda s: s.contact_forces(c).normal``, are kept as an object
            array of them).
        vtx: a directory: every FEM body's displacement is written as a VTX (.bp) series
            ``<dir>/<body name>.bp`` (a reduced body's through its full body, rebuilt
            only for the output), and a hard-incompressible body's pressures as
            ``<dir>/<body name>_pressure.bp`` (``FemBody.output_fields``), and the contact
            pressure on each FEM body a contact touches as
            ``<dir>/<body name>_contact_pressure.bp`` (``Scene.contact_pressure``, summed
            over its contacts), every ``write_every`` steps.
        keep: times at which a copy of every FEM body's displacement is kept
            (``Run.snapshots``, e.g. for renders).
        on_failure: ``"raise"``: a step that fails even after halving raises the scene's
            ElementInversionError or StepFailed (the series written so far are closed and
            kept); ``"stop"``: the run ends there and returns what it recorded up to the
            last completed step, the exception in ``Run.failure`` (hard cases, studies).
        leave: keep the progress bar on screen when done.
    """
    if not (np.isfinite(duration) and duration > 0 and np.isfinite(dt) and dt > 0):
        raise InputError(f"simulate: duration and dt must be finite and > 0, got {duration}, {dt}")
    if on_failure not in ("raise", "stop"):
        raise InputError(f"simulate: on_failure must be 'raise' or 'stop', got {on_failure!r}")
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
            for suffix, functions in body.output_fields().items():
                writers.append(
                    (None, ResultWriter(Path(vtx) / f"{body.name}{suffix}.bp", functions))
                )
        for body in scene.reduced_bodies:
            writers.append((body, ResultWriter(Path(vtx) / f"{body.name}.bp", [body.full.u])))
    pressures = _contact_pressure_fields(scene) if vtx is not None else {}
    for name, (nodal, _) in pressures.items():
        writers.append((None, ResultWriter(Path(vtx) / f"{name}_contact_pressure.bp", [nodal])))

    def write():
        for name, (nodal, contacts) in pressures.items():
            nodal.x.array[:] = 0.0
            for contact in contacts:
                nodal.x.array[:] += scene.contact_pressure(contact)[name].nodal
        for reduced, writer in writers:
            if reduced is not None:
                reduced.to_full()
            writer.write(scene.t)

    wanted = sorted(float(t) for t in keep)
    snapshots: dict = {}

    def keep_snapshots():
        for t in wanted:
            if t not in snapshots and abs(t - scene.t) < 0.5 * dt:
                snapshots[t] = {body.name: _copy(body.u) for body in scene.fem_bodies}

    comm = scene.comm
    values = {name: [np.asarray(f(scene), dtype=float)] for name, f in record.items()}
    times, step_ms, failure = [scene.t], [], None
    with one_blas_thread():  # module docstring
        try:
            write()
            keep_snapshots()
            show = progress and comm.rank == 0
            for k in tqdm(
                range(1, steps + 1), desc=label, unit="step", disable=not show, leave=leave
            ):
                comm.Barrier()
                tic = time.perf_counter()
                try:
                    scene.step(dt)
                except SolverError as exc:
                    if on_failure == "raise":
                        raise
                    failure = exc
                    break
                comm.Barrier()
                step_ms.append(1e3 * (time.perf_counter() - tic))
                scene.t = t0 + k * dt  # no drift from repeated addition
                times.append(scene.t)
                for name, f in record.items():
                    values[name].append(np.asarray(f(scene), dtype=float))
                keep_snapshots()
                if k % write_every == 0:
                    write()
        finally:
            for _, writer in writers:
                writer.close()
    return Run(
        np.array(times),
        {name: _stacked(v) for name, v in values.items()},
        np.array(step_ms),
        int(scene.halvings),
        float(scene.min_det_F),
        snapshots,
        failure,
        int(scene.fallbacks),
    )


def _stacked(values: list) -> np.ndarray:
    """The values of one record over the times: an array (times, ...) when each time's has
    the same shape, else an object array of them (a contact's forces per pair: the number
    of pairs changes)."""
    if len({v.shape for v in values}) <= 1:
        return np.array(values)
    out = np.empty(len(values), dtype=object)
    out[:] = values
    return out


def _contact_pressure_fields(scene) -> dict:
    """{FEM body name: (its P1 contact pressure Function, the contacts on it)} for the FEM
    bodies (a reduced body's full body) that a contact of the scene touches."""
    fields: dict = {}
    for contact in scene.contacts:
        for points, _ in contact.normal_forces([], 1.0):
            body = points.mesh_body
            if body is None:
                continue
            if body.name not in fields:
                fields[body.name] = (
                    fem.Function(
                        fem.functionspace(body.mesh, ("Lagrange", 1)), name="contact_pressure"
                    ),
                    [],
                )
            fields[body.name][1].append(contact)
    return fields


def _copy(u: fem.Function) -> fem.Function:
    out = fem.Function(u.function_space, name=u.name)
    out.x.array[:] = u.x.array
    return out
