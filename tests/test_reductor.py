"""The reductor (artifem.reduction.reductor) and its schedules (artifem.reduction.schedules).

(1) A free muscle beam: with the POD of every snapshot of the training and every
    integration point the reduced scene reproduces the full scene on a training
    schedule (Galerkin projection of a trajectory inside the basis: measured 9e-10 m on
    0.5 m); on a held-out schedule the error decreases strictly with the POD size.
(2) The beam's end riding on a bone hinged to the world: the reductor puts the bone's
    motion into the basis (rigid lift) and the node attachment becomes a lift attachment;
    with every snapshot and point the reduced scene reproduces the full one (measured
    7e-9 m on 0.09 m), the carried nodes stay on the bone, and the trained cubature keeps
    the error near the all-points one.
(3) The cache: a second reduction builds the model once and runs no training, and gives
    the same model; the training seconds are reported either way.
(4) Bad input, refused before any training run: an unknown body, an unknown input, a
    coupling the reductor cannot carry (a load element), an unknown load, a name both an
    exciter and a load.
(6) A rigid block on a polar frame of the beam's end (Fig. 11): the frame attachment
    goes onto the reduced body, and with every snapshot and point the beam and the block
    follow the full scene (measured 6e-16 m and 2e-16 m on 0.22 m).
(5) Random schedules: determined by their seed, in [0, 1], several exciters together up
    to the requested level, some releasing within the run; another seed gives others.
"""

import json

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.errors import InputError, UnknownNameError
from artifem.excitation import ExcitationSchedule
from artifem.multibody.attachments import FemFrame, FrameAttachment, NodeAttachment
from artifem.multibody.joints import RevoluteJoint, axis_rotation
from artifem.multibody.rigid_body import RigidBody, exp_so3
from artifem.reduction.reductor import Basis, Points, ReducibleScene, Reductor, Training, reduce
from artifem.reduction.schedules import each_alone, random_schedules
from artifem.scene import Scene, simulate
from artifem.scene.inputs import Gravity, SurfaceLoadLevel
from outputs import assert_picture
from reduced_beam import Builds, make_body, ndofs

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="reduced bodies are serial")

DT = 0.01


def free_beam() -> Scene:
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add(make_body(excitation=0.0))
    return scene


def hinged_beam(mass: str = "lumped") -> Scene:
    """The beam's free end (x = 1) rides on a bone hinged to the world about z."""
    body = make_body(excitation=0.0, mass=mass)
    bone = RigidBody(
        "bone",
        0.3,
        np.diag([2e-3, 3e-3, 4e-3]),
        position=(1.1, 0.15, 0.1),
        rotation=exp_so3([0.2, -0.1, 0.3]),
    )
    hinge = RevoluteJoint.at_world(bone, None, (1.2, 0.15, 0.1), axis_rotation((0, 0, 1)))
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    end = body.find_nodes(lambda x: x[0] > 1.0 - 1e-12)
    scene.add(body, bone, hinge, NodeAttachment(body, end, bone, name="end"))
    return scene


def beam_with_a_rigid_tip() -> Scene:
    """A rigid block on a polar frame of the beam's free end (paper Fig. 11 right)."""
    body = make_body(excitation=0.0)
    tip = RigidBody("tip", 0.5, np.diag([1e-3, 2e-3, 2e-3]), position=(1.05, 0.15, 0.1))
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add(body, tip, FrameAttachment(tip, FemFrame(body, (0.95, 0.15, 0.1)), name="tip"))
    return scene


def run(model: ReducibleScene, scene: Scene, schedule, duration: float) -> dict:
    """Displacements of the model's body (full or reduced) and the attachment error."""
    model.drive(scene, schedule)
    reduced = next(iter(scene.reduced_bodies), None)
    full = model.fem_body_or_full(scene)
    n = ndofs(full)
    record = {
        "u": (lambda s: reduced.nodal_displacement().copy())
        if reduced
        else (lambda s: full.u.x.array[:n].copy())
    }
    if scene.node_attachments or scene.lift_attachments:
        record["attached"] = lambda s: max(s.attachment_errors().values())
    if scene.frame_attachments:
        record["tip"] = lambda s: s.frame_attachments[0].slave.position.copy()
    return simulate(scene, duration, DT, record=record, progress=False).records


