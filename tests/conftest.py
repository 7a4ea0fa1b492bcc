"""Shared test fixtures.

``rng``: every test that draws random inputs owns its generator, seeded from the
test's own id, so its inputs never depend on which tests ran before it (the suite
runs in random order) and a failure is reproduced by running the test alone.

Session fixtures: expensive results that several test modules need with the same
inputs, computed once per run instead of once per module (issue 13: the suite's time on
a fresh machine is mostly JIT compilation and full model runs). Each is computed on
first use, whichever module asks first, and only read afterwards. Under pytest-xdist the
first worker that asks computes it into the run's shared temporary directory while the
others wait on a lock; each worker then works on its own copy (``computed_once``), so a
test that changes its copy (deleting an artifact to test a resume) cannot disturb a test
on the other worker.

- ``quick_jaw_tongue``: the quick reduced jaw-tongue training (test_jaw_tongue_reduced,
  test_airway);
- ``quick_tongue_study``: ``artifem study tongue --quick``'s output directory
  (test_tongue_study; test_cli_end_to_end's demo starts from its training cache).

Slow tests: every test of a file measured to take over ``SLOW_S`` seconds
(``tests/durations.json``) is marked ``slow``, besides those marked by hand, so that
``make test PYTEST_ARGS='-m "not slow"'`` is a loop of about 2.5 minutes (a warm JIT
cache); a new file counts as fast until ``make test-durations`` has measured it.

Order of the files under pytest-xdist: the files measured to take over ``HEAVY_S``
seconds (``tests/durations.json``, written by ``make test-durations``) go first, in the
random order pytest-randomly gave them, the rest after them in theirs; with
``--no-loadscope-reorder`` (the Makefile) the two workers take the long files first and
end together (longest-processing-time-first scheduling; xdist's default puts the files
with the most tests first, which says little of their time).
"""

import collections
import fcntl
import json
import os
import resource
import shutil
import time
import zlib
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np
import pytest


#: seconds of a test file (setup, call and teardown of its tests) above which it runs first
HEAVY_S = 20.0
#: seconds of a test file above which its tests are marked ``slow`` (module docstring)
SLOW_S = 15.0
DURATIONS = Path(__file__).with_name("durations.json")
_SECONDS = json.loads(DURATIONS.read_text())["seconds_per_file"] if DURATIONS.exists() else {}


def pytest_addoption(parser):
    parser.addoption(
        "--write-durations",
        metavar="FILE",
        type=Path,
        help="after a passing run, write each test file's seconds (setup, "
        "call and teardown of its tests) to FILE as JSON",
    )


def pytest_itemcollected(item):
    """The tests of a file measured to take over ``SLOW_S`` are ``slow`` (before ``-m``
    deselects)."""
    if _SECONDS.get(item.nodeid.split("::")[0], 0.0) >= SLOW_S:
        item.add_marker(pytest.mark.slow)


