"""The public API a script uses without deep imports (``import artifem as af``) and
``af.simulate``: names, records, series, and its bad input."""

import numpy as np
import pytest

import artifem as af
from dolfinx import mesh as dmesh
from mpi4py import MPI
from outputs import read_series, same_rows

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")


def assert_the_series_is_the_run(path, run, body):
    """The VTX series ``simulate`` wrote for ``body``: one step per recorded time (from
    t = 0, which is the rest state) and, at the last, the body's final displacement."""
    series = read_series(path)
    np.testing.assert_array_equal(series.times, run.times)
    assert "displacement" in series.fields
    assert np.all(series.at("displacement", 0) == 0.0)
    assert same_rows(series.at("displacement"), body.u.x.array.reshape(-1, 3))


@pytest.mark.parametrize("package", ["artifem", "artifem.forms", "artifem.io", "artifem.reduction"])
def test_every_public_name_resolves_and_unknown_names_are_attribute_errors(package):
    """The surface the docs' API reference lists: each package's ``__all__``."""
    import importlib

    module = importlib.import_module(package)
    for name in module.__all__:
        assert getattr(module, name) is not None, name
        assert name in dir(module)
    with pytest.raises(AttributeError, match="no attribute 'Scen'"):
        _ = module.Scen
    assert af.Scene.__module__ == "artifem.scene.scene"


def test_a_user_scene_in_fifteen_lines(tmp_path):
    """A bone hinged to the world carries a soft block; simulate records the hinge angle
    and writes the block's series. Checked against the physics that is determined: the
    bone falls (gravity), the joint holds, the time grid is exact; the series holds every
    step and ends at the block's displacement; min det F is the measured one."""
    box = dmesh.create_box(
        MPI.COMM_SELF,
        [np.array([0.05, -0.02, -0.04]), np.array([0.25, 0.02, 0.0])],
        [4, 1, 1],
        dmesh.CellType.hexahedron,
    )
    block = af.FemBody(box, af.NeoHookean.from_young_poisson(5e4, 0.3), 1000.0, name="block")
    bone = af.RigidBody("bone", 0.3, 1e-3 * np.eye(3), position=(0.15, 0.0, 0.0))
    hinge = af.RevoluteJoint.at_world(bone, None, (0.0, 0.0, 0.0), af.axis_rotation((0, 1, 0)))
    scene = af.Scene(gravity=(0.0, 0.0, -9.81))
    scene.add(
        bone, block, hinge, af.NodeAttachment(block, block.find_nodes(lambda x: x[2] > -1e-9), bone)
    )
    run = af.simulate(
        scene,
        0.05,
        0.01,
        vtx=tmp_path,
        progress=False,
        record={"angle": lambda s: hinge.angle(), "com": lambda s: bone.position},
    )
    np.testing.assert_allclose(run.times, np.linspace(0.0, 0.05, 6), atol=1e-15)
    assert run.records["angle"].shape == (6,) and run.records["com"].shape == (6, 3)
    assert np.all(np.diff(run.records["com"][:, 2]) < 0)  # it falls
    # deterministic, measured: the hinge turned by 0.0833552 rad, the bone's centre at
    # (0.1495368, 0, -0.0124925) m; Baumgarte-stabilized, the joint error 5.76e-5 m
    # (O(h^2 |v|^2 / r)), asserted below 1.25 times that
    assert run.records["angle"][-1] == pytest.approx(0.08335520085, rel=1e-6)
    np.testing.assert_allclose(
        run.records["com"][-1], [0.1495367510, 0.0, -0.0124925449], rtol=0, atol=1e-6 * 0.15
    )
    assert max(scene.constraint_errors().values()) < 1.25 * 5.76e-5
    assert run.step_ms.shape == (5,)  # one wall time per step
    # deterministic: measured 0.9979234882491348 (two runs, same digits); rel 1e-6 allows
    # another BLAS or machine of the same kind
    assert run.halvings == 0 and run.min_det_F == pytest.approx(0.9979234882491348, rel=1e-6)
    assert_the_series_is_the_run(tmp_path / "block.bp", run, block)


def test_simulate_holds_numpy_blas_to_one_thread_while_it_runs():
    """A run's small dense algebra on one BLAS thread (artifem.scene.run), the caller's
    setting back afterwards, also when the run raises."""
    from threadpoolctl import ThreadpoolController, threadpool_limits

    def threads(s=None) -> float:
        return float(
            sum(
                i["num_threads"]
                for i in ThreadpoolController().info()
                if i["filepath"] == numpy_blas
            )
        )

    numpy_blas = next(
        i["filepath"] for i in ThreadpoolController().info() if "numpy" in i["filepath"]
    )
    bone = af.RigidBody("bone", 0.3, 1e-3 * np.eye(3))
    scene = af.Scene()
    scene.add(bone)
    with threadpool_limits(limits=2, user_api="blas"):
        before = threads()
        run = af.simulate(scene, 0.03, 0.01, progress=False, record={"threads": threads})
        assert np.all(run.records["threads"][1:] == 1.0) and threads() == before == 2.0

        def stop(s, t0, t1):
            raise RuntimeError("a controller that fails")

        scene.add_controller(stop)
        with pytest.raises(RuntimeError, match="fails"):
            af.simulate(scene, 0.03, 0.01, progress=False)
        assert threads() == 2.0


