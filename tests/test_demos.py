"""Every demo script (demos/*.py, found by glob) runs to the end in its quick mode
(ARTIFEM_QUICK=1: a few steps) and writes what it says it writes: each picture decodes and
shows something, each VTX series holds every step of the run and, at its last, what the
demo printed (or the measured values), and the inflated sphere's JSON is its closed form's."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from outputs import assert_picture, read_series

ROOT = Path(__file__).resolve().parents[1]
DEMOS = ROOT / "demos"

#: files a demo must write (besides anything else it writes)
OUTPUTS = {
    "material_prototyping.py": ["yeoh.png", "tongue_mooney_rivlin.png"],
    "tongue_gravity.py": ["tongue_gravity.png", "tongue.bp"],
    "bone_hinge_muscle.py": ["bone_hinge_muscle.png", "tissue.bp"],
    "reduced_body_in_joints.py": ["reduced_beam.png", "beam_modes.bp"],
    "skin_pressure.py": ["skin_pressure.png", "block.bp"],
    "static_pressure.py": ["static_pressure.png"],
    "inflated_sphere.py": ["pressure_stretch.png", "inflated_sphere.png", "inflated_sphere.json"],
    "contact_pad_on_bone.py": [
        "contact_pad_on_bone.png",
        "contact_pressure.png",
        "pad.bp",
        "pad_contact_pressure.bp",
    ],
}


def test_every_demo_is_listed():
    assert sorted(p.name for p in DEMOS.glob("*.py")) == sorted(OUTPUTS)


@pytest.mark.parametrize("script", sorted(p.name for p in DEMOS.glob("*.py")))
def test_demo_runs(script, tmp_path):
    env = {**os.environ, "ARTIFEM_QUICK": "1"}
    run = subprocess.run(
        [sys.executable, str(DEMOS / script), str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    for name in OUTPUTS[script]:
        assert (tmp_path / name).exists(), f"{script} did not write {name}"
        if name.endswith(".png"):
            assert_picture(tmp_path / name)
    for name, (duration, dt) in SERIES.get(script, {}).items():
        # one write at t = 0 and one after every step (af.simulate, write_every=1)
        times = read_series(tmp_path / name).times
        np.testing.assert_allclose(times, dt * np.arange(round(duration / dt) + 1), atol=1e-15)
    CHECKS.get(script, lambda out, stdout: None)(tmp_path, run.stdout)


#: the series each demo writes: (its quick duration, its step), from the demo's source
SERIES = {
    "tongue_gravity.py": {"tongue.bp": (0.05, 0.01)},
    "bone_hinge_muscle.py": {"tissue.bp": (0.05, 0.005)},
    "reduced_body_in_joints.py": {"beam_modes.bp": (0.05, 0.005)},
    "skin_pressure.py": {"block.bp": (0.02, 0.005)},
    "contact_pad_on_bone.py": {"pad.bp": (0.03, 0.005), "pad_contact_pressure.bp": (0.03, 0.005)},
}

#: the largest nodal displacement at the last step, measured (two runs, same digits), and
#: the relative tolerance: 1e-6 where the runs are the same on every machine measured; the
#: pad's contact rows make it turn on round-off: 0.0049365019 on one machine, 0.0049365232 on
#: another (AMD EPYC, OpenBLAS Haswell/Zen kernels; 4.3e-6 apart), so 1e-4 there
MEASURED_MAX_U_M = {
    "tissue.bp": (0.01378963853086978, 1e-6),
    "beam_modes.bp": (0.03310692837482838, 1e-6),
    "block.bp": (0.0027249293302724614, 1e-6),
    "pad.bp": (0.004936501880568165, 1e-4),
}


def last_displacement(path):
    """The reference coordinates and the last step's displacements of a written series,
    whose largest component is checked against MEASURED_MAX_U_M (where it is listed)."""
    series = read_series(path)
    u = series.at("displacement")
    if path.name in MEASURED_MAX_U_M:
        measured, rel = MEASURED_MAX_U_M[path.name]
        assert np.abs(u).max() == pytest.approx(measured, rel=rel)
    return series.at("geometry", 0), u


def printed(pattern, stdout):
    match = re.search(pattern, stdout)
    assert match, (pattern, stdout)
    return match.group(1)


def check_tongue_gravity(out, stdout):
    """The written tip (ArtiSynth's node 920) is the tip the demo printed (numpy's 8
    digits), and exactly the 115 jaw and hyoid attachment nodes are still at rest."""
    X, u = last_displacement(out / "tongue.bp")
    data = ROOT / "models" / "data" / "artisynth-tongue"
    nodes = np.loadtxt(data / "tongue.node")
    tip = np.argmin(np.linalg.norm(X - nodes[nodes[:, 0] == 920, 1:], axis=1))
    tip_mm = np.array(printed(r"tip moved \[([^\]]*)\] mm", stdout).split(), dtype=float)
    np.testing.assert_allclose(1e3 * u[tip], tip_mm, rtol=1e-7)
    attached = np.unique(
        np.concatenate(
            [np.loadtxt(data / f"{b}Attachments.txt", dtype=int) for b in ("jaw", "hyoid")]
        )
    )
    assert np.count_nonzero(np.all(u == 0.0, axis=1)) == attached.size == 115


def check_bone_hinge_muscle(out, stdout):
    """The tissue's top nodes ride on the bone: the angle they turned about the hinge's y
    axis is the hinge angle the demo printed (to its one decimal; the attachment's
    Baumgarte error is 2e-5 deg here, measured)."""
    X, u = last_displacement(out / "tissue.bp")
    x = (X + u)[np.abs(X[:, 2]) < 1e-9]
    turned = np.degrees(np.arctan2(-x[:, 2], x[:, 0]))
    assert np.abs(turned - float(printed(r"hinge angle (\S+) deg", stdout))).max() <= 0.05


def check_reduced_body_in_joints(out, stdout):
    """The written beam tip's z is the tip the demo printed (one decimal, mm), and the
    clamped end (3 x 3 nodes, where every mode is zero) has not moved."""
    X, u = last_displacement(out / "beam_modes.bp")
    tip = np.argmin(np.linalg.norm(X - [1.0, 0.05, 0.05], axis=1))
    assert abs(1e3 * u[tip, 2] - float(printed(r"tip (\S+) mm", stdout))) <= 0.05
    assert np.all(u[X[:, 0] < 1e-12] == 0.0) and np.count_nonzero(X[:, 0] < 1e-12) == 9


def check_skin_pressure(out, stdout):
    last_displacement(out / "block.bp")


def check_contact_pad_on_bone(out, stdout):
    """The written contact pressure is the one the demo printed: its peak (to the printed
    Pa) on as many nodes."""
    last_displacement(out / "pad.bp")
    p = read_series(out / "pad_contact_pressure.bp").at("contact_pressure")
    peak, nodes = printed(r"peak pressure (\d+ Pa on \d+) nodes", stdout).split(" Pa on ")
    assert abs(p.max() - float(peak)) <= 0.5 and np.count_nonzero(p) == int(nodes)


#: the quick sphere's inner hoop stretch at p = 0.347 mu and 0.694 mu, measured (two runs,
#: same digits; static Newton to 1e-10): 5.3 % and 6.2 % of la - 1 under the closed form
MEASURED_LA_FEM = [1.1202436199669672, 1.3691834602922188]


def check_inflated_sphere(out, stdout):
    """The JSON's closed form is the docstring's, solved here on its own (scipy's brentq
    and a bounded maximum): the limit pressure, each level's exact stretch and the error
    of the FEM stretch; the FEM stretches are the measured ones."""
    from scipy.optimize import brentq, minimize_scalar

    figures = json.loads((out / "inflated_sphere.json").read_text())
    a, b, mu = figures["A"], figures["B"], figures["mu"]

    def pressure(la):
        lb = (1.0 + (la**3 - 1.0) * (a / b) ** 3) ** (1.0 / 3.0)
        return 2 * mu * (1 / lb - 1 / la) + 0.5 * mu * (lb**-4 - la**-4)

    peak = minimize_scalar(lambda la: -pressure(la), bounds=(1.0, 3.0), options={"xatol": 1e-10})
    assert figures["p_max_over_mu"] == pytest.approx(pressure(peak.x) / mu, rel=1e-9)
    levels = figures["levels"]
    assert [r["p_over_mu"] for r in levels] == pytest.approx(
        np.linspace(0.0, 0.85 * pressure(peak.x) / mu, 3)[1:], rel=1e-9
    )
    for r, la_fem in zip(levels, MEASURED_LA_FEM, strict=True):
        exact = brentq(lambda s: pressure(s) - r["p_over_mu"] * mu, 1.0, peak.x, xtol=1e-14)
        assert r["la_exact"] == pytest.approx(exact, rel=1e-9)
        assert r["la_fem"] == pytest.approx(la_fem, rel=1e-6)
        assert r["error_la_minus_1"] == pytest.approx((r["la_fem"] - exact) / (exact - 1), rel=1e-7)


CHECKS = {
    "tongue_gravity.py": check_tongue_gravity,
    "bone_hinge_muscle.py": check_bone_hinge_muscle,
    "reduced_body_in_joints.py": check_reduced_body_in_joints,
    "skin_pressure.py": check_skin_pressure,
    "contact_pad_on_bone.py": check_contact_pad_on_bone,
    "inflated_sphere.py": check_inflated_sphere,
}
