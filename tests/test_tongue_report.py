"""The report stage of the speed-vs-error study (artifem.models.tongue.report) on a
small synthetic study directory: figures, renders, tables and target checks."""

import json
import math

import numpy as np
import pytest
from matplotlib.image import imread

from artifem.models.tongue.report import main, write_report

TIMES = np.linspace(0.0, 1.0, 11)
FAILURE = "Newton diverged at t = 0.42 s"


def run_entry(basis, r, points, sampling, motion, ms, max_error, failed=False):
    """A runs[] entry of study.json (full model: 100 ms per step)."""
    entry = {
        "id": f"{basis}_r{r}_m{points}_{sampling}_{motion}",
        "basis": basis,
        "r": r,
        "points": points,
        "sampling": sampling,
        "motion": motion,
        "ms_per_step": ms,
        "mean_error_mm": max_error / 2,
        "max_error_mm": max_error,
        "max_node_error_mm": 3 * max_error,
        "speedup": 100.0 / ms,
        "time_of_max_error": 0.5,
    }
    if failed:
        entry.update(
            {
                key: math.nan
                for key in (
                    "ms_per_step",
                    "mean_error_mm",
                    "max_error_mm",
                    "max_node_error_mm",
                    "speedup",
                    "time_of_max_error",
                )
            },
            failed=True,
            error=FAILURE,
        )
    return entry


RUNS = [
    run_entry("extended-modal", 54, 600, "trained", "protrusion", 8.0, 1.5),
    run_entry("extended-modal", 54, 600, "trained", "retraction", 9.0, 1.7),
    run_entry("trained-pod", 20, 300, "trained", "protrusion", 0.5, 0.6),  # passes
    run_entry("trained-pod", 20, 300, "trained", "retraction", 0.7, 0.8),
    run_entry("trained-pod", 20, 200, "trained", "protrusion", 0.4, 1.4),  # error too big
    run_entry("trained-pod", 20, 200, "trained", "retraction", 0.3, 0.5, failed=True),
    run_entry("trained-pod", 20, 600, "random", "protrusion", 2.0, 0.9),
]  # not checked


def two_hexes():
    """(points in m, cells) of two unit-10-mm hexahedra in a row, VTK ordering."""
    grid = np.mgrid[0:3, 0:2, 0:2].reshape(3, -1).T  # nodes (i, j, k)
    order = np.lexsort((grid[:, 0], grid[:, 1], grid[:, 2]))  # renumbered i + 3 j + 6 k
    points = 0.01 * grid[order].astype(float)
    cells = np.array([[0, 1, 4, 3, 6, 7, 10, 9], [1, 2, 5, 4, 7, 8, 11, 10]])
    return points, cells


def write_study(out):
    """The files the study driver writes: study.json, series.npz, one frame."""
    study = {
        "model": {"name": "tongue", "nodes": 12, "elements": 2, "level": 0, "dofs": 36},
        "dt": 0.1,
        "duration": 1.0,
        "full": {
            "ms_per_step": 100.0,
            "ms_per_step_by_motion": {"protrusion": 98.0, "retraction": 102.0},
        },
        "training": {
            "snapshots": 440,
            "energy_captured": 0.99931,
            "basis": {"r": 20},
            "muscles": ["GGP", "SL"],
        },
        "runs": RUNS,
        "targets": {"ms_per_step": 1.0, "speedup": 100.0, "max_error_mm": 1.0},
    }
    (out / "study.json").write_text(json.dumps(study))
    ramp = np.minimum(TIMES / 0.5, 1.0)
    series = {"times": TIMES}
    for run in RUNS:
        errors = run["max_error_mm"] * ramp if not run.get("failed") else 0.5 * ramp
        series[f"error/{run['id']}"] = (
            np.where(TIMES > 0.4, np.nan, errors) if run.get("failed") else errors
        )
    np.savez(out / "series.npz", **series)
    points, cells = two_hexes()
    u_full = 0.002 * points[:, [0]] / 0.02 * np.array([0.0, 0.0, 1.0])
    (out / "frames").mkdir()
    np.savez(
        out / "frames" / f"{RUNS[2]['id']}.npz",
        points=points,
        cells=cells,
        u_full=u_full,
        u_reduced=0.9 * u_full,
        time=0.5,
    )


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    write_study(out)
    return out, write_report(out)


def test_writes_every_figure(study_dir):
    out, report = study_dir
    assert report == out / "report.md"
    pngs = [
        "error_protrusion.png",
        "error_retraction.png",
        "speed_vs_error.png",
        f"render_{RUNS[2]['id']}.png",
    ]
    for name in pngs:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        assert np.ptp(imread(out / name)[..., :3]) > 0, f"{name} is blank"
        assert f"]({name})" in report.read_text()
    assert sorted(p.name for p in out.glob("*.png")) == sorted(pngs)


def test_table2_analog(study_dir):
    text = study_dir[1].read_text()
    assert "| Extended modal (r=54) | 8.50 (53.2) | — (33.0) | — (23.6) |" in text
    assert "| Trained (r=20) | — (27.7) | 0.60 (15.2) | 0.40 [1 failed] (12.1) |" in text
    assert "Full model: ours 100.00 ms per step, paper 188.9 ms." in text
    assert (
        "Full model: 100.00 ms per step (median over motions; protrusion 98.00, retraction 102.00)"
    ) in text
    assert "12 nodes, 2 elements, level 0" in text
    assert "- energy_captured: 0.9993" in text and "- basis.r: 20" in text
    assert "muscles" not in text


def test_runs_table_reports_the_failure(study_dir):
    text = study_dir[1].read_text()
    assert (
        "| trained-pod | 20 | 300 | trained | protrusion | 0.50 | 200.0 | 0.30 | 0.60 | 1.80 | ok |"
    ) in text
    assert (
        f"| trained-pod | 20 | 200 | trained | retraction | — | — | — | — | — | FAILED: {FAILURE} |"
    ) in text


def test_target_checks(study_dir):
    text = study_dir[1].read_text()
    targets = text[text.index("## Targets") : text.index("## Figures")]
    assert "- **PASS** trained-pod r=20, 300 pts, trained" in targets
    assert (
        "  - protrusion: 0.50 ms/step (<= 1) ok, speed-up 200.0x (>= 100) ok, "
        "max error 0.60 mm (<= 1) ok"
    ) in targets
    assert "- **FAIL** trained-pod r=20, 200 pts, trained" in targets
    assert "max error 1.40 mm (<= 1) MISSED" in targets
    assert f"  - retraction: failed ({FAILURE})" in targets
    assert "random" not in targets and "extended-modal" not in targets
    assert "1 of 2 configurations meet every target." in targets


def test_module_main_regenerates(study_dir, tmp_path, capsys):
    out, report = study_dir
    before = report.read_text()
    report.unlink()
    assert main([str(out)]) == 0
    assert report.read_text() == before
    assert "report.md" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="no study.json"):
        main([str(tmp_path)])
