"""A reductor's training shared over the ranks of MPI.COMM_WORLD (run under mpiexec by
tests/test_distributed_training.py):

    mpiexec -n 2 python tests/distributed_training_job.py CACHE [--fail] [--distributed]

The free muscle beam (tests/reduced_beam.py), built on MPI.COMM_SELF on every rank
(``--distributed``: on MPI.COMM_WORLD), trained on four schedules; with ``--fail`` the
third one fails (a model error raised by its drive). Rank 0 prints ``RESULT {json}``: what
:meth:`Reductor.train` did.
"""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.errors import SolverError
from artifem.excitation import ExcitationSchedule
from artifem.reduction.reductor import ReducibleScene, Reductor, Training
from artifem.scene import Scene
from reduced_beam import make_body

#: the training schedules: the beam's muscle ramped to each level over 0.05 s
LEVELS = {"a": 0.2, "b": 0.4, "c": 0.6, "d": 0.8}
FAILING = "c"
DURATION, DT = 0.1, 0.01


def schedules() -> dict[str, ExcitationSchedule]:
    return {
        name: ExcitationSchedule.ramp_and_hold({"top": level}, 0.05)
        for name, level in LEVELS.items()
    }


class FailingBeam(ReducibleScene):
    """The beam, whose run at the FAILING level fails as a model error would."""

    def drive(self, scene, schedule):
        if schedule.values["top"][-1] == LEVELS[FAILING]:
            raise SolverError(f"beam: element 3 inverted (run {FAILING!r})")
        return super().drive(scene, schedule)


def free_beam(comm=MPI.COMM_SELF) -> Scene:
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add(make_body(excitation=0.0, comm=comm))
    return scene


def model(fail: bool = False, distributed: bool = False) -> ReducibleScene:
    kind = FailingBeam if fail else ReducibleScene
    build = (lambda: free_beam(MPI.COMM_WORLD)) if distributed else free_beam
    return kind("beam", build, "fem", {"beam": "free"})


if __name__ == "__main__":
    cache, flags = sys.argv[1], sys.argv[2:]
    reductor = Reductor(
        model("--fail" in flags, "--distributed" in flags),
        Training(schedules(), DURATION, DT, 2),
        cache,
        progress=False,
        comm=MPI.COMM_WORLD,
    )
    done = reductor.train()
    if MPI.COMM_WORLD.rank == 0:
        print("RESULT " + json.dumps({**done, "keys": reductor.snapshot_keys()}), flush=True)
