"""A reductor's training runs shared over MPI ranks (artifem.reduction.distributed).

tests/distributed_training_job.py trains the free muscle beam on four schedules under
``mpiexec -n 2``:

(1) each rank computes its share (round robin), and the cache then holds every run,
    equal to the same run computed serially in this process (one serial model per rank,
    the same code: measured identical to round-off);
(2) an interrupted training resumes: with one run removed from the cache, two ranks
    compute that one only;
(3) a run that fails on one rank fails the training on both ranks, which say which rank
    and which run, and the runs already finished stay in the cache;
(4) a reductor refuses a model whose body is distributed over the ranks, before any run.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.reduction.reductor import Reductor, Training
from artifem.reduction.training import ArtifactCache

sys.path.insert(0, str(Path(__file__).parent))
import distributed_training_job as job  # noqa: E402

MPIEXEC = Path(sys.executable).parent / "mpiexec"
pytestmark = [
    pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="launches its own mpiexec"),
    pytest.mark.skipif(not MPIEXEC.exists(), reason=f"no mpiexec next to {sys.executable}"),
]


def launch(cache: Path, *flags: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(MPIEXEC), "-n", "2", sys.executable, job.__file__, str(cache), *flags],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
    )


def result(proc: subprocess.CompletedProcess) -> dict:
    assert proc.returncode == 0, proc.stdout + proc.stderr
    line = next(l for l in proc.stdout.splitlines() if l.startswith("RESULT "))
    return json.loads(line[len("RESULT ") :])


def test_two_ranks_share_the_training_and_resume(tmp_path):
    cache = tmp_path / "cache"
    done = result(launch(cache))
    assert (done["ranks"], done["jobs"], done["missing"]) == (2, 4, 4)
    assert done["by_rank"] == [["a", "c"], ["b", "d"]]
    shared = ArtifactCache(cache)
    serial = Reductor(
        job.model(),
        Training(job.schedules(), job.DURATION, job.DT, 2),
        tmp_path / "serial",
        progress=False,
    )
    assert serial.snapshot_keys() == done["keys"]
    runs = serial._training_runs()
    for key, run in zip(done["keys"], runs):
        u = shared.load(key)["displacements"]
        assert np.abs(run.displacements).max() > 1e-4
        np.testing.assert_allclose(u, run.displacements, rtol=0, atol=1e-12)
    # an interrupted training: one run lost; two ranks compute that one alone
    shared.path(done["keys"][2]).unlink()
    again = result(launch(cache))
    assert again["missing"] == 1 and again["by_rank"] == [["c"], []]
    assert all(shared.path(k).exists() for k in done["keys"])


def test_a_failing_run_fails_every_rank_and_keeps_the_others(tmp_path):
    cache = tmp_path / "cache"
    proc = launch(cache, "--fail")
    assert proc.returncode != 0
    assert "element 3 inverted (run 'c')" in proc.stderr
    assert "rank 0 of 2 failed on job 'c'" in proc.stderr  # what rank 1 says
    keys = Reductor(
        job.model(),
        Training(job.schedules(), job.DURATION, job.DT, 2),
        tmp_path / "other",
        progress=False,
    ).snapshot_keys()
    kept = [name for name, key in zip(job.LEVELS, keys) if ArtifactCache(cache).path(key).exists()]
    assert kept == ["a", "b", "d"]


def test_a_distributed_model_is_refused(tmp_path):
    proc = launch(tmp_path / "cache", "--distributed")
    assert proc.returncode != 0
    assert "body 'fem' is distributed over 2 ranks" in proc.stderr
    assert not list((tmp_path / "cache").glob("*.npz"))


def test_a_study_under_two_ranks_trains_on_both_and_finishes_on_one(tmp_path):
    """``mpiexec -n 2 artifem study scene ...``: the two ranks share the training, rank 0
    runs the rest in a fresh serial process (artifem.reduction.distributed.continue_alone),
    and the job ends. (Rank 0 going on alone in its own process hung at exit in PETSc's
    garbage cleanup with the quick tongue study, reproduced by hand; this beam did not
    hang that way, so the test checks the flow, not that hang.) The record of the
    two-rank training is kept."""
    out = tmp_path / "study"
    tests = str(Path(__file__).parent)
    proc = subprocess.run(
        [
            str(MPIEXEC),
            "-n",
            "2",
            sys.executable,
            "-m",
            "artifem.cli",
            "study",
            "scene",
            "test_reductor_load_cases:pulled_model",
            "--out",
            str(out),
            "--training-runs",
            "4",
            "--duration",
            "0.2",
            "--snapshot-every",
            "2",
            "--r",
            "6",
            "--sampling",
            "all",
            "--held-out",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        env={
            **os.environ,
            "OPENBLAS_NUM_THREADS": "1",
            "PYTHONPATH": os.pathsep.join([tests, os.environ.get("PYTHONPATH", "")]),
        },
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    training = json.loads((out / "training.json").read_text())
    assert training["ranks"] == 2 and training["missing"] == 4
    assert sorted(n for names in training["by_rank"] for n in names) == [
        f"random-0-{i}" for i in range(4)
    ]
    assert all(training["by_rank"])  # both ranks computed
    split = json.loads((out / "generalization.json").read_text())
    assert [len(split["sets"][s]) for s in ("training", "motions", "held-out")] == [4, 1, 1]
    # the same study in one process gives the same split: each training run is computed
    # whole on one rank, so the errors agree to round-off
    from artifem.cli import main

    argv = proc.args[proc.args.index("study") :]
    serial = tmp_path / "serial"
    assert (
        main([*argv[: argv.index("--out") + 1], str(serial), *argv[argv.index("--out") + 2 :]]) == 0
    )
    alone = json.loads((serial / "generalization.json").read_text())
    for name, runs in split["sets"].items():
        for run, serial_run in zip(runs, alone["sets"][name], strict=True):
            assert run["name"] == serial_run["name"]
            for key in ("max_error_mm", "mean_error_mm", "max_estimate_mm"):
                assert run[key] == pytest.approx(serial_run[key], rel=1e-9), (name, key)
