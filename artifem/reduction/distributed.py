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

After a shared training the ranks should end together: a rank that goes on alone with
PETSc objects of its own can meet the others in petsc4py's exit-time garbage collection, a
collective, with different work to do, and wait forever (seen: rank 0 of
``mpiexec -n 2 artifem study tongue`` continuing after the training never exited). The
study therefore trains only under several ranks (``--train-only``) and continues on one.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from mpi4py import MPI

from artifem.errors import ArtifemError, SolverError

__all__ = ["compute_shared", "share"]


def share(count: int, comm: MPI.Comm) -> range:
    """The indices of ``count`` jobs this rank computes (round robin)."""
    return range(comm.rank, count, comm.size)


def compute_shared(jobs: Sequence[tuple[str, str, Callable[[], object]]], cache,
                   comm: MPI.Comm) -> dict:
    """Compute the jobs ``(name, cache key, compute)`` whose key is not in ``cache``,
    shared over ``comm`` (module docstring); ``compute`` stores its result under its key.

    Returns what this call did: {"ranks", "jobs", "missing": how many were not in the
    cache, "by_rank": the names each rank computed, "wall_seconds": from the common start
    to the last rank's end}.
    """
    comm.barrier()
    tic = time.perf_counter()
    missing = comm.bcast([i for i, (_, key, _) in enumerate(jobs)
                          if not cache.path(key).exists()] if comm.rank == 0 else None, root=0)
    mine, failure = [], None
    for i in share(len(missing), comm):
        name, key, compute = jobs[missing[i]]
        try:
            compute()
        except Exception as exc:            # reported on every rank below
            failure = (name, exc)
            break
        mine.append(name)
    by_rank = comm.allgather(mine)
    failures = comm.allgather(None if failure is None else
                              (failure[0], f"{type(failure[1]).__name__}: {failure[1]}"))
    wall = comm.allreduce(time.perf_counter() - tic, op=MPI.MAX)
    if failure is not None:
        raise failure[1]
    for rank, found in enumerate(failures):
        if found is not None:
            raise SolverError(f"rank {rank} of {comm.size} failed on job {found[0]!r}: "
                              f"{found[1]}") from None
    for i in missing:
        if not cache.path(jobs[i][1]).exists():
            raise ArtifemError(f"job {jobs[i][0]!r} left no result in the cache "
                               f"{cache.root}: do all ranks see the "
                               "same directory?")
    return {"ranks": comm.size, "jobs": len(jobs), "missing": len(missing), "by_rank": by_rank,
            "wall_seconds": wall}

