"""``artifem bench fom|tongue``: JSON schema on the smallest cases (not timing tests)."""

import json
import math

import numpy as np
import pytest

from artifem import bench
from artifem.cli import main


def assert_tip(tip, pinned):
    """The tip displacement (m) is the measured one to 1e-6 of its length (the runs are
    deterministic on this machine; the tolerance allows the solvers' round-off elsewhere)."""
    np.testing.assert_allclose(tip, pinned, rtol=0, atol=1e-6 * np.linalg.norm(pinned))


def test_bench_fom_smallest_case_writes_sound_json(tmp_path):
    """The 1k box, 2 warm-up and 2 timed steps of cg-gamg-lagged: the muscle and gravity
    move the tip by (-7.35, 1.27, -2.04) mm (measured, twice alike). docs/benchmarks/fom.json's
    1k case (10 timed steps) is no reference: a run of its settings today differs from it by
    0.7 to 4 % per component (the JSON was written on 2026-11-21, before later changes)."""
    out = tmp_path / "sub" / "bench_fom.json"
    code = main(
        ["bench", "fom", "--out", str(out), "--sizes", "1k", "--ranks", "1", "--steps", "2"]
    )
    assert code == 0
    report = json.loads(out.read_text())
    assert "errors" not in report
    assert len(report["cases"]) == 1
    case = report["cases"][0]
    for field in bench.CASE_FIELDS:
        assert field in case, field
    nx, ny, nz = bench.SIZES["1k"]
    assert case["nodes"] == (nx + 1) * (ny + 1) * (nz + 1)
    assert case["elements"] == nx * ny * nz
    assert case["ranks"] == 1
    assert case["solver"] == bench.DEFAULT_SOLVER
    assert case["steps"] == 2
    for field in ("ms_per_step", "assembly_ms", "solve_ms", "peak_mb"):
        value = case[field]
        assert isinstance(value, float) and math.isfinite(value) and value > 0, (field, value)
    assert case["assembly_ms"] + case["solve_ms"] <= case["ms_per_step"] * 1.05
    assert case["iterations"] >= 1
    assert case["halvings"] == 0
    # the muscle and gravity make the step do real work
    assert_tip(case["tip_displacement_m"], [-7.351426722e-3, 1.2684439588e-3, -2.0422086510e-3])


def test_bench_fom_rejects_bad_arguments(tmp_path, capsys):
    out = tmp_path / "b.json"
    assert main(["bench", "fom", "--out", str(out), "--sizes", "2x3"]) == 2
    assert main(["bench", "fom", "--out", str(out), "--solver", "lu"]) == 2
    assert not out.exists()
    assert "--solver" in capsys.readouterr().err


def test_bench_tongue_level0_writes_sound_json(tmp_path):
    """Level 0, protrusion, 5 warm-up and 2 timed steps with the hard formulation and MUMPS:
    the tip has moved (-0.798, 0.000, 0.709) mm (measured, twice alike). No committed figure
    has these settings: docs/benchmarks/tongue.json's level-0 case is the penalty
    formulation with cg-gamg over 20 steps."""
    out = tmp_path / "bench_tongue.json"
    code = main(
        ["bench", "tongue", "--out", str(out), "--levels", "0", "--ranks", "1", "--steps", "2"]
    )
    assert code == 0
    report = json.loads(out.read_text())
    assert report["benchmark"] == "tongue"
    assert "errors" not in report
    assert report["reference"] == {
        "seed_paper_ms_per_step": 188.9,
        "seed_paper_nodes": 2961,
        "machine": "quad-core i7-7700, Pardiso",
    }
    settings = report["settings"]
    assert settings["motion"] == "protrusion" and settings["dt"] == 0.01
    assert settings["warmup_steps"] == bench.TONGUE_WARMUP
    assert settings["timed_window_s"] == [0.05, 0.07]
    assert len(report["cases"]) == 1
    case = report["cases"][0]
    for field in bench.CASE_FIELDS + ("level", "loadavg_before", "loadavg_after"):
        assert field in case, field
    assert (case["level"], case["nodes"], case["elements"]) == (0, 946, 740)
    assert case["ranks"] == 1 and case["steps"] == 2
    # the tongue's default formulation with its own solver
    assert case["incompressibility"] == "hard" and case["solver"] == "mumps"
    assert settings["incompressibility"] == ["hard"] and settings["solvers"] == ["mumps"]
    assert case["timed_window_s"] == [0.05, 0.07]
    for field in ("ms_per_step", "assembly_ms", "solve_ms", "peak_mb"):
        value = case[field]
        assert isinstance(value, float) and math.isfinite(value) and value > 0, (field, value)
    assert case["iterations"] >= 1
    assert case["halvings"] == 0
    # the protrusion motion is under way: the tip has moved
    assert_tip(case["tip_displacement_m"], [-7.978711134e-4, 2.9404221e-9, 7.090426041e-4])


def test_bench_tongue_rejects_bad_arguments(tmp_path, capsys):
    out = tmp_path / "t.json"
    assert main(["bench", "tongue", "--out", str(out), "--levels", "2"]) == 2
    assert main(["bench", "tongue", "--out", str(out), "--motion", "swallow"]) == 2
    assert not out.exists()
    err = capsys.readouterr().err
    assert "--levels" in err and "--motion" in err


