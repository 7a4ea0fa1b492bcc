"""Reading back what a run wrote, so that a test compares an output instead of only finding
it (issue 32): a VTX series through the ``adios2`` reader, a picture through matplotlib."""

import json
from pathlib import Path
from typing import NamedTuple

import pytest

import artifem  # noqa: F401  (must precede dolfinx)
import dolfinx  # noqa: F401  (before adios2: the other order fails to load DOLFINx's ADIOS2)
import numpy as np


class Series(NamedTuple):
    """A VTX series (``.bp``) as written by :class:`artifem.io.results.ResultWriter`."""

    path: Path
    times: np.ndarray  #: the time of each written step
    fields: frozenset  #: the functions' names

    def at(self, name: str, step: int = -1) -> np.ndarray:
        """The values of field ``name`` at ``step`` (negative: from the end), one row per
        node of the written mesh (its geometry order, not the function's dof order)."""
        import adios2

        step = step % len(self.times)
        with adios2.FileReader(str(self.path)) as f:
            return np.asarray(f.read(name, step_selection=[step, 1]))


def read_series(path) -> Series:
    """The times and field names of the VTX series at ``path``."""
    import adios2

    path = Path(path)
    assert path.is_dir(), f"no VTX series at {path}"
    with adios2.FileReader(str(path)) as f:
        names = set(f.available_variables())
        times = np.atleast_1d(np.asarray(f.read("step", step_selection=[0, f.num_steps()])))
    geometry = {"NumberOfEntities", "NumberOfNodes", "connectivity", "geometry", "step", "types"}
    fields = frozenset(n for n in names - geometry if not n.startswith("vtk"))
    return Series(path, times.ravel(), fields)


def same_rows(written: np.ndarray, values: np.ndarray, rtol: float = 1e-12) -> bool:
    """Whether the written nodal rows are ``values`` (n x d) up to the node order (the
    series holds the mesh's geometry order): their sorted row norms agree to ``rtol``."""
    a = np.sort(np.linalg.norm(np.reshape(written, (len(values), -1)), axis=1))
    b = np.sort(np.linalg.norm(np.reshape(values, (len(values), -1)), axis=1))
    return bool(np.allclose(a, b, rtol=rtol, atol=rtol * max(np.abs(b).max(), 1e-300)))


