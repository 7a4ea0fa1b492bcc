"""``artifem bench fom``: JSON schema on the smallest case (not a timing test)."""

import json
import math

import pytest

from artifem import bench
from artifem.cli import main


def test_bench_fom_smallest_case_writes_sound_json(tmp_path):
    out = tmp_path / "sub" / "bench_fom.json"
    code = main(["bench", "fom", "--out", str(out), "--sizes", "1k", "--ranks", "1",
                 "--steps", "2"])
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
    assert math.hypot(*case["tip_displacement_m"]) > 1e-4


def test_bench_fom_rejects_bad_arguments(tmp_path, capsys):
    out = tmp_path / "b.json"
    assert main(["bench", "fom", "--out", str(out), "--sizes", "2x3"]) == 2
    assert main(["bench", "fom", "--out", str(out), "--solver", "lu"]) == 2
    assert not out.exists()
    assert "--solver" in capsys.readouterr().err


def test_parse_sizes():
    assert bench.parse_sizes("1k,5x4x3") == [("1k", (15, 7, 7)), ("5x4x3", (5, 4, 3))]
    with pytest.raises(ValueError):
        bench.parse_sizes("0x1x1")