TRAINING = Training(
    random_schedules(["top"], 2, seed=1, duration=0.2, active=(1, 1)),
    duration=0.2,
    dt=DT,
    snapshot_every=1,
)
HELD_OUT = ExcitationSchedule(
    np.array([0.0, 0.1, 0.15, 0.2]), {"top": np.array([0.0, 0.8, 0.8, 0.3])}
)


@pytest.mark.parametrize("make", [free_beam, hinged_beam, beam_with_a_rigid_tip])
def test_every_snapshot_and_point_reproduce_the_full_scene(make, tmp_path):
    model = ReducibleScene(make.__name__, make, "fem", {"model": make.__name__})
    S = 2 * 20
    reduced = reduce(
        model,
        TRAINING,
        basis=Basis("pod", S),
        points=Points(sampling="all"),
        cache=tmp_path,
        progress=False,
    )
    schedule = next(iter(TRAINING.schedules.values()))
    full = run(model, make(), schedule, 0.2)
    scene = reduced.scene()
    assert not scene.fem_bodies and len(scene.reduced_bodies) == 1
    red = run(model, scene, schedule, 0.2)
    scale = np.abs(full["u"]).max()
    assert scale > 0.05
    assert np.abs(red["u"] - full["u"]).max() < 1e-6 * scale
    if make is hinged_beam:
        assert [a.name for a in scene.lift_attachments] == ["end"]
        assert reduced.training["basis"]["lift_columns"] == 12
        assert red["attached"].max() < 1e-12
    if make is beam_with_a_rigid_tip:  # the frame went onto the reduced body
        (attachment,) = scene.frame_attachments
        assert attachment.frame.body is scene.reduced_bodies[0]
        assert np.abs(red["tip"] - full["tip"]).max() < 1e-6 * scale


def test_pod_vectors_vanish_on_the_carried_and_clamped_nodes_with_a_consistent_mass(tmp_path):
    """With the consistent mass (the reductor's mass an operator x -> M x) as with the lumped
    diagonal, the POD vectors of the hinged beam vanish exactly on the nodes the bone
    carries (the lift columns move them) and on the clamped ones."""

    def make():
        return hinged_beam(mass="consistent")

    model = ReducibleScene("hinged_consistent", make, "fem", {"model": "hinged_consistent"})
    reduced = reduce(
        model,
        TRAINING,
        basis=Basis("pod", 8),
        points=Points(sampling="all"),
        cache=tmp_path,
        progress=False,
    )
    body = model.fem_body_or_full(make())
    x = body.V.tabulate_dof_coordinates()[: body.V.dofmap.index_map.size_local]
    nodes = np.flatnonzero((x[:, 0] > 1.0 - 1e-12) | (x[:, 0] < 1e-12))
    U = reduced.basis[:, :8]
    assert reduced.r == 8 + 12 and np.abs(U).max() > 0
    assert np.all(U[(3 * nodes[:, None] + np.arange(3)).ravel()] == 0.0)


#: the held-out schedule's largest nodal error (m) of the POD bases r = 2, 4, 8 on the free
#: beam, measured (two runs, same digits; the beam moves 0.198 m): the bound is 1.25 x these
MEASURED_HELD_OUT_ERROR_M = (0.07052360579559819, 0.016115883042228135, 0.0035715691338387423)


