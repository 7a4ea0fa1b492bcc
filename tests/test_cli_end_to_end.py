"""Every command of ``artifem`` that no other test runs end to end, run through the command
line (``artifem.cli.main``, as the console script does) in its quickest documented setting,
and what it writes checked for soundness against expectations that do not come from the
command itself: step and record counts from ``--duration / --dt``, mesh sizes from the
model's description, balances that hold exactly (net force of a pressure on a closed skin,
jaw and arch forces, mass = density x volume), one command's figures against another's run
of the same scene, and PNG headers.

Covered elsewhere: ``mesh info`` (test_io), ``material curves``, ``simulate beam``
(test_cli), ``simulate tongue --case`` (test_tongue_model), ``study beam-ellipsoid``
(test_beam_ellipsoid), every model's ``simulate`` through the runner (test_models and the
model's own tests), ``study tongue --quick`` (test_tongue_study), one-rank ``bench fom``
and ``bench tongue`` (test_bench); every command's bad input: test_cli_bad_input.

``study jaw-tongue --quick`` and ``bench scenes --quick`` load the session's quick
jaw-tongue training (``quick_jaw_tongue``, tests/conftest.py, shared with
test_jaw_tongue_reduced and test_airway) through ``--cache``; ``demo --quick`` starts from
the training of the session's quick tongue study (``quick_tongue_study``, shared with
test_tongue_study). Run alone, these tests compute those first (about 50 s and 40 s).
"""

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.cli import main

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="the commands run in serial")

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MPIEXEC = Path(__import__("sys").executable).parent / "mpiexec"


def is_png(path, min_bytes=5_000) -> bool:
    path = Path(path)
    return path.read_bytes()[:8] == PNG_SIGNATURE and path.stat().st_size > min_bytes


def finite_positive(x) -> bool:
    return isinstance(x, float) and math.isfinite(x) and x > 0


# ---- simulate jaw-tongue, study jaw-tongue ----------------------------------------------

JT_DURATION, JT_DT = 0.05, 0.01