@pytest.hookimpl(trylast=True)  # after pytest-randomly's shuffle
def pytest_collection_modifyitems(config, items):
    """Long files first (module docstring), each group in the order it came in."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return
    items.sort(key=lambda item: _SECONDS.get(item.nodeid.split("::")[0], 0.0) < HEAVY_S)


_file_seconds: collections.Counter = collections.Counter()
_file_cpu: collections.Counter = collections.Counter()
_tests: set = set()
_started: list = []
_cpu_mark: list = [0.0]


def _cpu_seconds() -> float:
    """CPU seconds of this process and of the processes it has waited for (a command's
    subprocess, ``mpiexec``'s ranks, the C compiler of a form)."""
    own, children = (
        resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
    )
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def pytest_sessionstart(session):
    _started.append(time.perf_counter())


def pytest_runtest_logstart(nodeid, location):
    _cpu_mark[0] = _cpu_seconds()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """Each phase's report carries the CPU seconds it took (``cpu_s``), for
    ``--write-durations``: a file's CPU against its wall time shows waiting (another
    worker's form compile, a shared fixture's lock) apart from work."""
    report = yield
    now = _cpu_seconds()
    report.user_properties.append(("cpu_s", now - _cpu_mark[0]))
    _cpu_mark[0] = now
    return report


def pytest_runtest_logreport(report):
    _file_seconds[report.nodeid.split("::")[0]] += report.duration
    _file_cpu[report.nodeid.split("::")[0]] += dict(report.user_properties).get("cpu_s", 0.0)
    _tests.add(report.nodeid)


def pytest_sessionfinish(session, exitstatus):
    out = session.config.getoption("write_durations")
    if out is None or exitstatus != 0 or "PYTEST_XDIST_WORKER" in os.environ:
        return
    workers = getattr(session.config.option, "numprocesses", None) or 1
    out.write_text(
        json.dumps(
            {
                "what": "seconds per test file (setup, call and teardown of its tests) in one "
                "passing run of the suite with an empty JIT cache, and the CPU seconds they "
                "took (the test's process and the processes it waited for); "
                "tests/conftest.py runs the long files first",
                "command": "make test-durations",
                "tests": len(_tests),
                "workers": workers,
                "wall_s": round(time.perf_counter() - _started[0], 1),
                "seconds_per_file": {f: round(t, 1) for f, t in sorted(_file_seconds.items())},
                "cpu_seconds_per_file": {f: round(t, 1) for f, t in sorted(_file_cpu.items())},
            },
            indent=1,
        )
        + "\n"
    )


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A generator seeded by the test's node id (stable across runs and orders)."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


def computed_once(tmp_path_factory, name: str, make: Callable[[Path], None]) -> Path:
    """A directory that ``make(directory)`` fills, made once per test run.

    In one process: made in a fresh temporary directory. Under pytest-xdist: made once in
    the run's temporary root (shared by the workers and new for every run), under an
    exclusive lock (stdlib ``fcntl``: one machine, no extra dependency), by whichever
    worker asks first; every worker gets its own copy of it.
    """
    if "PYTEST_XDIST_WORKER" not in os.environ:  # set by xdist in its workers
        own = tmp_path_factory.mktemp(name)
        make(own)
        return own
    root = tmp_path_factory.getbasetemp().parent
    shared, done = root / name, root / f"{name}.done"
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not done.exists():  # first asker (or an earlier one failed)
            shutil.rmtree(shared, ignore_errors=True)
            shared.mkdir()
            make(shared)
            done.touch()
    own = tmp_path_factory.mktemp(name)
    shutil.copytree(shared, own, dirs_exist_ok=True)
    return own


@pytest.fixture(scope="session")
def foot_cache(tmp_path_factory) -> Path:
    """A foot mesh cache holding the coarse (level 0) mesh, meshed once per test run."""
    from artifem.models.foot.mesh import foot_mesh

    return computed_once(tmp_path_factory, "foot_cache", lambda d: foot_mesh(0, cache=d))


class QuickJawTongue(NamedTuple):
    config: Any  # jaw_tongue.reduced.ReducedJawTongueConfig
    model: Any  # reduction.reductor.ReducedModel (jaw_tongue.reduced.train)
    cache: Path  # its ArtifactCache directory (training runs, POD, points)


@pytest.fixture(scope="session")
def quick_jaw_tongue(tmp_path_factory) -> QuickJawTongue:
    """The quick jaw-tongue reduced training (r = 12 POD + 12 lift columns, 150 trained
    points, 0.15 s training runs of every exciter), trained once per run into a tmp
    cache directory (``computed_once``; a worker that did not train loads it). Modules that train
    through another entry point (``jaw_tongue.study.compare``,
    ``airway.model.reduced_tongue``, ``airway.study.benchmark``) pass
    this ``cache`` and ``config``: the artifacts are keyed by the inputs (the airway's
    jaw-tongue config is the default one, as here), so they load instead of training again
    (so do ``artifem study jaw-tongue --quick`` and ``artifem bench scenes --quick`` given
    ``--cache``)."""
    import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
    from artifem.models.jaw_tongue import reduced as jtr

    config = jtr.quick_config()  # also ``artifem study jaw-tongue --quick``'s training
    cache = (
        computed_once(
            tmp_path_factory, "jaw_tongue_quick", lambda d: jtr.train(config, d / "cache")
        )
        / "cache"
    )
    return QuickJawTongue(config, jtr.train(config, cache), cache)


@pytest.fixture(scope="session")
def quick_tongue_study(tmp_path_factory) -> Path:
    """The output directory of ``artifem study tongue --quick --held-out 2`` (about 50 s;
    the command of the committed quick split, docs/benchmarks/quick_splits.json): study.json,
    generalization.json, report, pictures and the training cache (``cache/``).
    test_tongue_study reads it and runs the study again in it (after deleting one training
    artifact, which that run restores); test_cli_end_to_end copies its cache into the
    quick demo's study directory, as a second demo run would find it."""
    import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
    from artifem.cli import main
    from outputs import quick_split

    def make(out: Path) -> None:
        assert main([*quick_split("tongue")["argv"], "--out", str(out)]) == 0

    return computed_once(tmp_path_factory, "study", make)


@pytest.fixture
def direct_solver():
    """A factory of MUMPS LinearSolvers for one body (LU when its tangent is unsymmetric:
    a follower pressure), so that Newton's convergence is not blurred by a linear
    tolerance (test_static_newton)."""
    from mpi4py import MPI

    from artifem.linear_solver import LinearSolver

    def make(body):
        return LinearSolver(MPI.COMM_SELF, "mumps", V=body.V, symmetric=body.conservative)

    return make


@pytest.fixture(scope="session")
def icosphere():
    """``icosphere(level, radius)`` -> (vertices, triangles): a sphere of radius ``radius``,
    an icosahedron subdivided ``level`` times, outward."""

    def build(level, radius=1.0):
        p = (1 + 5**0.5) / 2
        vertices = [
            (-1, p, 0),
            (1, p, 0),
            (-1, -p, 0),
            (1, -p, 0),
            (0, -1, p),
            (0, 1, p),
            (0, -1, -p),
            (0, 1, -p),
            (p, 0, -1),
            (p, 0, 1),
            (-p, 0, -1),
            (-p, 0, 1),
        ]
        vertices = [np.array(v, float) / np.linalg.norm(v) for v in vertices]
        faces = [
            (0, 11, 5),
            (0, 5, 1),
            (0, 1, 7),
            (0, 7, 10),
            (0, 10, 11),
            (1, 5, 9),
            (5, 11, 4),
            (11, 10, 2),
            (10, 7, 6),
            (7, 1, 8),
            (3, 9, 4),
            (3, 4, 2),
            (3, 2, 6),
            (3, 6, 8),
            (3, 8, 9),
            (4, 9, 5),
            (2, 4, 11),
            (6, 2, 10),
            (8, 6, 7),
            (9, 8, 1),
        ]
        for _ in range(level):
            midpoints = {}

            def midpoint(i, j):
                key = (min(i, j), max(i, j))
                if key not in midpoints:
                    m = vertices[i] + vertices[j]
                    vertices.append(m / np.linalg.norm(m))
                    midpoints[key] = len(vertices) - 1
                return midpoints[key]

            faces = [
                f
                for a, b, c in faces
                for ab, bc, ca in [(midpoint(a, b), midpoint(b, c), midpoint(c, a))]
                for f in ((a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca))
            ]
        return radius * np.array(vertices), np.array(faces)

    return build


@pytest.fixture(scope="session")
def sliding_block():
    """``sliding_block(lift, foundation=None)`` -> (scene, body, contact): a 6 x 6 x 3 hex
    block (0.1 x 0.1 x 0.05 m, neo-Hookean, 196 nodes) ``lift`` above a plane tilted by
    11 degrees, thrown sideways at 0.3 m/s; mu = 0.3, margin 2 cm (the KKT path's scenes)."""
    import artifem as af
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    def make(lift, foundation=None):
        msh = dmesh.create_box(
            MPI.COMM_SELF,
            [np.array([0.0, 0.0, lift]), np.array([0.1, 0.1, 0.05 + lift])],
            [6, 6, 3],
            dmesh.CellType.hexahedron,
        )
        body = af.FemBody(
            msh,
            af.NeoHookean.from_young_poisson(1e5, 0.3),
            1000.0,
            rayleigh=(10.0, 1e-3),
            name="block",
        )
        body.v.x.array.reshape(-1, 3)[:, 0] = 0.3
        contact = af.PlaneContact(
            body,
            (0.0, 0.0, 0.0),
            (0.2, 0.0, 1.0),
            mu=0.3,
            tolerance=1e-5,
            margin=0.02,
            foundation=foundation,
        )
        scene = af.Scene(gravity=(0.0, 0.0, -9.81))
        scene.add(body, contact)
        return scene, body, contact

    return make


#: what a scene script does under ``mpiexec``: its run on every rank, JSON from rank 0
_SCRIPT_MAIN = """

if __name__ == "__main__":
    import json as _json
    import sys as _sys
    from mpi4py import MPI as _MPI
    _result = run(*build(_MPI.COMM_WORLD))
    if _MPI.COMM_WORLD.rank == 0:
        with open(_sys.argv[1], "w") as _f:
            _json.dump(_result, _f)
"""


@pytest.fixture(scope="session")
def script_scene(tmp_path_factory):
    """``script_scene(text, name)`` -> (path, namespace): a scene script defining
    ``build(comm, **options)`` and ``run(*built) -> dict``, written to a file that, run
    under ``mpiexec`` with a path argument, writes ``run(*build(COMM_WORLD))`` there as JSON
    (:func:`_run_two_ranks`), and executed here (its ``build`` and ``run`` for the serial
    comparison)."""

    def make(text: str, name: str):
        text = text + _SCRIPT_MAIN
        path = tmp_path_factory.mktemp(name) / f"{name}.py"
        path.write_text(text)
        namespace = {"__name__": name}
        exec(compile(text, str(path), "exec"), namespace)
        return path, namespace

    return make


@pytest.fixture(scope="session")
def two_ranks():
    """``two_ranks(path, tmp_path)`` -> the JSON a scene script writes (its first argument)
    when run under ``mpiexec -n 2`` with this interpreter (its output in the failure)."""
    return _run_two_ranks


def _run_two_ranks(path: Path, tmp_path: Path) -> dict:
    import subprocess
    import sys

    out = tmp_path / "result.json"
    command = [
        str(Path(sys.executable).parent / "mpiexec"),
        "-n",
        "2",
        sys.executable,
        str(path),
        str(out),
    ]
    proc = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, f"{' '.join(command)} failed:\n{proc.stdout}\n{proc.stderr}"
    return json.loads(out.read_text())
