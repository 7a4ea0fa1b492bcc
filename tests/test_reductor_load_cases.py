"""Load cases in a reductor's training, and a path muscle carried onto the reduced body.

The muscle beam (clamped at x = 0) pulled sideways at its tip by a Thelen path muscle from a
world point, a follower pressure on its top face and gravity: three scene inputs
(:mod:`artifem.scene.inputs`) that schedules drive beside the beam's own muscle.

(1) The inputs set what they name, on a scene built full and on the same scene reduced.
(2) With every snapshot of a load-case training in the basis and every integration point,
    the reduced scene reproduces the full one on a training schedule: the path went onto
    the reduced body (same weights, G = sum_j w_j U_j) and the loads act on it live.
(3) On a held-out load case, a basis trained on the load cases is far closer to the full
    model than one of the same size trained on the muscle alone (the loads bend the beam
    in directions the muscle does not): 2.5 mm against 91 mm on a 0.10 m motion, measured;
    the one within 1.25 x its measured error, the other not below its own / 1.25.
"""

import json

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.errors import InputError, UnknownNameError
from artifem.excitation import ExcitationSchedule
from artifem.multibody.attachments import FemPoint
from artifem.multibody.muscles import ThelenMuscle, ThelenParameters
from artifem.multibody.point_attachments import shape_function_weights
from artifem.multibody.point_paths import PointPath
from artifem.reduction.reductor import Basis, Points, ReducibleScene, Reductor, Training
from artifem.reduction.schedules import random_schedules
from artifem.scene import Scene, simulate
from artifem.scene.inputs import Gravity, PathExcitation, SurfaceLoadLevel, controller
from outputs import assert_picture
from reduced_beam import make_body, ndofs

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="reduced bodies are serial")

DT = 0.01
TIP, ANCHOR = np.array([1.0, 0.15, 0.1]), np.array([1.0, 0.8, 0.1])
LOADS = {
    "pull": PathExcitation("sideways"),
    "press": SurfaceLoadLevel("fem", "top", 400.0),
    "gravity": Gravity((0.0, 0.0, -9.81)),
}


def pulled_beam() -> Scene:
    """The beam, a pressure on its top face (set by the inputs, 0 at first), a Thelen
    muscle from a world point to its tip, no gravity until an input sets it."""
    body = make_body(excitation=0.0, loads=False, comm=MPI.COMM_SELF)
    body.add_pressure(0.0, where=lambda x: np.isclose(x[2], 0.2), name="top")
    L = float(np.linalg.norm(ANCHOR - TIP))
    muscle = ThelenMuscle(ThelenParameters(40.0, 0.8 * L, 0.2 * L), name="sideways")
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(
        body,
        PointPath(
            muscle,
            [ANCHOR, FemPoint(body, shape_function_weights(body, TIP), name="tip")],
            name="sideways",
        ),
    )
    return scene


def pulled_model() -> ReducibleScene:
    """The pulled beam as a reductor's model (also for ``artifem study scene``)."""
    return ReducibleScene(
        "pulled",
        pulled_beam,
        "fem",
        {"model": "pulled"},
        loads=LOADS,
        motions={"press": ExcitationSchedule.ramp_and_hold({"press": 1.0}, 0.1)},
    )


MODEL = pulled_model()


def run(scene: Scene, schedule: ExcitationSchedule, duration: float) -> np.ndarray:
    MODEL.drive(scene, schedule)
    reduced = next(iter(scene.reduced_bodies), None)
    n = ndofs(MODEL.fem_body_or_full(scene))
    full = MODEL.fem_body_or_full(scene)
    record = (
        (lambda s: reduced.nodal_displacement().copy())
        if reduced
        else (lambda s: full.u.x.array[:n].copy())
    )
    return simulate(scene, duration, DT, record={"u": record}, progress=False).records["u"]


def test_scene_inputs_set_what_they_name():
    scene = pulled_beam()
    schedule = ExcitationSchedule(
        np.array([0.0, 1.0]),
        {
            "pull": np.array([0.0, 0.5]),
            "press": np.array([0.0, 1.0]),
            "gravity": np.array([1.0, 0.0]),
        },
    )
    controller(schedule, LOADS)(scene, 0.0, 0.5)
    assert np.allclose(scene.gravity, [0.0, 0.0, -0.5 * 9.81])
    assert scene.fem_bodies[0].surface_loads["top"].get() == pytest.approx(200.0)
    assert scene.paths[0]._timed.excitation(0.5) == pytest.approx(0.25)
    with pytest.raises(UnknownNameError, match=r"unknown scene inputs \['wind'\]"):
        controller(ExcitationSchedule(np.array([0.0]), {"wind": np.array([0.0])}), LOADS)
    with pytest.raises(UnknownNameError, match="0 paths named 'other'"):
        PathExcitation("other").apply(scene, 0.5)
    with pytest.raises(InputError, match="a pressure needs a reference of 1 number"):
        SurfaceLoadLevel("fem", "top", (0.0, 0.0, 1.0)).apply(scene, 0.5)


TRAINING = Training(
    random_schedules(["pull", "press", "gravity", "top"], 3, seed=3, duration=0.2, active=(2, 3)),
    duration=0.2,
    dt=DT,
    snapshot_every=1,
)
HELD_OUT = ExcitationSchedule(
    np.array([0.0, 0.08, 0.2]),
    {
        "pull": np.array([0.0, 0.9, 0.6]),
        "press": np.array([0.0, 0.7, 0.7]),
        "gravity": np.array([0.0, 0.5, 0.5]),
    },
)


