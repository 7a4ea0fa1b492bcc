"""The robustness study (artifem.robustness_study): its schedules are valid inputs of each
hard kind, drawn reproducibly, and a short study of the tongue reports every run."""

import json

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.errors import InputError
from artifem.robustness_study import KINDS, hard_schedules, load, robustness_study, write_report
from outputs import assert_picture

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


#: seed 0's five schedules, two steps of 0.01 s on the level-0 tongue: (retried steps:
#: fallbacks, halvings; min det F; max |V / V0 - 1|), measured (two runs, same digits; the
#: runs are deterministic on one machine, their wall times are not). To rel 1e-4: a run
#: with retried steps turns on round-off across machines (pulses-0-2's min det F: 0.2433487,
#: 0.2433484 and 0.2433509 with three BLAS kernels).
MEASURED_RUNS = {
    "smooth-0-0": (0, 0, 0.5679368620627201, 0.00012877664909538566),
    "coactivation-0-1": (0, 0, 0.6846359376598343, 3.397258193271746e-05),
    "pulses-0-2": (1, 1, 0.24334871027898752, 4.9716059214333086e-05),
    "all-0-3": (1, 0, 0.16931428900676543, 3.8420635717351104e-07),
    "release-0-4": (2, 1, 0.3059412580540805, 3.62866609902035e-05),
}


def test_a_short_study_of_the_tongue_reports_every_run(tmp_path):
    """Five schedules (one of each kind), two steps each, default settings: every run
    finishes with its measured retries, min det F and volume change; its cost is against
    the study's semi-implicit step; the report's table has one row per run, rendered from
    the JSON it wrote, and the picture shows the bars."""
    result = robustness_study(load("tongue"), 5, seed=0, duration=0.02, dt=0.01, progress=False)
    write_report(result, tmp_path)
    saved = json.loads((tmp_path / "robustness.json").read_text())
    assert saved["summary"] == result["summary"]
    assert_picture(tmp_path / "robustness.png")
    runs = result["runs"]
    assert [r["kind"] for r in runs.values()] == list(KINDS)
    report = (tmp_path / "robustness.md").read_text().splitlines()
    for name, r in saved["runs"].items():  # the table's row is the JSON's run
        row = (
            f"| {name} | {r['outcome']} | {r['t_reached']:.3g} | {r['cost']:.2f} | "
            f"{r['fallbacks']} | {r['halvings']} | {r['min_det_F']:.3f} | "
            f"{r['max_volume_change']:.1e} | {r['wall_s']:.1f} |"
        )
        assert row in report, row
    summary = result["summary"]
    assert summary["finished"] == 5 and summary["by_kind"] == {k: "1/1" for k in KINDS}
    assert summary["fallbacks"] == sum(r["fallbacks"] for r in runs.values())
    assert summary["min_det_F"] == min(r["min_det_F"] for r in runs.values())
    assert summary["semi_implicit_step_ms"] is not None  # some steps needed no retry
    for name, r in runs.items():
        fallbacks, halvings, det_F, volume = MEASURED_RUNS[name]
        assert r["outcome"] == "finished" and r["error"] is None, name
        assert r["steps"] == 2 and r["t_reached"] == pytest.approx(0.02)
        assert (r["fallbacks"], r["halvings"]) == (fallbacks, halvings), name
        assert r["min_det_F"] == pytest.approx(det_F, rel=1e-4), name
        assert r["max_volume_change"] == pytest.approx(volume, rel=1e-4), name
        assert r["cost"] is not None, name  # a timing: only its presence is determined


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