def test_simulate_leaves_its_finished_progress_bar_on_screen(capsys):
    """``progress=True`` draws a bar labelled ``label`` on stderr; by default the finished bar
    stays (its last state, 3/3 steps, on a line of its own), and ``leave=False`` erases it."""
    scene = af.Scene()
    scene.add(af.RigidBody("bone", 0.3, 1e-3 * np.eye(3)))
    af.simulate(scene, 0.03, 0.01, label="fall")
    err = capsys.readouterr().err
    assert err.endswith("\n") and "fall: 100%" in err.split("\r")[-1] and "3/3" in err
    af.simulate(scene, 0.03, 0.01, label="fall", leave=False)
    assert "fall: 100%" not in capsys.readouterr().err.split("\r")[-1]


def test_simulate_bad_input_is_a_clear_error():
    scene = af.Scene()
    for duration, dt in ((0.0, 0.01), (1.0, -0.01), (np.nan, 0.01)):
        with pytest.raises(af.InputError, match="duration and dt must be finite and > 0"):
            af.simulate(scene, duration, dt)
    with pytest.raises(af.InputError, match="record\\['x'\\] must be a callable"):
        af.simulate(scene, 0.1, 0.01, record={"x": 3})
    with pytest.raises(af.InputError, match="write_every"):
        af.simulate(scene, 0.1, 0.01, write_every=0)


def test_the_readme_scene_example_runs(tmp_path):
    """The README's Scene example, as printed (a shorter run, output in tmp_path); the
    tissue's series holds every step and ends at its displacement."""
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    section = readme[readme.index("## A first scene") :]
    code = section[section.index("```python") + len("```python") :]
    code = code[: code.index("```")]
    assert "af.simulate(scene, 0.6, 0.005" in code and 'vtx="out/"' in code
    code = code.replace("af.simulate(scene, 0.6, 0.005", "af.simulate(scene, 0.02, 0.005")
    code = code.replace('vtx="out/"', f"vtx={str(tmp_path)!r}, progress=False")
    namespace = {}
    exec(compile(code, "README.md", "exec"), namespace)
    assert namespace["run"].records["angle"].shape == (5,)
    assert_the_series_is_the_run(tmp_path / "tissue.bp", namespace["run"], namespace["tissue"])


def test_the_python_api_pages_fem_scene_example_runs(tmp_path, monkeypatch):
    """docs/python_api.md's one-body scene (the tongue, stepped on its own), as printed,
    shorter; the tongue's series holds every step and ends at its displacement."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    section = (root / "docs" / "python_api.md").read_text()
    code = section[section.index("```python") + len("```python") :]
    code = code[: code.index("```")]
    assert "af.simulate(scene, 1.0, 0.01" in code and 'vtx="out/"' in code
    code = code.replace("af.simulate(scene, 1.0, 0.01", "af.simulate(scene, 0.02, 0.01")
    code = code.replace('vtx="out/"', f"vtx={str(tmp_path)!r}, progress=False")
    monkeypatch.chdir(root)
    namespace = {}
    exec(compile(code, "python_api.md", "exec"), namespace)
    scene, run = namespace["scene"], namespace["run"]
    assert scene.islands() == ([namespace["body"]], [])
    assert run.records["tip"].shape == (3, 3) and np.abs(run.records["tip"][-1]).max() > 0
    assert_the_series_is_the_run(tmp_path / "tongue.bp", run, namespace["body"])


def test_the_api_reference_lists_exactly_the_public_surface():
    """docs/api.md documents every name of af, and of artifem.forms, artifem.io and
    artifem.reduction what they add to af; nothing else, nothing twice."""
    import importlib
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "api.md").read_text()
    listed = [line.strip() for line in text.splitlines() if line.startswith("   artifem.")]
    assert len(listed) == len(set(listed))
    expected = {f"artifem.{n}" for n in af.__all__}
    for package in ("artifem.forms", "artifem.io", "artifem.reduction"):
        module = importlib.import_module(package)
        expected |= {
            f"{package}.{n}"
            for n in module.__all__
            if getattr(af, n, None) is not getattr(module, n)
        }
    assert set(listed) == expected