def test_every_snapshot_and_point_of_a_load_case_training_reproduce_the_full_scene(tmp_path):
    reductor = Reductor(MODEL, TRAINING, tmp_path, progress=False)
    reduced = reductor.reduce(Basis("pod", 3 * 20), Points(sampling="all"))
    schedule = max(TRAINING.schedules.values(), key=lambda s: len(set(s.values) & set(LOADS)))
    assert len(set(schedule.values) & set(LOADS)) >= 2
    full = run(pulled_beam(), schedule, 0.2)
    scene = reduced.scene()
    (path,) = scene.paths
    assert path.name == "sideways" and path.bodies == tuple(scene.reduced_bodies)
    red = run(scene, schedule, 0.2)
    scale = np.abs(full).max()
    assert scale > 0.02
    assert np.abs(red - full).max() < 1e-6 * scale


def test_a_basis_trained_on_load_cases_follows_a_held_out_load_case(tmp_path):
    full = run(pulled_beam(), HELD_OUT, 0.2)
    muscle_only = Training(
        random_schedules(["top"], 3, seed=3, duration=0.2), duration=0.2, dt=DT, snapshot_every=1
    )
    errors = {}
    for name, training in (("loads", TRAINING), ("muscle", muscle_only)):
        reduced = Reductor(MODEL, training, tmp_path, progress=False).reduce(
            Basis("pod", 6), Points(sampling="all")
        )
        errors[name] = np.abs(run(reduced.scene(), HELD_OUT, 0.2) - full).max()
    # measured (two runs, same digits), m: the load-case basis and the muscle-only one
    assert errors["loads"] < 1.25 * 0.0024632806783443763, errors
    assert errors["muscle"] > 0.09071138670027198 / 1.25, errors


def test_the_scene_study_command_splits_any_model(tmp_path):
    """``artifem study scene MODULE:FUNCTION``: random training over the exciter and the
    three loads, the split on training, motions and held-out schedules, the render."""
    from artifem.cli import main

    out = tmp_path / "study"
    args = [
        "study",
        "scene",
        "test_reductor_load_cases:pulled_model",
        "--out",
        str(out),
        "--training-runs",
        "4",
        "--duration",
        "0.2",
        "--snapshot-every",
        "2",
        "--r",
        "6",
        "--sampling",
        "all",
        "--held-out",
        "2",
    ]
    assert main(args) == 0
    training = json.loads((out / "training.json").read_text())
    assert training["runs"] == training["missing"] == 4 and training["ranks"] == 1
    figures = json.loads((out / "generalization.json").read_text())
    assert [len(figures["sets"][s]) for s in ("training", "motions", "held-out")] == [4, 1, 2]
    assert figures["reduced"]["basis"]["r"] == 6
    assert all(not r["failed"] for runs in figures["sets"].values() for r in runs)
    assert figures["worst"]["set"] == "held-out"
    report = (out / "generalization.md").read_text()
    for r in figures["sets"]["held-out"]:  # the held-out table's rows are the JSON's runs
        row = f"| {r['name']} | {r['max_error_mm']:.2f} | {r['mean_error_mm']:.2f} | "
        assert row + f"{r['max_estimate_mm']:.2f} | {r['estimate_ratio']:.2f} |" in report
    assert_picture(out / "generalization.png")
    assert_picture(out / "generalization_worst.png")
    assert main(args) == 0  # again: all from the cache, the record of the
    assert json.loads((out / "training.json").read_text()) == training  # training kept


@pytest.mark.parametrize(
    "spec, message",
    [
        ("pulled_model", "give the model as MODULE:FUNCTION"),
        ("no_such_module_here:f", "cannot import 'no_such_module_here'"),
        ("test_reductor_load_cases:nothing", "has no 'nothing'"),
        ("test_reductor_load_cases:pulled_beam", "returned a Scene, not a ReducibleScene"),
    ],
)
def test_the_scene_study_refuses_a_bad_model_spec(spec, message, tmp_path, capsys):
    from artifem.cli import main

    assert main(["study", "scene", spec, "--out", str(tmp_path)]) == 2
    assert message in capsys.readouterr().err


def test_the_scene_study_enriches_its_points_without_a_full_run(tmp_path, capsys):
    """``--point-pool``: the points' greedy enrichment over random schedules of their own
    seed, recorded in points.json, its states in the reduced model's training record."""
    from artifem.cli import main

    out = tmp_path / "study"
    base = [
        "study",
        "scene",
        "test_reductor_load_cases:pulled_model",
        "--out",
        str(out),
        "--training-runs",
        "3",
        "--duration",
        "0.2",
        "--snapshot-every",
        "2",
        "--r",
        "6",
        "--points",
        "30",
        "--held-out",
        "1",
        "--point-pool",
        "2",
        "--point-rounds",
        "1",
    ]
    assert main(base) == 0
    record = json.loads((out / "points.json").read_text())
    assert record["pool"] == 2 and record["seed"] == 2000 and len(record["history"]) == 2
    first = record["history"][0]
    assert set(first["indicators"]) == {"points-2000-0", "points-2000-1"}
    assert first["added"] == max(first["indicators"], key=first["indicators"].get)
    kept = 10 if record["stopped"] == "rounds" else 0  # "stalled": the round undone
    assert record["stopped"] in ("rounds", "stalled") and record["extra_states"] == kept
    figures = json.loads((out / "generalization.json").read_text())
    assert figures["reduced"]["points"]["extra_states"] == kept
    assert len(list((out / "cache").glob("full-run-*"))) == 2  # the motion and held-out
    capsys.readouterr()
    assert main([*base, "--point-seed", "0"]) == 2
    assert "--point-seed 0 is also --training-seed" in capsys.readouterr().err
    assert main([*base, "--sampling", "random"]) == 2
    assert "--point-pool enriches trained points" in capsys.readouterr().err