def test_held_out_error_decreases_with_the_basis_size(tmp_path):
    """Strictly, and each basis within 1.25 times its measured error."""
    model = ReducibleScene("free", free_beam, "fem", {"model": "free"})
    reductor = Reductor(model, TRAINING, tmp_path, progress=False)
    full = run(model, free_beam(), HELD_OUT, 0.2)["u"]
    errors = []
    for r in (2, 4, 8):
        reduced = reductor.reduce(Basis("pod", r), Points(sampling="all"))
        u = run(model, reduced.scene(), HELD_OUT, 0.2)["u"]
        errors.append(np.abs(u - full).max())
    assert errors[0] > errors[1] > errors[2]
    for error, measured in zip(errors, MEASURED_HELD_OUT_ERROR_M, strict=True):
        assert error < 1.25 * measured, errors


def test_trained_points_on_a_carried_body_stay_near_every_point(tmp_path):
    model = ReducibleScene("hinged", hinged_beam, "fem", {"model": "hinged"})
    reductor = Reductor(model, TRAINING, tmp_path, progress=False)
    full = run(model, hinged_beam(), HELD_OUT, 0.2)
    every = run(
        model, reductor.reduce(Basis("pod", 6), Points(sampling="all")).scene(), HELD_OUT, 0.2
    )
    trained = reductor.reduce(Basis("pod", 6), Points(60, tol=1e-6, training_states=40))
    # the tol is not reached within the 60 points asked for: all 60 taken, and the training
    # residual is 2.796e-4 (measured, two runs): 1.25 x that
    assert trained.points.m == 60 and trained.points.residual < 1.25 * 0.0002796324130680636
    some = run(model, trained.scene(), HELD_OUT, 0.2)
    err_every = np.abs(every["u"] - full["u"]).max()
    err_some = np.abs(some["u"] - full["u"]).max()
    # measured (the beam's tip moves 0.0896 m): every point 2.856e-3 m, the 60 trained points
    # 2.867e-3 m (0.4 % more); each within 1.25 x its measured value
    assert err_every < 1.25 * 0.002856219486849991
    assert err_some < 1.25 * 0.0028674613388382023
    assert some["attached"].max() < 1e-12


def test_a_second_reduction_loads_every_stage_from_the_cache(tmp_path):
    build = Builds(hinged_beam)
    model = ReducibleScene("hinged", build, "fem", {"model": "hinged"})
    spec = dict(basis=Basis("pod", 5), points=Points(40, tol=1e-6, training_states=20))
    first = reduce(model, TRAINING, cache=tmp_path, progress=False, **spec)
    assert build.count == 1 + len(TRAINING.schedules)  # the model, then each run
    second = reduce(model, TRAINING, cache=tmp_path, progress=False, **spec)
    assert build.count == 2 + len(TRAINING.schedules)  # the model only
    assert np.array_equal(first.basis, second.basis)
    assert np.array_equal(first.points.indices, second.points.indices)
    assert first.training == second.training
    assert first.training["seconds"]["snapshots"] > 0


def test_bad_input_is_refused_before_any_training_run(tmp_path):
    build = Builds(free_beam)
    with pytest.raises(UnknownNameError, match="no FEM body named 'tongue'"):
        reduce(ReducibleScene("beam", build, "tongue", {}), TRAINING, cache=tmp_path)
    unknown = Training(each_alone(["bottom"], 0.5, 0.1), 0.1, DT)
    with pytest.raises(UnknownNameError, match=r"unknown inputs \['bottom'\]"):
        reduce(ReducibleScene("beam", build, "fem", {}), unknown, cache=tmp_path)

    class Push:
        """A load element on the beam (no onto_reduced)."""

        name = "push"

        def __init__(self, body):
            self.bodies = (body,)

        def master_loads(self, t):
            return [(self.bodies[0], np.zeros_like(self.bodies[0].v.x.array))]

    def with_push() -> Scene:
        scene = free_beam()
        scene.add(Push(scene.fem_bodies[0]))
        return scene

    with pytest.raises(InputError, match="Push 'push' couples 'fem'"):
        reduce(ReducibleScene("beam", Builds(with_push), "fem", {}), TRAINING, cache=tmp_path)
    with pytest.raises(UnknownNameError, match="no surface load 'lid'"):
        reduce(
            ReducibleScene(
                "beam", build, "fem", {}, loads={"lid": SurfaceLoadLevel("fem", "lid", 100.0)}
            ),
            TRAINING,
            cache=tmp_path,
        )
    with pytest.raises(InputError, match=r"\['top'\] name both an exciter and a load"):
        reduce(
            ReducibleScene("beam", build, "fem", {}, loads={"top": Gravity()}),
            TRAINING,
            cache=tmp_path,
        )
    assert build.count == 4 and not list(tmp_path.glob("*.npz"))


