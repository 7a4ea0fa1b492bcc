"""Every ``artifem simulate`` model under ``mpiexec -n 2`` runs or refuses, never hangs.

Each model is launched on 2 ranks with its shortest options that still take a few steps,
under a timeout: a distributed model (artifem.cli.DISTRIBUTED) must exit 0 with its
output written once, from 2 ranks, its figures and its displacement series those of the
same command run serially; a serial model (ONE_RANK) must exit 0 with its output from
one rank and say on stderr that it ran on one rank (a bad input: its one-line error,
status 2 on every rank); a refused command must exit 2 before any work with its one-line
reason. Every picture is drawn. A run still going at its timeout fails the test (its
processes are killed). An error raised on one rank only of a distributed command must end
every rank.
"""

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from artifem.cli import COMMANDS, DISTRIBUTED, ONE_RANK, main
from outputs import assert_picture, read_series

MPIEXEC = Path(sys.executable).parent / "mpiexec"
ARTIFEM = [sys.executable, "-m", "artifem.cli"]
#: seconds; the slowest model (airway) takes about 13 s on 2 ranks of an idle machine.
TIMEOUT = 300

#: model -> (the shortest options that take a few steps, files it must write in --out).
MODELS = {
    "beam": (
        ["--duration", "0.03", "--level", "0", "--no-progress"],
        ["curl/simulate.json", "curl/beam.png", "curl/beam.bp"],
    ),
    "tongue": (
        ["--duration", "0.03", "--no-progress"],
        ["protrusion/simulate.json", "protrusion/tongue.png", "protrusion/tongue.bp"],
    ),
    "beam-ellipsoid": (
        ["--duration", "0.03", "--level", "0", "--no-progress"],
        ["frame/simulate.json", "frame/beam-ellipsoid.png"],
    ),
    "jaw-tongue": (
        ["--duration", "0.03", "--no-progress"],
        ["protrusion/simulate.json", "protrusion/jaw-tongue.png"],
    ),
    "styloglossus": (
        ["--duration", "0.02", "--no-progress"],
        ["4-nodes/simulate.json", "4-nodes/styloglossus.png"],
    ),
    "airway": (
        ["--duration", "0.02", "--no-progress"],
        ["protrusion/simulate.json", "protrusion/airway.png"],
    ),
    "masseter": (
        ["--level", "0", "--duration", "0.02", "--no-progress"],
        ["embedding-aponeuroses/simulate.json", "embedding-aponeuroses/masseter.png"],
    ),
    "foot": (
        ["--level", "0", "--duration", "0.01", "--no-progress"],
        ["standing/simulate.json", "standing/foot.png", "standing/plantar_pressure.png"],
    ),
}

pytestmark = pytest.mark.skipif(
    not MPIEXEC.exists(), reason=f"no mpiexec next to the interpreter ({MPIEXEC})"
)