def assert_picture(path, min_pixels: int = 200) -> np.ndarray:
    """The PNG at ``path`` decodes, is at least ``min_pixels`` on each side and is not one
    flat colour (something was drawn); returns its RGB pixels."""
    import matplotlib.image

    path = Path(path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    rgb = matplotlib.image.imread(path)[..., :3]
    assert min(rgb.shape[:2]) >= min_pixels, f"{path}: {rgb.shape[1]} x {rgb.shape[0]} pixels"
    c = np.round(255 * rgb.reshape(-1, 3)).astype(np.int64)
    colours = np.unique((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).size
    assert colours > 16, f"{path}: {colours} colours, nothing drawn"
    return rgb


def study_report_rows(data: dict) -> list[str]:
    """The rows ``artifem study tongue``'s report.md must have for its study.json ``data``,
    formatted here: its Table 2 analog (trained points: each basis's ms per step by point
    count; one motion: the run's own) and its table of every run (volume changes in %)."""
    from artifem.models.tongue.report import BASIS_NAMES

    runs = data["runs"]
    trained = [r for r in runs if r["sampling"] == "trained"]
    counts = sorted({r["points"] for r in trained}, reverse=True)

    def ms(basis, r, points):
        return np.median(
            [
                x["ms_per_step"]
                for x in trained
                if (x["basis"], x["r"], x["points"]) == (basis, r, points)
            ]
        )

    table2 = [
        f"| {BASIS_NAMES[basis]} (r={r}) | "
        + " | ".join(f"{ms(basis, r, m):.2f}" for m in counts)
        + " |"
        for basis, r in sorted({(x["basis"], x["r"]) for x in trained})
    ]
    every = [
        f"| {r['basis']} | {r['r']} | {r['points']} | {r['sampling']} | {r['motion']} | "
        f"{r['ms_per_step']:.2f} | {r['speedup']:.1f} | {r['mean_error_mm']:.2f} | "
        f"{r['max_error_mm']:.2f} | {r['max_node_error_mm']:.2f} | "
        f"{100 * r['max_volume_change']:.3f} | {100 * r['full_max_volume_change']:.3f} | ok |"
        for r in runs
    ]
    return table2 + every


def landmark_rows(X) -> dict:
    """The rows of a written tongue series at the tongue's landmarks, found by their rest
    coordinates (the level-1 landmarks are the level-0 ones' material points,
    test_tongue_model)."""
    from artifem.models.tongue.model import load_tongue_data

    data = load_tongue_data(0)
    return {
        name: int(np.argmin(np.linalg.norm(X - data.mesh.points[row], axis=1)))
        for name, row in data.landmarks.items()
    }


def assert_tongue_series(out, f) -> None:
    """The two series ``simulate tongue`` wrote in ``out`` against its figures ``f``:
    t = 0 and every step; at the last, the landmarks it reports (rounded to 1e-3 mm) and
    the range of the element pressures."""
    times = f["dt"] * np.arange(f["steps"] + 1)
    series = read_series(out / "tongue.bp")
    np.testing.assert_allclose(series.times, times, atol=1e-15)
    X, u = series.at("geometry", 0), series.at("displacement")
    for name, node in landmark_rows(X).items():
        np.testing.assert_allclose(
            1e3 * u[node], f["landmarks"][name], rtol=0, atol=5e-4 + 1e-9, err_msg=name
        )
    pressure = read_series(out / "tongue_pressure.bp")
    np.testing.assert_allclose(pressure.times, times, atol=1e-15)
    p = pressure.at("pressure")
    assert [p.min(), p.max()] == pytest.approx(f["pressure_range_Pa"], rel=1e-12)


def assert_landmarks(f, measured) -> None:
    """The figures' landmarks (mm, rounded to 1e-3 by the command) are the measured ones,
    to one rounding unit."""
    assert set(f["landmarks"]) == set(measured)
    for name, mm in measured.items():
        np.testing.assert_allclose(f["landmarks"][name], mm, rtol=0, atol=1.5e-3, err_msg=name)


#: scripts/quick_splits.py's record of the quick train/test splits the suite re-derives
QUICK_SPLITS = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "quick_splits.json"


def quick_split(name: str) -> dict:
    """The committed quick split ``name`` ("tongue", "jaw-tongue"): its command (``argv``),
    its study's own figures (``runs``) and generalization.json's errors (``sets``), with
    the margin the suite allows (``margin``)."""
    doc = json.loads(QUICK_SPLITS.read_text())
    return {**doc["splits"][name], "margin": doc["margin"]}


def assert_split_as_committed(out, name: str) -> None:
    """generalization.json in ``out`` has the committed quick split's runs, set by set
    (training, motions, held-out), none failed, each run's largest and mean error at most
    the margin times the committed one and its estimate / error ratio within the margin
    either way of it: a change that breaks how the reduced model generalizes fails."""
    committed = quick_split(name)
    margin = committed["margin"]
    split = json.loads((Path(out) / "generalization.json").read_text())
    assert set(split["sets"]) == set(committed["sets"])
    for which, runs in split["sets"].items():
        assert {r["name"] for r in runs} == set(committed["sets"][which]), which
        for r in runs:
            c = committed["sets"][which][r["name"]]
            where = (which, r["name"], r, c)
            assert not r["failed"] and not r.get("full_failed"), where
            assert r["max_error_mm"] <= margin * c["max_error_mm"], where
            assert r["mean_error_mm"] <= margin * c["mean_error_mm"], where
            ratio = r["estimate_ratio"] / c["estimate_ratio"]
            assert 1 / margin <= ratio <= margin, where