def test_format_table_leading_columns():
    case = {
        "level": 1,
        "nodes": 6699,
        "ranks": 2,
        "solver": "mumps",
        "ms_per_step": 1.0,
        "assembly_ms": 0.5,
        "solve_ms": 0.4,
        "iterations": 1.0,
        "peak_mb": 100.0,
    }
    head, _, row = bench.format_table([case], lead=("level",)).splitlines()
    assert head.split()[:2] == ["level", "nodes"]
    assert row.split()[:4] == ["1", "6699", "2", "mumps"]


def test_parse_sizes():
    assert bench.parse_sizes("1k,5x4x3") == [("1k", (15, 7, 7)), ("5x4x3", (5, 4, 3))]
    with pytest.raises(ValueError):
        bench.parse_sizes("0x1x1")


def test_the_targets_hold_at_their_bounds_and_are_printed(tmp_path, monkeypatch, capsys):
    """bench fom's targets, those of docs/benchmarks.md (on 2 cores, at most 100 ms per step
    at 3,000 nodes and 650 ms at 13,000): a two-rank case at its target meets it, one above
    misses it, a one-rank or a 1k case has none; each is written and printed. The cases
    are made up (``run_cases`` replaced): this checks the bookkeeping, not a machine."""
    ms = {("1k", 1): 1e3, ("1k", 2): 1e3, ("3k", 1): 1e3, ("3k", 2): 100.5, ("13k", 1): 1e3}
    ms[("13k", 2)] = 650.0

    def made_up(title, plan, steps, warmup, timeout, mpiexec):
        cases = []
        for item in plan:
            key = (item["fields"]["size"], item["ranks"])
            fields = dict.fromkeys(bench.CASE_FIELDS, 1.0)
            cases.append(
                {
                    **fields,
                    **item["fields"],
                    "ranks": item["ranks"],
                    "solver": item["solver"],
                    "ms_per_step": ms[key],
                }
            )
        return cases, []

    monkeypatch.setattr(bench, "run_cases", made_up)
    out = tmp_path / "fom.json"
    assert main(["bench", "fom", "--out", str(out), "--sizes", "1k,3k,13k", "--ranks", "1,2"]) == 0
    targets = json.loads(out.read_text())["targets"]
    assert [(t["size"], t["ranks"], t["target_ms_per_step"], t["met"]) for t in targets] == [
        ("3k", 2, 100.0, False),
        ("13k", 2, 650.0, True),
    ]
    printed = capsys.readouterr().out
    assert f"target 3k on 2 ranks ({bench.DEFAULT_SOLVER}): 100.5 ms <= 100 ms: NOT met" in printed
    assert f"target 13k on 2 ranks ({bench.DEFAULT_SOLVER}): 650.0 ms <= 650 ms: met" in printed


def test_machine_info_without_proc_cpuinfo_names_the_platform(monkeypatch):
    """Where /proc/cpuinfo cannot be read (macOS, a container without /proc), the report
    names the CPU as the platform module does instead of failing."""
    import platform
    from pathlib import Path

    real = Path.read_text

    def no_proc(self, *args, **kwargs):
        if str(self) == "/proc/cpuinfo":
            raise FileNotFoundError(self)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "read_text", no_proc)
    info = bench.machine_info()
    assert info["cpu"] == (platform.processor() or platform.machine())
    assert info["cores"] >= 1


def test_the_worker_alone_runs_the_level0_tongue_without_warm_up(capsys):
    """``python -m artifem.bench_worker --scene tongue`` without --level is the level-0
    tongue (946 nodes); with no warm-up its one step is the timed one."""
    from artifem import bench_worker

    argv = ["--scene", "tongue", "--solver", bench.DEFAULT_SOLVER, "--steps", "1", "--warmup", "0"]
    assert bench_worker.main(argv) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("BENCH_RESULT "))
    result = json.loads(line.removeprefix("BENCH_RESULT "))
    assert result["nodes"] == 946 and result["scene"] == "tongue"
    assert (result["steps"], result["warmup_steps"]) == (1, 0)
    assert len(result["iterations_per_step"]) == 1


def test_bench_scenes_keeps_the_other_scenes_when_one_fails(tmp_path, monkeypatch):
    """A scene whose benchmark raises is recorded under ``errors`` with its exception; the
    scenes after it still run and are written; the command exits 1. (Two stand-in scene
    modules: the real ones run in tests/test_cli_end_to_end.py.)"""
    import sys
    import types

    from artifem import bench_scenes

    def failing(steps=None):
        raise RuntimeError("the mesh is gone")

    modules = {
        "scene_a": types.SimpleNamespace(benchmark=failing),
        "scene_b": types.SimpleNamespace(benchmark=lambda steps=None: {"cases": {"full": steps}}),
    }
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, f"stand_in_{name}", module)
    monkeypatch.setattr(bench_scenes, "SCENES", {n: f"stand_in_{n}" for n in modules})
    out = tmp_path / "scenes.json"
    code = main(
        ["bench", "scenes", "--scenes", "scene_a,scene_b", "--steps", "3", "--out", str(out)]
    )
    assert code == 1
    report = json.loads(out.read_text())
    assert report["errors"] == [{"scene": "scene_a", "error": "RuntimeError: the mesh is gone"}]
    assert list(report["scenes"]) == ["scene_b"]
    assert report["scenes"]["scene_b"]["cases"] == {"full": 3}
    assert report["scenes"]["scene_b"]["seconds"] >= 0