@pytest.fixture(scope="module")
def jaw_tongue_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("jaw_tongue")
    assert (
        main(
            [
                "simulate",
                "jaw-tongue",
                "--case",
                "protrusion",
                "--no-progress",
                "--duration",
                str(JT_DURATION),
                "--dt",
                str(JT_DT),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    out = out / "protrusion"
    return out, json.loads((out / "simulate.json").read_text())


def test_simulate_jaw_tongue_writes_sound_results(jaw_tongue_run):
    out, f = jaw_tongue_run
    steps = round(JT_DURATION / JT_DT)
    assert (f["motion"], f["steps"], f["halvings"]) == ("protrusion", steps, 0)
    # one record per step and one at rest
    assert f["t"] == pytest.approx([k * JT_DT for k in range(steps + 1)])
    for key in (
        "opening_angle_deg",
        "tip_displacement_mm",
        "jaw_nodes_mean_dz_mm",
        "opener_tension_N",
    ):
        assert len(f[key]) == steps + 1, key
        assert np.all(np.isfinite(f[key])), key
    # the level-0 tongue (946 nodes) with its 59 jaw-attachment nodes (models/jaw_tongue/model.py)
    assert f["tongue"]["nodes"] == 946 and f["tongue"]["jaw_attachment_nodes"] == 59
    assert finite_positive(f["ms_per_step"]) and 0 < f["min_det_F"] <= 1.5
    # the opener opens the jaw within its hinge limits; the carried nodes ride on it
    lo, hi = np.degrees(f["jaw"]["limits_rad"])
    angles = np.array(f["opening_angle_deg"])
    assert angles[0] == pytest.approx(0.0, abs=1e-9) and f["max_opening_angle_deg"] > 0.0
    assert np.all((angles >= lo - 1e-6) & (angles <= hi + 1e-6))
    assert f["max_opening_angle_deg"] == pytest.approx(angles.max())
    assert f["tip_displacement_mm"][0] == [0.0, 0.0, 0.0]
    assert np.linalg.norm(f["final_tip_displacement_mm"]) > 0.1  # the tongue moved
    assert f["max_attachment_error_m"] < 1e-12 and f["max_joint_error"] < 1e-5
    assert is_png(out / "jaw-tongue.png", 10_000)


def test_study_jaw_tongue_quick_agrees_with_simulate_jaw_tongue(
    tmp_path, quick_jaw_tongue, jaw_tongue_run, capsys
):
    from artifem.models.jaw_tongue import reduced as jtr

    assert quick_jaw_tongue.config == jtr.quick_config()  # its training is in the cache
    out = tmp_path / "study"
    assert (
        main(
            [
                "study",
                "jaw-tongue",
                "--quick",
                "--duration",
                str(JT_DURATION),
                "--cache",
                str(quick_jaw_tongue.cache),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    f = json.loads((out / "jaw_tongue_reduced.json").read_text())
    assert "| protrusion |" in capsys.readouterr().out  # the table, printed
    assert (f["duration"], f["dt"]) == (JT_DURATION, JT_DT)
    assert f["basis"]["pod_vectors"] == 12 and f["points"]["count"] == 150
    assert set(f["motions"]) == {"protrusion"}  # --quick: one motion
    r = f["motions"]["protrusion"]
    assert finite_positive(r["full_ms_per_step"]) and finite_positive(r["reduced_ms_per_step"])
    assert r["speedup"] == pytest.approx(r["full_ms_per_step"] / r["reduced_ms_per_step"])
    assert 0 < r["max_mean_error_mm"] <= r["max_node_error_mm"]
    assert r["max_mean_error_mm"] < 0.5  # a few tenths of a mm
    assert r["max_attachment_error_m"] < 1e-12 and r["max_joint_error"] < 1e-5
    assert 0 <= r["worst_time_s"] <= JT_DURATION + 1e-12
    # its full scene is the one `simulate jaw-tongue` ran: same motion, dt, duration
    _, sim = jaw_tongue_run
    tip = np.linalg.norm(sim["tip_displacement_mm"], axis=1).max()
    assert r["max_tip_displacement_mm"] == pytest.approx(tip, rel=1e-6)
    assert r["max_angle_deg"]["full"] == pytest.approx(sim["max_opening_angle_deg"], rel=1e-6)
    assert r["max_angle_deg"]["reduced"] == pytest.approx(r["max_angle_deg"]["full"], rel=0.2)
    assert is_png(out / r["png"], 10_000)
    assert "| protrusion |" in (out / "jaw_tongue_reduced.md").read_text()


# ---- simulate masseter, airway, styloglossus --------------------------------------------


def test_study_masseter_coarse(tmp_path):
    from artifem.models.masseter.model import MODELS

    assert main(["study", "masseter", "--coarse", "--steps", "1", "--out", str(tmp_path)]) == 0
    s = json.loads((tmp_path / "masseter.json").read_text())
    c = s["config"]
    assert c["steps"] == 1 and c["voxel_size"] == 0.005  # --steps, --coarse
    assert set(s["models"]) == {f"{p}/{a}" for p, a in MODELS}
    sigma_area = c["max_stress"] * c["excitation"] * c["width_bottom"] * c["thickness"]
    for label, m in s["models"].items():
        assert len(m["ms_per_step_all"]) == m["steps"] == 1, label
        assert finite_positive(m["ms_per_step"]) and m["masters"] > 0, label
        assert 0 < m["min_det_F"] <= 1.5 and m["max_displacement_mm"] > 0, label
        # the static jaw and arch forces balance; the jaw force is about the active fiber
        # stress times the muscle's cross-section
        jaw, arch = np.array(m["jaw_force_N"]), np.array(m["arch_force_N"])
        assert np.linalg.norm(jaw + arch) < 1e-9 * np.linalg.norm(jaw), label
        assert 0.5 < m["jaw_force_magnitude_N"] / sigma_area < 1.5, label
        # mass = density x volume (voxels or tetrahedra)
        volume = m.get("voxel_volume", m.get("tet_volume"))
        if m["membrane_nodes"] == 0 and "slab_cells" not in m:
            assert m["mass_kg"] == pytest.approx(c["density"] * volume, rel=1e-9), label
    assert is_png(s["png"], 10_000)


def test_study_airway_one_motion(tmp_path):
    duration, dt = 0.02, 0.01
    assert (
        main(
            [
                "study",
                "airway",
                "--motions",
                "protrusion",
                "--duration",
                str(duration),
                "--dt",
                str(dt),
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    f = json.loads((tmp_path / "airway.json").read_text())
    assert set(f["runs"]) == {
        f"{m}/{p}" for m in ("none", "protrusion") for p in ("pressure", "no_pressure")
    }
    steps = round(duration / dt)
    sections = f["sections"]["count"]
    for key, r in f["runs"].items():
        assert len(r["t"]) == len(r["opening_angle_deg"]) == steps + 1, key
        assert finite_positive(r["ms_per_step_median"]), key
        assert len(r["final_areas_mm2"]) == sections and min(r["final_areas_mm2"]) > 0, key
        assert r["max_attachment_error_m"] < 1e-12, key
    # a uniform pressure on a closed skin: no net force on the masters together
    res = f["resultants_N_at_rest_pressure"]
    total = np.sum([res[m] for m in ("tongue", "jaw", "palate")], axis=0)
    assert np.linalg.norm(total) < 1e-9 * np.linalg.norm(res["tongue"])
    assert np.allclose(res["sum"], total, atol=1e-12)
    # the air pushes the airway open: with pressure its sections are larger
    for motion, effect in f["pressure_effect_final"].items():
        assert effect["mean_area_change_percent"] > 0, motion
    assert all(is_png(p, 10_000) for p in f["png"])


def test_study_styloglossus_with_its_reduced_tongue(tmp_path):
    duration, tension, r, points = 0.04, 0.15, 4, 40
    assert (
        main(
            [
                "study",
                "styloglossus",
                "--duration",
                str(duration),
                "--tension",
                str(tension),
                "--r",
                str(r),
                "--points",
                str(points),
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    f = json.loads((tmp_path / "styloglossus.json").read_text())
    assert set(f["runs"]) == {
        "excitation 4",
        "excitation 24",
        "tension 4",
        "tension 24",
        "tension 24+",
        "reduced 4",
        "reduced 24",
        "reduced 24+",
    }
    assert f["reduced"]["pod_vectors"] == r and set(f["reduced"]["training"]) == {"4", "24", "24+"}
    for support, trained in f["reduced"]["training"].items():  # a model per support
        assert trained["runs"] == 2 and trained["basis"]["r"] == r, support
        assert 0 < trained["points"]["count"] <= points, support
    for name, run in f["runs"].items():
        assert run["steps"] == round(duration / 0.01) and run["dt"] == 0.01, name
        assert 0 < run["min_det_F"] <= 1.5 and finite_positive(run["ms_per_step"]), name
        for side, w in run["weights"].items():
            assert len(w) == run["support_nodes"], (name, side)
            assert sum(w) == pytest.approx(1.0, abs=1e-9), (name, side)  # partition of unity
            if run["nonnegative"]:
                assert min(w) >= 0, (name, side)
        if run["load"] == "tension":  # --tension T, applied as T e(t), e = t / 0.5 s
            ramped = tension * duration / 0.5
            assert run["tension_N"] == pytest.approx({"left": ramped, "right": ramped})
    for name in ("reduced 4", "reduced 24", "reduced 24+"):
        e = f["runs"][name]["error_vs_full"]
        assert 0 <= e["mean_node_mm"] <= e["max_node_mm"] < 1.0, name
    assert "| reduced 4 |" in (tmp_path / "styloglossus.md").read_text()
    assert all(is_png(tmp_path / p, 10_000) for p in f["png"].values())


# ---- simulate tongue: level 1, a schedule file --------------------------------------------


def test_simulate_tongue_level_1(tmp_path):
    assert (
        main(
            [
                "simulate",
                "tongue",
                "--level",
                "1",
                "--duration",
                "0.02",
                "--no-progress",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    f = json.loads((tmp_path / "protrusion" / "simulate.json").read_text())
    # every one of the 740 hexahedra split 2x2x2: 5,920 elements and 6,699 nodes
    assert (f["level"], f["nodes"], f["elements"], f["steps"]) == (1, 6699, 740 * 8, 2)
    assert finite_positive(f["ms_per_step"]) and 0 < f["min_det_F"] <= 1.5
    assert f["halvings"] == 0
    tip = f["landmarks"]["tip"]
    assert np.all(np.isfinite(tip)) and np.linalg.norm(tip) > 0  # the muscles act at once
    assert is_png(tmp_path / "protrusion" / "tongue.png", 10_000)


def test_simulate_tongue_schedule_file_runs_like_the_named_motion(tmp_path):
    """A schedule file written by hand as the paper's protrusion (GGP 0.4, TRANS 0.4, SL 0.1
    ramped over 0.5 s, then held): the same landmarks as ``--motion protrusion``."""
    path = tmp_path / "my_protrusion.json"
    path.write_text(
        json.dumps(
            {
                "times": [0.0, 0.5, 1.0],
                "excitations": {
                    "GGP": [0.0, 0.4, 0.4],
                    "TRANS": [0.0, 0.4, 0.4],
                    "SL": [0.0, 0.1, 0.1],
                },
            }
        )
    )
    common = ["--duration", "0.05", "--dt", "0.01", "--no-progress"]
    assert (
        main(["simulate", "tongue", "--schedule", str(path), "--out", str(tmp_path / "s"), *common])
        == 0
    )
    assert (
        main(["simulate", "tongue", "--case", "protrusion", "--out", str(tmp_path / "m"), *common])
        == 0
    )
    mine = json.loads((tmp_path / "s" / "my_protrusion" / "simulate.json").read_text())
    named = json.loads((tmp_path / "m" / "protrusion" / "simulate.json").read_text())
    assert (mine["motion"], mine["steps"], mine["nodes"]) == ("my_protrusion", 5, 946)
    assert 0 < mine["min_det_F"] <= 1.5 and mine["halvings"] == 0
    assert np.linalg.norm(mine["landmarks"]["tip"]) > 0.01
    for name in ("tip", "top", "base"):
        assert mine["landmarks"][name] == pytest.approx(named["landmarks"][name], abs=1e-3)
    assert is_png(tmp_path / "s" / "my_protrusion" / "tongue.png", 10_000)


# ---- bench: two ranks, scenes ----------------------------------------------------------

needs_mpiexec = pytest.mark.skipif(
    not MPIEXEC.exists(), reason=f"no mpiexec next to the interpreter ({MPIEXEC})"
)


@needs_mpiexec
def test_bench_fom_on_one_and_two_ranks(tmp_path):
    out = tmp_path / "fom.json"
    assert (
        main(
            [
                "bench",
                "fom",
                "--sizes",
                "6x3x3",
                "--ranks",
                "1,2",
                "--steps",
                "2",
                "--warmup",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    report = json.loads(out.read_text())
    assert "errors" not in report
    one, two = report["cases"]
    assert (one["ranks"], two["ranks"]) == (1, 2)
    for case in (one, two):
        assert (case["nodes"], case["elements"]) == (7 * 4 * 4, 6 * 3 * 3)
        assert case["steps"] == 2 and case["halvings"] == 0
        for field in ("ms_per_step", "assembly_ms", "solve_ms", "peak_mb"):
            assert finite_positive(case[field]), (case["ranks"], field)
    # the same box, the same steps: two ranks move the tip as one does (to the solver's
    # tolerance)
    a, b = np.array(one["tip_displacement_m"]), np.array(two["tip_displacement_m"])
    assert np.linalg.norm(a) > 1e-5
    assert np.linalg.norm(b - a) < 1e-4 * np.linalg.norm(a)


@needs_mpiexec
def test_bench_tongue_on_two_ranks(tmp_path):
    out = tmp_path / "tongue.json"
    assert (
        main(
            [
                "bench",
                "tongue",
                "--levels",
                "0",
                "--ranks",
                "1,2",
                "--steps",
                "2",
                "--warmup",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    report = json.loads(out.read_text())
    assert "errors" not in report and report["settings"]["ranks"] == [1, 2]
    assert report["settings"]["timed_window_s"] == [0.01, 0.03]
    one, two = report["cases"]
    assert (one["ranks"], two["ranks"]) == (1, 2)
    for case in (one, two):
        assert (case["level"], case["nodes"], case["elements"]) == (0, 946, 740)
        assert case["steps"] == 2 and case["halvings"] == 0
        assert finite_positive(case["ms_per_step"]) and finite_positive(case["peak_mb"])
    a, b = np.array(one["tip_displacement_m"]), np.array(two["tip_displacement_m"])
    assert np.linalg.norm(a) > 1e-6
    assert np.linalg.norm(b - a) < 1e-4 * np.linalg.norm(a)


def test_bench_scenes_quick(tmp_path, quick_jaw_tongue):
    from artifem import bench_scenes
    from artifem.models.masseter.model import MODELS

    out = tmp_path / "scenes.json"
    assert (
        main(
            [
                "bench",
                "scenes",
                "--quick",
                "--cache",
                str(quick_jaw_tongue.cache),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    report = json.loads(out.read_text())
    assert report["benchmark"] == "scenes" and "errors" not in report
    assert report["settings"]["quick"] is True
    scenes = report["scenes"]
    assert set(scenes) == set(bench_scenes.SCENES)
    steps = bench_scenes.QUICK_STEPS
    for name, s in scenes.items():
        assert s["steps"] == steps and finite_positive(s["seconds"]), name
    r = quick_jaw_tongue.config.r
    jt = scenes["jaw-tongue"]
    assert jt["reduced"]["pod_vectors"] == r
    full, red = jt["cases"]["full"], jt["cases"]["reduced"]
    assert finite_positive(full["ms_per_step"]) and finite_positive(red["ms_per_step"])
    assert jt["cases"]["speedup"] == pytest.approx(full["ms_per_step"] / red["ms_per_step"])
    assert red["masters"] == r + 6 < full["masters"]  # q and the jaw's twist
    aw = scenes["airway"]
    for case in ("full", "reduced"):
        for key in (
            "ms_per_step_without_airway",
            "ms_per_step_with_skin_pressure",
            "ms_skin_positions",
            "ms_skin_jacobian",
            "ms_pressure_master_loads",
        ):
            assert finite_positive(aw["cases"][case][key]), (case, key)
    assert aw["cases"]["reduced"]["masters"] == r + 6
    ms = scenes["masseter"]
    assert set(ms["cases"]) == {f"{p}/{a}" for p, a in MODELS}
    assert all(finite_positive(c["ms_per_step"]) for c in ms["cases"].values())
    foot = scenes["foot"]
    assert set(foot["cases"]) == {
        "fem_alone",
        "with_bones",
        "with_bones_and_contact",
        "reduced",
        "reduced_trained",
    }
    assert all(finite_positive(c["ms_per_step"]) for c in foot["cases"].values())
    assert foot["reduced"]["reduced"] == {
        "pod_vectors": 6,
        "lift_columns": 132,
        "points": 100,
        "sampling": "random",
    }
    trained = foot["reduced"]["reduced_trained"]
    assert trained["sampling"] == "trained" and trained["points"] <= 100


# ---- demo ------------------------------------------------------------------------------


def test_demo_quick(tmp_path, capsys, quick_tongue_study):
    """``artifem demo --quick`` as run a second time: the study's training already in
    OUT/study/cache (copied from the session's quick study, the same configuration), which
    the demo reuses as documented; the rest (the study's runs and report, the beam, the
    tongue's motions) runs."""
    from artifem import demo
    from artifem.models import muscle_beam
    from artifem.models.tongue.model import MOTIONS

    shutil.copytree(quick_tongue_study / "cache", tmp_path / "study" / "cache")
    assert main(["demo", "--quick", "--out", str(tmp_path)]) == 0
    said = capsys.readouterr().out.strip().splitlines()[-1]
    assert said.startswith("demo: ") and f"{tmp_path}/study/report.md" in said
    study = json.loads((tmp_path / "study" / "study.json").read_text())
    assert study["runs"] and not any(r["failed"] for r in study["runs"])
    assert "Table 2" in (tmp_path / "study" / "report.md").read_text()
    beam = json.loads((tmp_path / "muscle_beam" / "curl" / "simulate.json").read_text())
    nx, ny, nz = muscle_beam.LEVELS[int(demo.QUICK_BEAM[1])]
    assert beam["nodes"] == (nx + 1) * (ny + 1) * (nz + 1) and beam["steps"] == 10  # 0.2 / 0.02
    assert np.linalg.norm(beam["tip_displacement_mm"]["t=0.2"]) > 0.1
    for motion in MOTIONS:
        f = json.loads((tmp_path / "tongue" / motion / "simulate.json").read_text())
        assert f["steps"] == 10 and 0 < f["min_det_F"] <= 1.5, motion  # 0.1 s / 0.01 s
        assert np.linalg.norm(f["landmarks"]["tip"]) > 0.01, motion
    for png in ("muscle_beam/curl/beam.png", "tongue/cases.png", "study/speed_vs_error.png"):
        assert is_png(tmp_path / png, 10_000), png
