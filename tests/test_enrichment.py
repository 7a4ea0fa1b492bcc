"""Greedy training (artifem.reduction.enrichment) on the free muscle beam.

(1) Each iteration adds the candidate of largest estimate among those left, and stops at
    the requested size; the estimates are the hierarchical ones (a reduced model against
    one with twice the vectors and points), finite and positive.
(2) It stops at the tolerance (nothing added when the first estimate is below it) and
    when the pool is exhausted; a candidate whose full run fails leaves the pool, with the
    reason, and the next worst is tried.
(3) Bad input is refused before any run: a candidate already in the training, a size
    below the first training's.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.errors import InputError, SolverError
from artifem.excitation import ExcitationSchedule
from artifem.reduction.enrichment import greedy_training
from artifem.reduction.reductor import Basis, Points, ReducibleScene, Training
from artifem.scene import Scene
from reduced_beam import make_body

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="reduced bodies are serial")


def free_beam() -> Scene:
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add(make_body(excitation=0.0))
    return scene


def ramp(level: float, time: float = 0.1) -> ExcitationSchedule:
    return ExcitationSchedule.ramp_and_hold({"top": level}, time)


MODEL = ReducibleScene("beam", free_beam, "fem", {"beam": "free"})
FIRST = Training({"low": ramp(0.2)}, duration=0.3, dt=0.01, snapshot_every=2)
POOL = {"mid": ramp(0.5), "high": ramp(1.0), "fast": ramp(0.8, 0.02)}
OPTIONS = dict(basis=Basis("pod", 3), points=Points(40, training_states=20), progress=False)


def test_each_iteration_adds_the_worst_estimated_candidate(tmp_path):
    result = greedy_training(MODEL, FIRST, POOL, cache=tmp_path, max_runs=3, **OPTIONS)
    assert result.stopped == "size"
    added = [h["added"] for h in result.history]
    assert added[-1] is None and len(added) == 3
    left = set(POOL)
    for entry in result.history[:-1]:
        assert set(entry["estimates_mm"]) == left
        assert all(np.isfinite(v) and v > 0 for v in entry["estimates_mm"].values())
        assert entry["added"] == max(entry["estimates_mm"], key=entry["estimates_mm"].get)
        assert entry["max_estimate_mm"] == entry["estimates_mm"][entry["added"]]
        left.remove(entry["added"])
    assert list(result.training.schedules) == ["low", *added[:-1]]
    assert result.reduced.training["runs"] == 3


def test_it_stops_at_the_tolerance_and_when_the_pool_is_exhausted(tmp_path):
    first = greedy_training(MODEL, FIRST, POOL, cache=tmp_path, max_runs=1, **OPTIONS)
    assert first.stopped == "size" and first.history[0]["max_estimate_mm"] is None
    probe = greedy_training(MODEL, FIRST, POOL, cache=tmp_path, max_runs=2, **OPTIONS)
    worst = probe.history[0]["max_estimate_mm"]
    done = greedy_training(MODEL, FIRST, POOL, cache=tmp_path, tol=1.01 * worst, **OPTIONS)
    assert done.stopped == "tolerance" and list(done.training.schedules) == ["low"]
    one = {"mid": POOL["mid"]}
    exhausted = greedy_training(MODEL, FIRST, one, cache=tmp_path, **OPTIONS)
    assert exhausted.stopped == "pool" and list(exhausted.training.schedules) == ["low", "mid"]


class InvertingBeam(ReducibleScene):
    """The beam, whose *full* runs of the pool's schedules fail as an inversion would."""

    def drive(self, scene, schedule):
        if not scene.reduced_bodies and schedule.values["top"][-1] != 0.2:
            raise SolverError("beam: element 3 inverted")
        return super().drive(scene, schedule)


def test_a_candidate_the_full_model_cannot_run_leaves_the_pool_with_why(tmp_path):
    model = InvertingBeam("beam", free_beam, "fem", {"beam": "free"})
    result = greedy_training(model, FIRST, POOL, cache=tmp_path, **OPTIONS)
    assert result.stopped == "pool" and list(result.training.schedules) == ["low"]
    entry = result.history[0]
    assert entry["added"] is None
    assert entry["rejected"] == {name: "beam: element 3 inverted" for name in POOL}


def test_bad_input_is_refused_before_any_run(tmp_path):
    with pytest.raises(InputError, match="already training"):
        greedy_training(MODEL, FIRST, {"low": ramp(0.3)}, cache=tmp_path, **OPTIONS)
    with pytest.raises(InputError, match="max_runs"):
        greedy_training(MODEL, FIRST, POOL, cache=tmp_path, max_runs=0, **OPTIONS)
    assert not list(tmp_path.glob("*.npz"))
