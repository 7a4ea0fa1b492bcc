"""Every scene gets every safeguard (artifem.scene.Scene.step): controllers, the health check
after each step (non-finite values, det F <= 0), step halving with a complete save and
restore of the scene's state, and a clear ElementInversionError when halving cannot recover.

The reference for "complete" is independent of the save/restore code: a step that fails
once and is retried as two half steps must give exactly what two half steps give in a twin
scene that never failed (FEM, rigid, joint and muscle-activation state alike).
"""

import json

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.errors import ElementInversionError, InputError, StepFailed
from artifem.excitation import ExcitationSchedule
from artifem.fem_body import FemBody
from artifem.forms import NeoHookean
from artifem.multibody.attachments import FemPoint, NodeAttachment
from artifem.multibody.joints import RevoluteJoint
from artifem.multibody.muscles import ThelenMuscle, ThelenParameters
from artifem.multibody.point_attachments import shape_function_weights
from artifem.multibody.point_paths import PointPath
from artifem.multibody.rigid_body import RigidBody
from artifem.scene import Scene
from outputs import assert_picture

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")

H = 0.01
TIP = np.array([0.95, 0.1, 0.2])


class Glitch:
    """A load element that pushes one tip node by 1e9 N on its first call only (a step
    that inverts elements), and nothing afterwards."""

    def __init__(self, body: FemBody):
        self.body, self.calls = body, 0
        self.dof = int(body.local_dofs(body.find_nodes(lambda x: np.isclose(x[0], 1.0)))[0])
        self.bodies = (body,)

    def master_loads(self, t):
        self.calls += 1
        f = np.zeros(self.body.v.x.array.size)
        if self.calls == 1:
            f[3 * self.dof + 2] = -1e9
        yield self.body, f


def hinged_beam(glitch: bool = False):
    """A beam carried at x = 0 by a bone hinged to the world about y, pulled up near its tip
    by a Thelen muscle (activation dynamics on) whose excitation ramps in 0.02 s."""
    msh = dmesh.create_box(
        MPI.COMM_SELF,
        [np.zeros(3), np.array([1.0, 0.2, 0.2])],
        [10, 2, 2],
        dmesh.CellType.hexahedron,
    )
    beam = FemBody(
        msh, NeoHookean.from_young_poisson(2e5, 0.3), 1000.0, rayleigh=(0.5, 0.0), name="beam"
    )
    bone = RigidBody("bone", 2.0, 0.01 * np.eye(3), position=(0.0, 0.1, 0.1))
    carried = NodeAttachment(beam, beam.find_nodes(lambda x: x[0] < 1e-12), bone)
    y_up = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # frame z = world y
    hinge = RevoluteJoint.at_world(bone, None, (0.0, 0.1, 0.1), y_up, name="hinge")
    params = ThelenParameters(200.0, 0.4, 0.3)
    muscle = ThelenMuscle(params, excitation=0.0, name="lifter")
    schedule = ExcitationSchedule.ramp_and_hold({"lifter": 0.8}, 0.02)
    path = PointPath(
        muscle,
        [np.array([0.95, 0.1, 0.9]), FemPoint(beam, shape_function_weights(beam, TIP))],
        excitation=lambda t: schedule.at(t)["lifter"],
        name="lifter",
    )
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add(beam, bone, carried, hinge, path)
    if glitch:
        scene.add(Glitch(beam))
    return scene, beam, bone, muscle


def snapshot(scene, beam, bone, muscle):
    return {
        "t": scene.t,
        "u": beam.u.x.array.copy(),
        "v": beam.v.x.array.copy(),
        "p": bone.position.copy(),
        "R": bone.rotation.copy(),
        "w": bone.twist,
        "activation": muscle.activation,
    }


def assert_same(a, b, rtol=1e-12):
    for key in a:
        x, y = np.asarray(a[key], float), np.asarray(b[key], float)
        assert np.abs(x - y).max() <= rtol * max(np.abs(y).max(), 1e-300), key


def test_a_failed_step_is_undone_and_retried_by_the_implicit_step_before_halving():
    """Scene.fallback (the default): the glitched semi-implicit step is undone and the same
    step is taken by the implicit Newton step (the glitch is gone by then), exactly as a
    twin scene stepped implicitly from the start gives it; no halving."""
    failing, *parts_f = hinged_beam(glitch=True)
    calls = []
    failing.add_controller(lambda scene, t0, t1: calls.append((t0, t1)))
    failing.step(H)
    assert (failing.fallbacks, failing.halvings) == (1, 0)
    assert calls == [(0.0, H)]

    twin, *parts_t = hinged_beam()
    twin.integrator = type(failing.fallback)()
    twin.step(H)
    a, b = snapshot(failing, *parts_f), snapshot(twin, *parts_t)
    assert np.abs(b["u"]).max() > 1e-5  # it moved
    assert_same(a, b, rtol=1e-10)


def test_a_failed_step_is_undone_and_retried_as_two_exact_half_steps():
    failing, *parts_f = hinged_beam(glitch=True)
    failing.fallback = None  # halving alone (the fallback: above)
    calls = []
    failing.add_controller(lambda scene, t0, t1: calls.append((t0, t1)))
    failing.step(H)  # the first try inverts: halved once
    assert failing.halvings == 1
    assert calls == [(0.0, H), (0.0, H / 2), (H / 2, H)]

    twin, *parts_t = hinged_beam()
    twin.step(H / 2)
    twin.step(H / 2)
    assert twin.halvings == 0
    a, b = snapshot(failing, *parts_f), snapshot(twin, *parts_t)
    assert a["t"] == pytest.approx(H)
    assert np.abs(b["u"]).max() > 1e-5 and b["activation"] > 0.05  # it moved, it activated
    assert_same(a, b)
    assert 0 < failing.min_det_F == pytest.approx(twin.min_det_F, rel=1e-12)