def test_random_schedules_are_seeded_space_filling_and_release():
    exciters = [f"m{k}" for k in range(6)]
    a = random_schedules(exciters, 12, seed=7, duration=1.0, excitation=(0.1, 1.0), active=(2, 4))
    b = random_schedules(exciters, 12, seed=7, duration=1.0, excitation=(0.1, 1.0), active=(2, 4))
    c = random_schedules(exciters, 12, seed=8, duration=1.0, excitation=(0.1, 1.0), active=(2, 4))
    assert list(a) == [f"random-7-{i}" for i in range(12)]
    for s, t in zip(a.values(), b.values()):
        assert np.array_equal(s.times, t.times) and s.values.keys() == t.values.keys()
        assert all(np.array_equal(s.values[k], t.values[k]) for k in s.values)
    assert any(not np.array_equal(s.times, t.times) for s, t in zip(a.values(), c.values()))
    peaks, released = [], 0
    for s in a.values():
        assert 2 <= len(s.values) <= 4 and set(s.values) <= set(exciters)
        assert s.times[0] == 0.0 and s.times[-1] == 1.0
        for values in s.values.values():
            assert values.min() >= 0.0 and values.max() <= 1.0 and values[0] == 0.0
            peaks.append(values.max())
            released += values[-1] < values.max()
    # the Latin hypercube spreads the levels over (0.1, 1): the highest decile is reached
    assert max(peaks) > 0.9 and min(p for p in peaks if p > 0) < 0.4
    assert released > 0
    with pytest.raises(InputError, match="excitations are in"):
        random_schedules(exciters, 2, seed=0, duration=1.0, excitation=(0.1, 1.5))


#: each run's max error (mm) and its hierarchical estimate / error in the split below,
#: measured (two runs, same digits, seed 99): the errors within 1.25 x, the ratios within a
#: factor 1.25 (both are reduced models' errors)
MEASURED_SPLIT = {
    "random-1-0": (1.2156225746267209, 0.9999606400442934),
    "random-1-1": (1.3586985116643395, 0.9999955333688375),
    "ramp": (5.862950894268891, 0.9732633321867273),
    "held-out-99-0": (1.175021470580914, 1.0205197592921367),
    "held-out-99-1": (1.2837484665929013, 0.9668305863185739),
    "held-out-99-2": (1.1543683325259326, 1.0484068759546397),
}


