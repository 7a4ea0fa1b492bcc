"""Independent cached computations shared over the ranks of an MPI communicator.

A reduction's training runs are independent full simulations. :func:`compute_shared`
splits the ones not yet in the cache over the ranks of ``comm`` (job i of the missing
ones on rank i mod size); each rank computes its share, on its own serial model, and
stores each result in the :class:`~artifem.reduction.training.ArtifactCache` (one atomic
file per job, on a file system all ranks see). The cache stays the single source of
results: once every rank is through, each reads any result from it, and an interrupted
training resumes with the jobs not on disk, on any number of ranks.

Why a static split and not ``mpi4py.futures``: its executors make the root rank a master
that hands out tasks and computes none, so two ranks on our two cores would be one
worker. Training runs of one model and one duration cost about the same, so a
round-robin split keeps every rank busy; on a cluster the same command runs with
``mpiexec -n N`` over its nodes.

A job that fails on one rank fails the call on every rank (the others name the rank and
the job), after all ranks are through their shares: no rank waits forever on another.

After a shared training the ranks must not diverge in PETSc work: at exit each rank runs
PETSc's garbage cleanup of PETSC_COMM_WORLD (petsc4py's ``_pre_finalize``, then
``PetscFinalize``), whose collectives (a communicator duplication, an intersection of
the delayed-destroy keys) depend on that rank's own PETSc state. A rank that went on
alone with a study meets the others there with different work to do, and both wait
forever (reproduced with gdb, also with the ranks meeting at a barrier first: rank 0 in
``MPI_Comm_dup`` under ``PetscGarbageCleanup``, rank 1 in ``MPI_Finalize``).
:func:`continue_alone` avoids it: rank 0 runs the rest of the command in a fresh serial
process (its own MPI, the results read from the cache) while the other ranks wait
without spinning, and all ranks end alike.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from mpi4py import MPI

from artifem.errors import ArtifemError, SolverError

__all__ = ["compute_shared", "continue_alone", "record_training", "share"]

#: Environment variables of MPI launchers: a child process without them initializes MPI
#: as a singleton (a serial process) instead of joining the launcher's job.
_LAUNCHER_PREFIXES = ("PMI_", "PMIX_", "HYDRA_", "MPIR_", "MPICH_", "OMPI_")


def share(count: int, comm: MPI.Comm) -> range:
    """The indices of ``count`` jobs this rank computes (round robin)."""
    return range(comm.rank, count, comm.size)


def compute_shared(
    jobs: Sequence[tuple[str, str, Callable[[], object]]], cache, comm: MPI.Comm
) -> dict:
    """Compute the jobs ``(name, cache key, compute)`` whose key is not in ``cache``,
    shared over ``comm`` (module docstring); ``compute`` stores its result under its key.

    Returns what this call did: {"ranks", "jobs", "missing": how many were not in the
    cache, "by_rank": the names each rank computed, "wall_seconds": from the common start
    to the last rank's end}.
    """
    comm.barrier()
    tic = time.perf_counter()
    missing = comm.bcast(
        [i for i, (_, key, _) in enumerate(jobs) if not cache.path(key).exists()]
        if comm.rank == 0
        else None,
        root=0,
    )
    mine, failure = [], None
    for i in share(len(missing), comm):
        name, key, compute = jobs[missing[i]]
        try:
            compute()
        except Exception as exc:  # reported on every rank below
            failure = (name, exc)
            break
        mine.append(name)
    by_rank = comm.allgather(mine)
    failures = comm.allgather(
        None if failure is None else (failure[0], f"{type(failure[1]).__name__}: {failure[1]}")
    )
    wall = comm.allreduce(time.perf_counter() - tic, op=MPI.MAX)
    if failure is not None:
        raise failure[1]
    for rank, found in enumerate(failures):
        if found is not None:
            raise SolverError(
                f"rank {rank} of {comm.size} failed on job {found[0]!r}: {found[1]}"
            ) from None
    for i in missing:
        if not cache.path(jobs[i][1]).exists():
            raise ArtifemError(
                f"job {jobs[i][0]!r} left no result in the cache "
                f"{cache.root}: do all ranks see the "
                "same directory?"
            )
    return {
        "ranks": comm.size,
        "jobs": len(jobs),
        "missing": len(missing),
        "by_rank": by_rank,
        "wall_seconds": wall,
    }


def continue_alone(argv: Sequence[str], comm: MPI.Comm, *, poll: float = 0.1) -> int:
    """Run ``artifem ARGV`` on rank 0 in a fresh serial process, the other ranks of
    ``comm`` waiting without spinning (a polled ``Ibarrier``), then return the command's
    exit status on every rank (module docstring: why not on rank 0 itself)."""
    status = 0
    if comm.rank == 0:
        env = {k: v for k, v in os.environ.items() if not k.startswith(_LAUNCHER_PREFIXES)}
        status = subprocess.run([sys.executable, "-m", "artifem.cli", *argv], env=env).returncode
    request = comm.Ibarrier()
    while not request.Test():
        time.sleep(poll)
    return comm.bcast(status, root=0)


def record_training(path: Path, done: dict, same: Sequence[str]) -> Path:
    """Write ``done`` (what a training call did, with the study's settings) to ``path`` as
    JSON, unless the file already records the same training (equal ``same`` entries) and
    this call computed nothing: a study continuing from the cache keeps the record of the
    computation (which ranks ran what, and how long)."""
    path = Path(path)
    old = json.loads(path.read_text()) if path.exists() else {}
    if done["missing"] or any(old.get(k) != done.get(k) for k in same):
        path.write_text(json.dumps(done, indent=1))
    return path
