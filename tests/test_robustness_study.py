"""The robustness study (artifem.robustness_study): its schedules are valid inputs of each
hard kind, drawn reproducibly, and a short study of the tongue reports every run."""

import json

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.errors import InputError
from artifem.robustness_study import KINDS, hard_schedules, load, robustness_study, write_report

EXCITERS = ["A", "B", "C", "D", "E", "F"]


def test_the_schedules_are_valid_and_of_every_kind():
    drawn = hard_schedules(EXCITERS, 10, seed=3, duration=1.0)
    assert [kind for kind, _ in drawn.values()] == list(KINDS) * 2
    for name, (kind, s) in drawn.items():
        assert name.startswith(f"{kind}-3-")
        assert s.times[0] == 0.0 and s.times[-1] == pytest.approx(1.0)
        values = np.array(list(s.values.values()))
        assert values.min() >= 0.0 and values.max() <= 1.0 and values[:, 0].max() == 0.0
        switches = np.abs(np.diff(values, axis=1)) / np.diff(s.times)  # per second
        if kind == "coactivation":
            assert len(s.values) == 2 and values[:, -1].min() == 1.0
        elif kind == "all":
            assert sorted(s.values) == EXCITERS and np.ptp(values[:, -1]) == 0.0
        elif kind == "pulses":
            assert 1 <= len(s.values) <= 3
            assert (switches > 400).sum(axis=1).min() >= 10  # on and off, fast, often
        elif kind == "release":
            assert values[:, -1].max() == 0.0 and values.max(axis=1).min() >= 0.5
            assert switches.max() > 400  # dropped within 1 ms
        else:
            assert 2 <= len(s.values) <= 4


def test_the_same_seed_draws_the_same_schedules():
    a, b = (hard_schedules(EXCITERS, 5, seed=7, duration=0.5) for _ in range(2))
    c = hard_schedules(EXCITERS, 5, seed=8, duration=0.5)
    for name in a:
        assert a[name][1].values.keys() == b[name][1].values.keys()
        for e in a[name][1].values:
            np.testing.assert_array_equal(a[name][1].values[e], b[name][1].values[e])
    assert any(not np.array_equal(a[n][1].times, c[m][1].times) for n, m in zip(a, c))


@pytest.mark.parametrize(
    "exciters, count, duration, fragment",
    [
        (["A", "A"], 3, 1.0, "distinct names"),
        (EXCITERS, 0, 1.0, "count must be a positive integer"),
        (EXCITERS, 3, -1.0, "duration must be positive"),
    ],
)
def test_bad_input(exciters, count, duration, fragment):
    with pytest.raises(InputError, match=fragment):
        hard_schedules(exciters, count, seed=0, duration=duration)


def test_a_short_study_of_the_tongue_reports_every_run(tmp_path):
    """Five schedules (one of each kind), two steps each, default settings: every run is
    reported with its outcome, its cost against the study's semi-implicit step and its
    health figures, and the report files are written."""
    result = robustness_study(load("tongue"), 5, seed=0, duration=0.02, dt=0.01, progress=False)
    write_report(result, tmp_path)
    saved = json.loads((tmp_path / "robustness.json").read_text())
    assert saved["summary"] == result["summary"]
    assert (tmp_path / "robustness.png").stat().st_size > 0
    assert "| schedule | outcome |" in (tmp_path / "robustness.md").read_text()
    runs = result["runs"]
    assert [r["kind"] for r in runs.values()] == list(KINDS)
    summary = result["summary"]
    assert summary["finished"] == sum(r["outcome"] == "finished" for r in runs.values())
    assert summary["fallbacks"] == sum(r["fallbacks"] for r in runs.values())
    step = summary["semi_implicit_step_ms"]  # None: every step of the study retried
    for r in runs.values():
        assert (r["cost"] is None) == (step is None or r["steps"] == 0)
        if r["outcome"] == "finished":
            assert r["steps"] == 2 and r["t_reached"] == pytest.approx(0.02)
            assert r["min_det_F"] > 0 and r["error"] is None
        else:
            assert r["error"] and r["t_reached"] < 0.02


def test_every_run_starts_from_rest_with_every_input_off():
    """A run after another (the study's one scene, restored to rest) ends where the same
    run does on a fresh scene: the exciters a schedule leaves out are held at 0, not at
    the last run's excitation (they were, and the study's first steps failed on them)."""
    from artifem.robustness_study import _run

    model = load("tongue")
    drawn = hard_schedules(
        list(model.inputs(model.fem_body(model.build()))), 4, seed=0, duration=0.02
    )
    every, some = drawn["all-0-3"][1], drawn["smooth-0-0"][1]
    assert len(some.values) < len(every.values)

    def final_u(schedules):
        scene = model.build()
        rest = scene.save_state()
        for schedule in schedules:
            _run(model, scene, rest, schedule, 0.02, 0.01)
        return model.fem_body(scene).u.x.array.copy()

    alone, after = final_u([some]), final_u([every, some])
    assert np.abs(alone).max() > 0
    np.testing.assert_allclose(after, alone, rtol=0, atol=1e-12 * np.abs(alone).max())