def test_generalization_study_reports_the_three_sets(tmp_path):
    """The train/test split on the free beam: training, the model's motions and held-out
    random schedules, each run's error and estimate within their measured margins (the
    hierarchical estimate, r = 12 against r = 3, is within 5 % of the error); the report's
    table rows are the JSON's runs, and the series and the plots are written."""
    from artifem.reduction.generalization import generalization_study

    motion = ExcitationSchedule.ramp_and_hold({"top": 0.7}, 0.1)
    model = ReducibleScene("free", free_beam, "fem", {"model": "free"}, motions={"ramp": motion})
    figures = generalization_study(
        Reductor(model, TRAINING, tmp_path / "cache", progress=False),
        tmp_path,
        basis=Basis("pod", 3),
        points=Points(sampling="all"),
        reference=(Basis("pod", 12), Points(sampling="all")),
        held_out=3,
        seed=99,
        duration=0.2,
        progress=False,
    )
    sets = figures["sets"]
    assert [len(sets[s]) for s in ("training", "motions", "held-out")] == [2, 1, 3]
    assert figures["reduced"]["basis"]["r"] == 3 and figures["reference"]["basis"]["r"] == 12
    assert {r["name"] for runs in sets.values() for r in runs} == set(MEASURED_SPLIT)
    for runs in sets.values():
        for r in runs:
            error, ratio = MEASURED_SPLIT[r["name"]]
            assert not r["failed"] and r["max_error_mm"] < 1.25 * error, r
            assert (r["speedup"] is None) == (r in sets["training"])  # no 2nd full run
            assert 1 / 1.25 < r["estimate_ratio"] / ratio < 1.25, r
            # the slowest step after the first over the median: at least 1 (3 or more steps)
            assert np.isfinite(r["max_step_over_median"]) and r["max_step_over_median"] >= 1, r
    written = json.loads((tmp_path / "generalization.json").read_text())
    report = (tmp_path / "generalization.md").read_text()
    for name in ("training", "motions", "held-out"):  # every row of each set's table
        assert f"## {name}" in report
        for r in written["sets"][name]:
            speedup = "-" if r["speedup"] is None else f"{r['speedup']:.0f}x"
            row = (
                f"| {r['name']} | {r['max_error_mm']:.2f} | {r['mean_error_mm']:.2f} | "
                f"{r['max_estimate_mm']:.2f} | {r['estimate_ratio']:.2f} | "
                f"{r['reduced_ms_per_step']:.2f} | {r['max_step_over_median']:.1f} | {speedup} |"
            )
            assert row in report, row
    assert_picture(tmp_path / "generalization.png")
    worst = figures["worst"]  # the render: the worst held-out moment
    assert worst["set"] == "held-out" and worst["mean_error_mm"] == pytest.approx(
        max(r["max_error_mm"] for r in sets["held-out"]), rel=1e-12
    )
    assert worst["max_node_error_mm"] > worst["mean_error_mm"]
    assert_picture(tmp_path / "generalization_worst.png")
    assert "generalization_worst.png" in (tmp_path / "generalization.md").read_text()
    series = np.load(tmp_path / "generalization_series.npz")
    assert series["held-out/held-out-99-0/error_mm"].shape == (21,)


def test_error_sources_split_the_error_into_basis_cubature_and_dynamics(tmp_path):
    """``sources=True``: with every point the reduced model is its own every-point model;
    a basis holding every snapshot of a run holds that run (projection at round-off), while
    its reduced model with few trained points is off by the cubature's error."""
    from artifem.reduction.evaluation import compare
    from artifem.reduction.generalization import error_sources, generalization_study

    model = ReducibleScene(
        "free",
        free_beam,
        "fem",
        {"model": "free"},
        motions={"ramp": ExcitationSchedule.ramp_and_hold({"top": 0.7}, 0.1)},
    )
    reductor = Reductor(model, TRAINING, tmp_path / "cache", progress=False)
    figures = generalization_study(
        reductor,
        tmp_path,
        basis=Basis("pod", 3),
        points=Points(sampling="all"),
        held_out=2,
        seed=99,
        duration=0.2,
        sources=True,
        progress=False,
    )
    for name in ("motions", "held-out"):
        for r in figures["sets"][name]:
            assert r["every_point_mm"] == pytest.approx(r["max_error_mm"], rel=1e-12)
            assert 0 < r["projection_mm"] < r["max_error_mm"]
    assert "best in the basis (mm)" in (tmp_path / "generalization.md").read_text()
    name, schedule = next(iter(TRAINING.schedules.items()))
    every_snapshot = reductor.reduce(Basis("pod", 2 * 20), Points(12, tol=1e-9))
    found = error_sources(reductor, every_snapshot, {name: schedule}, 0.2, DT, progress=False)[name]
    error = np.nanmax(
        compare(
            every_snapshot,
            {name: schedule},
            duration=0.2,
            dt=DT,
            cache=tmp_path / "cache",
            progress=False,
        )[0].error_mm
    )
    assert found["projection_mm"] < 1e-9
    assert found["every_point_mm"] < 1e-6 < 0.01 < error