def test_save_and_restore_state_reproduce_the_run():
    scene, beam, bone, muscle = hinged_beam()
    for _ in range(3):
        scene.step(H)
    saved = scene.save_state()
    for _ in range(2):
        scene.step(H)
    first = snapshot(scene, beam, bone, muscle)
    reaction = scene.reaction(scene.joints[0])
    scene.restore_state(saved)
    assert scene.t == pytest.approx(3 * H)
    for _ in range(2):
        scene.step(H)
    assert_same(snapshot(scene, beam, bone, muscle), first, rtol=0.0)
    for x, y in zip(scene.reaction(scene.joints[0]), reaction):
        np.testing.assert_array_equal(x, y)
    other, *_ = hinged_beam()
    other.add(RigidBody("extra", 1.0, np.eye(3)))
    with pytest.raises(InputError, match="saved from a scene with other components"):
        other.restore_state(saved)


def test_unrecoverable_inversion_names_body_time_elements_and_keeps_the_last_good_state():
    scene, beam, bone, muscle = hinged_beam()
    scene.max_halvings = 2
    scene.step(H)
    good = snapshot(scene, beam, bone, muscle)

    class Crush:  # every step inverts, whatever its size
        bodies = (beam,)

        def master_loads(self, t):
            f = np.zeros(beam.v.x.array.size)
            f[2::3] = -1e12
            yield beam, f

    scene.add(Crush())
    with pytest.raises(ElementInversionError) as err:
        scene.step(H)
    e = err.value
    assert e.body == "beam" and e.min_det <= 0 and e.elements.size > 0
    assert e.time == pytest.approx(H + H / 4)  # the smallest step after 2 halvings
    assert "'beam'" in str(e) and "after 2 halvings" in str(e)
    assert scene.halvings == 2
    assert_same(snapshot(scene, beam, bone, muscle), good, rtol=0.0)
    assert beam.inverted_elements()[0].size == 0


def test_a_solver_failure_is_retried_then_reported():
    scene, beam, bone, muscle = hinged_beam()
    scene.max_halvings = 1

    class Broken:
        bodies = (beam,)

        def master_loads(self, t):
            raise StepFailed("the load could not be evaluated")

    scene.add(Broken())
    with pytest.raises(
        StepFailed, match="the load could not be evaluated; step 0.005 s after 1 halvings"
    ):
        scene.step(H)
    assert scene.t == 0.0 and scene.halvings == 1


def test_bad_time_step_and_controller_are_clear_errors():
    scene, *_ = hinged_beam()
    for h in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(InputError, match="time step must be positive and finite"):
            scene.step(h)
    with pytest.raises(InputError, match="a controller is a callable"):
        scene.add_controller(3)
    with pytest.raises(InputError, match="max_halvings"):
        Scene(max_halvings=-1)


def test_jaw_tongue_with_every_exciter_stepped_to_one_runs(tmp_path):
    """The hard case of the Scene issue: all eleven exciters stepped to 1.0 at dt = 0.05 s.
    It used to return max |u| = 94 mm and det F = -65 silently, then stopped naming the
    tongue's inverted elements; with the Rayleigh damping on the stiffness at rest
    (FemBody.rest_stiffness) and the implicit fallback it runs, every body sound."""
    from artifem.cli import main
    from artifem.models.jaw_tongue import model as jt
    from artifem.models.jaw_tongue.study import simulate

    s = jt.build_scene(jt.JawTongueConfig())
    exciters = sorted(s.tongue.data.exciters)
    schedule = ExcitationSchedule(
        np.array([0.0, 1e-3, 1.0]), {name: [0.0, 1.0, 1.0] for name in exciters}
    )
    out = simulate(s, schedule, 0.5, 0.05)
    assert len(out["t"]) == 11 and out["t"][-1] == pytest.approx(0.5)
    assert 0 < s.scene.min_det_F < 1
    assert all(b.inverted_elements()[0].size == 0 for b in s.scene.bodies)
    assert all(np.all(np.isfinite(a)) for b in s.scene.bodies for a in b.state())
    assert np.abs(out["tip"][-1]).max() > 1e-3  # the muscles moved the tongue

    # the command line runs it too
    path = tmp_path / "all.json"
    path.write_text(
        json.dumps(
            {"times": [0.0, 1e-3, 1.0], "excitations": {n: [0.0, 1.0, 1.0] for n in exciters}}
        )
    )
    assert (
        main(
            [
                "simulate",
                "jaw-tongue",
                "--schedule",
                str(path),
                "--dt",
                "0.05",
                "--duration",
                "0.5",
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 0
    )
    # ... to the same end: its record is the run above (same code, same steps)
    written = json.loads((tmp_path / "o" / "all" / "simulate.json").read_text())
    assert (written["steps"], written["dt"], written["motion"]) == (10, 0.05, "all")
    np.testing.assert_allclose(
        written["final_tip_displacement_mm"], 1e3 * out["tip"][-1], rtol=1e-9, atol=1e-9
    )
    assert written["min_det_F"] == pytest.approx(s.scene.min_det_F, rel=1e-12)
    assert_picture(tmp_path / "o" / "all" / "jaw-tongue.png")