def mpirun(command: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """``mpiexec -n 2 command``; fails the test, killing every process of it, at TIMEOUT."""
    full = [str(MPIEXEC), "-n", "2"] + command
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen(
        full,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd,
        env=env,
        start_new_session=True,
    )
    try:
        out, err = proc.communicate(timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        pytest.fail(
            f"{' '.join(full)} still running after {TIMEOUT} s (a hang):\n"
            f"{out[-2000:]}\n{err[-2000:]}"
        )
    return subprocess.CompletedProcess(full, proc.returncode, out, err)


def last_rows(series: Path, name: str) -> np.ndarray:
    """The last step of field ``name`` of a VTX series, the blocks of every rank that wrote
    it stacked (shared nodes repeated), one row per node."""
    import adios2

    with adios2.FileReader(str(series)) as f:
        last = f.num_steps() - 1
        blocks = len(f.all_blocks_info(name)[last])
        rows = [
            np.asarray(f.read(name, block_id=b, step_selection=[last, 1])) for b in range(blocks)
        ]
    return np.concatenate([r.reshape(-1, 3) for r in rows])


def assert_same_figures(parallel, serial, rel: float, key: str = "figures") -> None:
    """Every figure of ``serial`` (a JSON tree) in ``parallel``: strings equal, numbers and
    vectors to ``rel`` of the vector's largest entry; the rank count and timings apart."""
    if isinstance(serial, dict):
        for k, v in serial.items():
            if k not in ("ranks", "ms_per_step"):
                assert_same_figures(parallel[k], v, rel, f"{key}/{k}")
    elif isinstance(serial, (int, float, list)) and not isinstance(serial, bool):
        scale = np.abs(serial).max() if np.size(serial) else 0.0
        np.testing.assert_allclose(parallel, serial, rtol=0, atol=rel * scale, err_msg=key)
    else:
        assert parallel == serial, key


def test_every_simulate_model_is_launched():
    assert set(MODELS) == {path[1] for path in COMMANDS if path[0] == "simulate"}


@pytest.mark.slow  # 5-15 s each, about 60 s in all, and 3 s for each serial twin
@pytest.mark.parametrize("model", sorted(MODELS))
def test_simulate_under_two_ranks(model, tmp_path):
    """A distributed model's 2-rank figures are its serial run's: to 1e-8 with MUMPS
    (measured 1.2e-9: the tongue's volume change), to 1e-6 with an iterative solver, whose
    rtol is 1e-7 (measured 2.6e-9: the beam's tip); its displacement series has every node
    of the serial one, to the same tolerance (measured 3.6e-9 of the largest |u|); its
    picture is the serial one's (both ranks wrote it over each other, each its own half,
    before rank 0 drew them all)."""
    options, outputs = MODELS[model]
    out = tmp_path / "out"
    proc = mpirun(ARTIFEM + ["simulate", model, "--out", str(out)] + options, tmp_path)
    under_mpi = COMMANDS[("simulate", model)][2]
    said = f"artifem simulate {model}: runs on one MPI rank of 2"
    if under_mpi in (DISTRIBUTED, ONE_RANK):
        assert proc.returncode == 0, f"{' '.join(proc.args)}:\n{proc.stdout}\n{proc.stderr}"
        missing = [name for name in outputs if not (out / name).exists()]
        assert not missing, f"{model} wrote no {missing} in {out}:\n{proc.stderr}"
        assert (said in proc.stderr) == (under_mpi == ONE_RANK), proc.stderr
        for png in (name for name in outputs if name.endswith(".png")):
            assert_picture(out / png)
        figures = json.loads((out / outputs[0]).read_text())
        if under_mpi == DISTRIBUTED:
            assert figures["ranks"] == 2
            serial = tmp_path / "serial"
            assert main(["simulate", model, "--out", str(serial)] + options) == 0
            expected = json.loads((serial / outputs[0]).read_text())
            rel = 1e-8 if expected["linear_solver"] == "mumps" else 1e-6
            assert_same_figures(figures, expected, rel)
            series = next(name for name in outputs if name.endswith(".bp"))
            mine, theirs = (read_series(d / series) for d in (out, serial))
            np.testing.assert_array_equal(mine.times, theirs.times)
            assert mine.fields == theirs.fields == {"displacement"}
            a, b = (last_rows(d / series, "displacement") for d in (out, serial))
            gap = np.abs(a[:, None, :] - b[None, :, :]).max(axis=2)
            scale = np.abs(b).max()
            assert len(b) == figures["nodes"] and len(a) >= len(b)
            assert max(gap.min(axis=0).max(), gap.min(axis=1).max()) < rel * scale
            # the picture is the serial one: rank 0 draws every rank's cells (measured: 0.09 %
            # of the tongue's pixels differ, along edges drawn twice where the ranks meet)
            for png in (name for name in outputs if name.endswith(".png")):
                a, b = (assert_picture(d / png) for d in (out, serial))
                assert a.shape == b.shape
                assert (np.abs(a - b).max(axis=2) > 0.1).mean() < 0.01, png
        else:
            assert figures["ranks"] == 1  # rank 0 alone
            assert proc.stderr.count(said) == 1  # said by rank 0 only
    else:
        assert proc.returncode == 2, f"{' '.join(proc.args)}:\n{proc.stdout}\n{proc.stderr}"
        assert (
            f"artifem simulate {model}: error: refused under mpiexec (2 ranks): {under_mpi}"
        ) in proc.stderr
        assert not out.exists()


def test_refused_command_exits_2_before_any_work(tmp_path):
    out = tmp_path / "bench.json"
    proc = mpirun(ARTIFEM + ["bench", "fom", "--out", str(out)], tmp_path)
    assert proc.returncode == 2, proc.stderr
    reason = COMMANDS[("bench", "fom")][2]
    assert proc.stderr.strip() == (
        f"artifem bench fom: error: refused under mpiexec (2 ranks): {reason}"
    )
    assert not out.exists()


def test_error_on_one_rank_ends_every_rank(tmp_path):
    """A distributed command whose rank 1 fails while rank 0 waits in a collective call
    (the jaw-tongue hang: an IndexError on one rank) ends with the error's status."""
    (tmp_path / "one_rank_fails.py").write_text(
        textwrap.dedent('''
        from mpi4py import MPI

        def add_arguments(parser):
            pass

        def run(args):
            comm = MPI.COMM_WORLD
            if comm.rank == 1:
                raise ValueError("bad input seen on rank 1 only")
            comm.Barrier()
            return 0
    ''')
    )
    (tmp_path / "launch.py").write_text(
        textwrap.dedent('''
        import sys                      # sys.path[0]: this directory, with one_rank_fails
        from artifem import cli

        cli.COMMANDS = {("fails",): ("one_rank_fails", "test", cli.DISTRIBUTED)}
        sys.exit(cli.main(["fails"]))
    ''')
    )
    proc = mpirun([sys.executable, str(tmp_path / "launch.py")], tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "artifem: error (rank 1): bad input seen on rank 1 only" in proc.stderr


@pytest.mark.slow  # about 5 s: the jaw-tongue scene built on 2 ranks
def test_jaw_tongue_simulate_refuses_a_distributed_tongue(tmp_path):
    """jaw_tongue.study.simulate records one rank's tongue (its tip, u, the render): on a tongue
    built on 2 ranks it raises on every rank, where its tip lookup used to fail on the
    rank without the tip and leave the other in the step's barrier."""
    (tmp_path / "distributed.py").write_text(
        textwrap.dedent('''
        import artifem  # noqa: F401  (before dolfinx)
        from mpi4py import MPI

        from artifem.errors import InputError
        from artifem.models.jaw_tongue import model as jt
        from artifem.models.jaw_tongue.study import simulate

        s = jt.build_scene(comm=MPI.COMM_WORLD)
        try:
            simulate(s, "protrusion", 0.02)
        except InputError as exc:
            print(f"rank {MPI.COMM_WORLD.rank}: {exc}")
    ''')
    )
    proc = mpirun([sys.executable, str(tmp_path / "distributed.py")], tmp_path)
    assert proc.returncode == 0, proc.stderr
    for rank in (0, 1):
        assert (
            f"rank {rank}: jaw_tongue.study.simulate: the tongue is distributed over 2 MPI ranks"
        ) in proc.stdout


def test_serial_model_bad_input_exits_2_on_every_rank(tmp_path):
    """The bad input of a model run on one rank ends it in its one-line error, and every
    rank with its status."""
    missing = tmp_path / "missing.json"
    proc = mpirun(
        ARTIFEM
        + ["simulate", "jaw-tongue", "--schedule", str(missing), "--out", str(tmp_path / "out")],
        tmp_path,
    )
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if "error" in line]
    assert (
        len(lines) == 1 and lines[0].startswith("artifem: error: ") and str(missing) in lines[0]
    ), proc.stderr