def test_a_held_out_set_drawn_with_the_training_seed_is_refused(tmp_path):
    from artifem.reduction.generalization import held_out_schedules

    training = Training(
        random_schedules(["top"], 2, seed=5, duration=0.2, prefix="held-out"), 0.2, DT
    )
    with pytest.raises(InputError, match="seed the training did not use"):
        held_out_schedules(
            ReducibleScene("free", free_beam, "fem", {}), ["top"], training, 2, 5, 0.2
        )


def test_a_hard_body_is_reduced_with_its_pressure_space(tmp_path):
    """The hard incompressibility goes through every stage: training pressures, the reduced
    pressure space (the constant and POD modes), the constraint's weights at trained
    points, and the split of a hard body (its reference too). With every snapshot in the
    basis, every point and every pressure mode (16 elements) the reduced scene reproduces
    the full hard scene; with 3 modes it holds only those: 0.4 % off, measured."""
    from artifem.incompressibility import Incompressible
    from artifem.reduction.generalization import generalization_study

    def hard_beam() -> Scene:
        scene = Scene(gravity=(0.0, 0.0, -9.81))
        scene.add(
            make_body(
                excitation=0.0,
                rayleigh=(0.5, 0.01),
                incompressibility=Incompressible(kappa=7.6e5, tol=1e-10),
            )
        )
        return scene

    model = ReducibleScene("hard", hard_beam, "fem", {"model": "hard"})
    schedule = next(iter(TRAINING.schedules.values()))
    full = run(model, hard_beam(), schedule, 0.2)["u"]
    scale = np.abs(full).max()
    for modes, tol in ((16, 1e-6), (3, 1e-2)):
        reduced = reduce(
            model,
            TRAINING,
            basis=Basis("pod", 40),
            points=Points(sampling="all"),
            cache=tmp_path,
            pressure_modes=modes,
            progress=False,
        )
        assert reduced.pressure_basis.shape[1] == modes
        assert np.abs(run(model, reduced.scene(), schedule, 0.2)["u"] - full).max() < tol * scale
    figures = generalization_study(
        Reductor(model, TRAINING, tmp_path, pressure_modes=3, progress=False),
        tmp_path / "split",
        basis=Basis("pod", 4),
        points=Points(40, tol=1e-6, training_states=20),
        held_out=1,
        seed=99,
        duration=0.2,
        progress=False,
    )
    assert figures["reduced"]["points"]["count"] <= 40
    assert all(not r["failed"] for runs in figures["sets"].values() for r in runs)


def test_a_full_model_that_fails_ends_its_comparison_there(tmp_path):
    """A held-out schedule the full model cannot complete (the hard tongue inverts elements
    under some) does not end the study: the comparison says why and keeps the error up to
    that time, the reduced run goes on."""
    from artifem.errors import StepFailed
    from artifem.reduction.evaluation import compare

    failing = {"on": False}

    def failing_beam() -> Scene:
        scene = free_beam()

        def stop(s, t0, t1):
            if failing["on"] and s.fem_bodies and t1 > 0.1 + 1e-9:
                raise StepFailed("the full beam stops at 0.1 s")

        scene.add_controller(stop)
        return scene

    model = ReducibleScene("failing", failing_beam, "fem", {"model": "failing"})
    reduced = reduce(
        model,
        TRAINING,
        basis=Basis("pod", 4),
        points=Points(sampling="all"),
        cache=tmp_path,
        progress=False,
    )
    failing["on"] = True
    (c,) = compare(
        reduced, {"held out": HELD_OUT}, duration=0.2, dt=DT, cache=tmp_path, progress=False
    )
    s = c.summary()
    assert s["full_failed"] and "stops at 0.1 s" in s["full_error"] and not s["failed"]
    assert np.all(np.isfinite(c.error_mm[:11])) and np.all(np.isnan(c.error_mm[11:]))
    assert c.reduced_ms.size == 20
