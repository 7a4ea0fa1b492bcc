"""Shared test fixtures.

``rng``: every test that draws random inputs owns its generator, seeded from the
test's own id, so its inputs never depend on which tests ran before it (the suite
runs in random order) and a failure is reproduced by running the test alone.

Session fixtures: expensive results that several test modules need with the same
inputs, computed once per run instead of once per module (issue 13: the suite's time on
a fresh machine is mostly JIT compilation and full model runs). Each is computed on
first use, whichever module asks first, and only read afterwards.

- ``quick_jaw_tongue``: the quick reduced jaw-tongue training (test_jaw_tongue_reduced,
  test_airway);
- ``level1_protrusion``: the level-1 tongue's protrusion run (the ``level_1`` hard case of
  test_tongue_hard_cases and the level-1 side of test_tongue_convergence);
- ``quick_tongue_study``: ``artifem study tongue --quick``'s output directory
  (test_tongue_study; test_cli_end_to_end's demo starts from its training cache).
"""

import zlib
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A generator seeded by the test's node id (stable across runs and orders)."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


class QuickJawTongue(NamedTuple):
    config: Any          # jaw_tongue_reduced.ReducedJawTongueConfig
    model: Any           # jaw_tongue_reduced.ReducedTongue
    cache: Path          # its ArtifactCache directory (training runs, POD, points)


@pytest.fixture(scope="session")
def quick_jaw_tongue(tmp_path_factory) -> QuickJawTongue:
    """The quick jaw-tongue reduced training (r = 12 POD + 12 lift columns, 150 trained
    points, 0.15 s training runs of every exciter), trained once per session into a tmp
    cache directory. Modules that train through another entry point
    (``jaw_tongue_reduced.compare``, ``airway.reduced_tongue``, ``airway.benchmark``) pass
    this ``cache`` and ``config``: the artifacts are keyed by the inputs (the airway's
    jaw-tongue config is the default one, as here), so they load instead of training again
    (so do ``artifem study jaw-tongue --quick`` and ``artifem bench scenes --quick`` given
    ``--cache``)."""
    import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
    from artifem.models import jaw_tongue_reduced as jtr

    config = jtr.quick_config()      # also ``artifem study jaw-tongue --quick``'s training
    cache = tmp_path_factory.mktemp("jaw_tongue_quick") / "cache"
    return QuickJawTongue(config, jtr.train(config, cache), cache)


@pytest.fixture(scope="session")
def level1_protrusion():
    """(tongue, run_built result) of the hard case ``level_1``: the level-1 tongue,
    semi-implicit, driven by the protrusion motion, dt = 0.01 s for 1.0 s, landmarks also
    recorded at the end of the ramp (0.5 s). That is exactly the level-1 run of
    ``convergence.run_motions(1, ("protrusion",))`` (same TongueConfig, schedule, dt,
    duration and record times, checked here), so both tests read this one run (about 90 s)
    instead of computing it twice. Read only: nothing steps or resets the tongue after."""
    import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
    from artifem.models.tongue.hard_cases import build_case, run_built
    from artifem.models.tongue.model import DT, RAMP_TIME, Tongue, TongueConfig

    tongue, schedule, dt = build_case("level_1", "semi-implicit")
    protrusion = Tongue.motion("protrusion")
    assert tongue.config == TongueConfig(level=1, integrator="semi-implicit")
    assert dt == DT and tongue.scene.t == 0.0
    assert np.array_equal(schedule.times, protrusion.times)
    assert schedule.values.keys() == protrusion.values.keys()
    assert all(np.array_equal(schedule.values[k], protrusion.values[k])
               for k in protrusion.values)
    return tongue, run_built(tongue, dt, record_times=(RAMP_TIME,))


@pytest.fixture(scope="session")
def quick_tongue_study(tmp_path_factory) -> Path:
    """The output directory of ``artifem study tongue --quick`` (about 40 s): study.json,
    report, pictures and the training cache (``cache/``). test_tongue_study reads it and
    runs the study again in it (after deleting one training artifact, which that run
    restores); test_cli_end_to_end copies its cache into the quick demo's study directory,
    as a second demo run would find it."""
    import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
    from artifem.cli import main

    out = tmp_path_factory.mktemp("study")
    assert main(["study", "tongue", "--quick", "--out", str(out)]) == 0
    return out
