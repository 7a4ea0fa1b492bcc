"""The command line, the set-up script and the demo scene, run as a user would."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from artifem.cli import main
from artifem.excitation import ExcitationSchedule
from outputs import assert_picture, read_series

ROOT = Path(__file__).resolve().parents[1]


def test_help_lists_every_command(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for word in ("mesh", "material", "simulate", "bench", "demo"):
        assert word in out


def test_console_script_runs():
    exe = Path(sys.executable).parent / "artifem"
    if not exe.exists():
        pytest.skip("artifem console script not installed in this environment")
    out = subprocess.run([str(exe), "mesh", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "info" in out.stdout


def test_simulate_beam_writes_results(tmp_path):
    """A short, coarse run of the demo scene: the figures are the measured ones, the series
    holds every step and ends at the tip the figures report, and the pictures show it."""
    from artifem.models.muscle_beam import HEIGHT, LENGTH, WIDTH

    out = tmp_path / "beam"
    status = main(
        [
            "simulate",
            "beam",
            "--out",
            str(out),
            "--level",
            "0",
            "--duration",
            "0.2",
            "--dt",
            "0.02",
            "--no-progress",
        ]
    )
    assert status == 0
    out = out / "curl"  # the beam's one case
    figures = json.loads((out / "simulate.json").read_text())
    assert figures["nodes"] == 9 * 3 * 3 and figures["elements"] == 32  # level 0: 8 x 2 x 2
    assert figures["steps"] == 10
    # deterministic, measured (two runs, same digits); rel 1e-6 allows another machine of
    # the same kind. The tip's y is round-off about the beam's symmetry plane (1e-8 mm).
    assert figures["min_det_F"] == pytest.approx(0.751658202697456, rel=1e-6)
    tip = figures["tip_displacement_mm"]["t=0.2"]
    assert tip == pytest.approx([-11.832920467857855, 0.0, -9.37993688637585], rel=1e-6, abs=1e-6)
    series = read_series(out / "beam.bp")
    np.testing.assert_allclose(series.times, 0.02 * np.arange(11), atol=1e-15)  # t = 0 and 10 steps
    X, u = series.at("geometry", 0), series.at("displacement")
    end = np.argmin(np.linalg.norm(X - [LENGTH, 0.5 * WIDTH, 0.5 * HEIGHT], axis=1))
    np.testing.assert_allclose(1e3 * u[end], tip, rtol=1e-12)  # the recorded tip node
    assert np.all(u[np.abs(X[:, 0]) < 1e-12] == 0.0)  # the clamped end
    assert_picture(out / "beam.png")
    assert_picture(out / "tip.png")


def test_material_curves_command(tmp_path):
    """The command's picture shows the curves, and its JSON is the material's response:
    P11 at each tabulated state is the point response of the tongue's Mooney-Rivlin there
    (the lateral stretches the command solved for are its own; that their P22 is zero is
    what it solves)."""
    from artifem.forms import MooneyRivlin
    from artifem.material_response import point_response

    png = tmp_path / "tongue.png"
    assert main(["material", "curves", "tongue", "--out", str(png), "--json"]) == 0
    assert_picture(png)
    curves = json.loads(png.with_suffix(".json").read_text())
    uni = curves["uniaxial"]
    np.testing.assert_allclose(uni["stretch"], np.linspace(1 / 1.5, 1.5, 41), rtol=1e-15)
    for k in (0, 20, 40):
        F = np.diag([uni["stretch"][k], uni["lateral_stretch_2"][k], uni["lateral_stretch_3"][k]])
        P = point_response(MooneyRivlin.tongue(), F)[1]
        assert uni["P11"][k] == pytest.approx(P[0, 0], rel=1e-12, abs=1e-9)
    assert np.all(np.diff(uni["P11"]) > 0)  # a tensile stress that grows with stretch


def test_material_curves_of_st_venant_kirchhoff_end_where_it_has_no_state(tmp_path, capsys):
    """``material curves svk`` (E = 3 kPa, nu = 0.45): St Venant-Kirchhoff's traction-free
    lateral stretches have closed forms, t^2 = 1 - nu (l^2 - 1) (uniaxial) and
    t3^2 = 1 - 2 nu / (1 - nu) (l^2 - 1) (equibiaxial), so the equibiaxial state exists only
    up to l = 1.269: the curve ends there (null in the JSON, said on stdout) instead of the
    command failing; the rest is the closed form to round-off."""
    png = tmp_path / "svk.png"
    assert main(["material", "curves", "svk", "--out", str(png), "--json"]) == 0
    assert "no traction-free equibiaxial state at 12 of the 41 stretches" in capsys.readouterr().out
    assert_picture(png)
    curves = json.loads(png.with_suffix(".json").read_text())
    nu = 0.45
    uni, bi = curves["uniaxial"], curves["equibiaxial"]
    l = np.array(uni["stretch"])
    np.testing.assert_allclose(uni["lateral_stretch_2"], np.sqrt(1 - nu * (l**2 - 1)), rtol=1e-12)
    exists = 1 - 2 * nu / (1 - nu) * (l**2 - 1) > 0
    assert exists.sum() == 29 and l[exists].max() == pytest.approx(1.25)
    t3 = np.array([np.nan if x is None else x for x in bi["lateral_stretch_3"]], dtype=float)
    np.testing.assert_allclose(
        t3[exists], np.sqrt(1 - 2 * nu / (1 - nu) * (l[exists] ** 2 - 1)), rtol=1e-12
    )
    assert np.all(np.isnan(t3[~exists])) and all(
        bi["P11"][k] is None for k in np.flatnonzero(~exists)
    )


def test_excitation_schedule_ramp_hold_and_file(tmp_path):
    s = ExcitationSchedule.ramp_and_hold({"GGP": 0.4, "TRANS": 0.4}, 0.5)
    assert s.at(0.25) == pytest.approx({"GGP": 0.2, "TRANS": 0.2})
    assert s.at(0.9) == pytest.approx({"GGP": 0.4, "TRANS": 0.4})
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"times": [0, 1], "excitations": {"A": [0, 1]}}))
    assert ExcitationSchedule.from_file(path).at(0.3)["A"] == pytest.approx(0.3)
    path.write_text(json.dumps({"times": [0, 1], "excitations": {"A": [0, 2]}}))
    with pytest.raises(ValueError, match="'A'.*\\[0, 1\\]"):
        ExcitationSchedule.from_file(path)
    with pytest.raises(FileNotFoundError, match="missing.json"):
        ExcitationSchedule.from_file(tmp_path / "missing.json")


def test_find_python_says_what_to_install(tmp_path):
    """With no Python >= 3.12 on PATH nor under pyenv, set-up stops with advice."""
    env = {"PATH": "/usr/bin:/bin", "PYENV_ROOT": str(tmp_path), "HOME": str(tmp_path)}
    fake_bin = tmp_path / "bin"
    fake_bin.mkdir()
    # Hide any system python >= 3.12 behind an old-version impostor.
    for name in ("python3.12", "python3.13", "python3", "python"):
        exe = fake_bin / name
        exe.write_text("#!/bin/sh\nexit 1\n")
        exe.chmod(0o755)
    env["PATH"] = f"{fake_bin}:/bin"
    out = subprocess.run(
        ["bash", str(ROOT / "scripts" / "find-python")], env=env, capture_output=True, text=True
    )
    assert out.returncode == 1
    assert "Python >= 3.12" in out.stderr and "pyenv install" in out.stderr


def test_find_python_finds_this_interpreter():
    out = subprocess.run(
        ["bash", str(ROOT / "scripts" / "find-python")],
        capture_output=True,
        text=True,
        env={**os.environ},
    )
    assert out.returncode == 0
    version = subprocess.run(
        [out.stdout.strip(), "-c", "import sys; print(sys.version_info[:2])"],
        capture_output=True,
        text=True,
    ).stdout
    assert eval(version) >= (3, 12)


def test_study_airway_takes_the_reduced_tongue_options(tmp_path):
    from artifem.cli import build_parser

    args = build_parser().parse_args(
        [
            "study",
            "airway",
            "--out",
            str(tmp_path),
            "--reduced",
            "--cache",
            str(tmp_path / "cache"),
        ]
    )
    assert args.reduced and args.cache == tmp_path / "cache"
    args = build_parser().parse_args(["study", "airway", "--out", str(tmp_path)])
    assert not args.reduced
