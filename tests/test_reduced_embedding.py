"""An FEM body embedded in the body a reductor reduces (EmbeddedFemAttachment.onto_reduced):
the slave keeps its own dofs' dynamics (mass, stiffness, loads) and its nodes follow the
reduced master, x_s = W (X_m + u_bar + U q) + c, v_s = (W U) q', f_q = (W U)^T f_s.

The scene: the muscle beam of tests/reduced_beam.py with a thin sheet (its own FEM body,
no fixed nodes) lying inside it, attached node by node ("membrane").

(1) With the POD of every training snapshot and every integration point the reduced scene
    reproduces the full scene on a training schedule, the beam and the sheet's nodes
    (measured 3e-16 m and 2e-16 m on 0.22 m and 0.21 m); likewise with the beam's end on a
    hinged bone, the sheet then following the basis' lift columns too (6e-9 m on 0.1 m).
    The reduced scene's attachment keeps its name and has the reduced body as its master.
(2) With a small basis (r = 4) the sheet's nodes sit at W x_m + c of the reduced master
    (rebuilt here from u = u_bar + U q on every node) at every step (2e-16 m); the sheet
    acts on the reduced coordinates exactly through G = W U: the masters' static force is
    f~ + G^T f_s and the step matrix A~ + G^T A_s G; a sheet 10 times heavier changes the
    beam's motion (measured by 6% of it).
(3) The static tangent of the hinged scene reduced matches finite differences of the
    master forces (measured 2e-9 and 9e-9 relative): K_geo of the bone sees the sheet's
    forces through (W U)^T on the lift columns.
(4) Bad input: the sheet, the attachment's slave, as the body to reduce is refused before
    any training run, naming the attachment; a reduced body of another body is refused.
(5) The masseter as built (models/masseter/model.py, coarse: its primary FEM carried by two bones,
    the jaw and the arch, three aponeurosis membranes embedded in it) reduces: each bone's
    lift columns hold the other bone's nodes at rest, and with every snapshot and point the
    reduced scene reproduces the full one (measured 3e-15 m on 0.7 mm).
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.errors import InputError
from artifem.excitation import ExcitationSchedule
from artifem.fem_body import FemBody
from artifem.forms import NeoHookean
from artifem.integrators import reduced_step_system, step_system
from artifem.multibody.attachments import EmbeddedFemAttachment, NodeAttachment
from artifem.multibody.joints import RevoluteJoint, axis_rotation
from artifem.multibody.rigid_body import RigidBody, exp_so3
from artifem.reduction.reductor import Basis, Points, ReducibleScene, Training, reduce
from artifem.reduction.schedules import random_schedules
from artifem.scene import Scene, simulate
from coupled_fd import master_force_difference
from reduced_beam import Builds, make_body, ndofs

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="reduced bodies are serial")

DT = 0.01
TRAINING = Training(
    random_schedules(["top"], 2, seed=1, duration=0.2, active=(1, 1)),
    duration=0.2,
    dt=DT,
    snapshot_every=1,
)
SCHEDULE = next(iter(TRAINING.schedules.values()))


def sheet(density: float = 1000.0) -> FemBody:
    """A thin 3 x 2 x 1 hex box inside the beam (0.6 x 0.2 x 0.04 m), nothing fixed."""
    msh = dmesh.create_box(
        MPI.COMM_SELF,
        [np.array([0.3, 0.05, 0.08]), np.array([0.9, 0.25, 0.12])],
        [3, 2, 1],
        dmesh.CellType.hexahedron,
    )
    return FemBody(
        msh,
        NeoHookean.from_young_poisson(5e4, 0.3),
        density,
        rayleigh=(0.5, 0.01),
        gravity=(0.0, 0.0, -9.81),
        name="sheet",
    )


def beam_with_a_sheet(density: float = 1000.0) -> Scene:
    beam = make_body(excitation=0.0, comm=MPI.COMM_SELF)
    slave = sheet(density)
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    scene.add(beam, slave, EmbeddedFemAttachment(slave, beam, name="membrane"))
    return scene


def hinged_beam_with_a_sheet() -> Scene:
    """The same, the beam's free end (x = 1) riding on a bone hinged to the world about z:
    the sheet's nodes near the end follow the bone through the basis' lift columns."""
    scene = beam_with_a_sheet()
    beam = scene.fem_bodies[0]
    bone = RigidBody(
        "bone",
        0.3,
        np.diag([2e-3, 3e-3, 4e-3]),
        position=(1.1, 0.15, 0.1),
        rotation=exp_so3([0.2, -0.1, 0.3]),
    )
    hinge = RevoluteJoint.at_world(bone, None, (1.2, 0.15, 0.1), axis_rotation((0, 0, 1)))
    end = beam.find_nodes(lambda x: x[0] > 1.0 - 1e-12)
    scene.add(bone, hinge, NodeAttachment(beam, end, bone, name="end"))
    return scene


MODEL = ReducibleScene("sheet in beam", beam_with_a_sheet, "fem", {"model": "sheet in beam"})


def slave_of(scene: Scene) -> FemBody:
    return next(b for b in scene.fem_bodies if b.name == "sheet")


def run(scene: Scene, duration: float = 0.2, record=None) -> dict:
    """The beam's displacements (full or reduced) and the sheet's, every step."""
    MODEL.drive(scene, SCHEDULE)
    reduced = next(iter(scene.reduced_bodies), None)
    beam = MODEL.fem_body_or_full(scene)
    n = ndofs(beam)
    record = dict(record or {})
    record["beam"] = (
        (lambda s: reduced.nodal_displacement().copy())
        if reduced
        else (lambda s: beam.u.x.array[:n].copy())
    )
    record["sheet"] = lambda s: slave_of(s).u.x.array.copy()
    return simulate(scene, duration, DT, record=record, progress=False).records


@pytest.mark.parametrize("make", [beam_with_a_sheet, hinged_beam_with_a_sheet])
def test_every_snapshot_and_point_reproduce_the_beam_and_its_sheet(make, tmp_path):
    model = ReducibleScene(make.__name__, make, "fem", {"model": make.__name__})
    reduced = reduce(
        model,
        TRAINING,
        basis=Basis("pod", 2 * 20),
        points=Points(sampling="all"),
        cache=tmp_path,
        progress=False,
    )
    full = run(make())
    scene = reduced.scene()
    (body,) = scene.reduced_bodies
    (attachment,) = scene.embedded_attachments
    assert [b.name for b in scene.fem_bodies] == ["sheet"]
    assert attachment.name == "membrane" and attachment.master is body
    assert attachment.slave is slave_of(scene)
    if make is hinged_beam_with_a_sheet:
        assert [a.name for a in scene.lift_attachments] == ["end"]
        assert np.abs(attachment.jacobian()[:, body.r - 12 :]).max() > 0.1  # on the lift
    red = run(scene)
    for part in ("beam", "sheet"):
        scale = np.abs(full[part]).max()
        assert scale > 0.05
        assert np.abs(red[part] - full[part]).max() < 1e-6 * scale


def test_a_small_basis_carries_the_sheet_exactly_and_feels_its_mass(tmp_path):
    reduced = reduce(
        MODEL,
        TRAINING,
        basis=Basis("pod", 4),
        points=Points(sampling="all"),
        cache=tmp_path,
        progress=False,
    )
    scene = reduced.scene()
    (body,) = scene.reduced_bodies
    (att,) = scene.embedded_attachments
    X_m = body.full.V.tabulate_dof_coordinates().ravel()
    X_s = att.slave.V.tabulate_dof_coordinates().ravel()

    def gap(s):  # |x_s - (W x_m + c)|, x_m from u = u_bar + U q on every node
        return np.abs(
            X_s + att.slave.u.x.array - att.W @ (X_m + body.nodal_displacement()) - att.offset
        ).max()

    red = run(scene, record={"gap": gap})
    assert np.abs(red["sheet"]).max() > 0.05
    assert np.max(red["gap"]) < 1e-12
    assert max(scene.attachment_errors().values()) < 1e-12

    # the sheet acts on q through G = W U: gravity and stiffness forces, mass and stiffness
    G = att.W @ body.U
    att.slave.assemble(tangent=False)
    f_s = -att.slave.R.array.copy()
    assert np.abs(f_s).max() > 0
    F_m = scene.master_forces()
    assert np.abs(F_m - (body.force() + G.T @ f_s)).max() < 1e-10 * np.abs(F_m).max()
    h = DT
    A_m = scene.step_matrix(h).toarray()
    A_s, b, applied = step_system(att.slave, h)
    indptr, indices, data = A_s.getValuesCSR()
    A_s = np.zeros((G.shape[0], G.shape[0]))
    A_s[np.repeat(np.arange(G.shape[0]), np.diff(indptr)), indices] = data
    b.destroy(), applied.destroy()
    expected = reduced_step_system(body, h, True)[0] + G.T @ A_s @ G
    assert np.abs(A_m - expected).max() < 1e-10 * np.abs(expected).max()
    assert np.abs(G.T @ A_s @ G).max() > 1e-3 * np.abs(expected).max()

    # a heavier sheet (the same reduced model put into a scene built with it) changes the
    # reduced beam's motion as it changes the full beam's, in part: the 4 POD vectors were
    # trained with the light sheet. Measured: the full beam's largest change 21.0 mm, the
    # reduced beam's 14.9 mm (0.707 of it), the reduced heavy run 13.2 mm off the full one;
    # each within 1.25 times (the ratio either way)
    heavy = beam_with_a_sheet(density=10000.0)
    reduced.put_in(heavy)
    red_heavy = run(heavy)["beam"]
    full_light = run(beam_with_a_sheet())["beam"]
    full_heavy = run(beam_with_a_sheet(density=10000.0))["beam"]
    ratio = np.abs(red_heavy - red["beam"]).max() / np.abs(full_heavy - full_light).max()
    assert 0.707 / 1.25 < ratio < min(1.25 * 0.707, 1.0)
    assert np.abs(red_heavy - full_heavy).max() < 1.25 * 0.01319


def test_the_static_tangent_through_the_sheet_and_the_lift_matches_finite_differences(tmp_path):
    """The hinged beam reduced (r = 4 + 12 lift columns): the sheet's forces reach the
    bone's lever stiffness through (W U)^T on the lift columns."""
    model = ReducibleScene("hinged", hinged_beam_with_a_sheet, "fem", {"model": "hinged"})
    scene = reduce(
        model,
        TRAINING,
        basis=Basis("pod", 4),
        points=Points(sampling="all"),
        cache=tmp_path,
        progress=False,
    ).scene()
    rng = np.random.default_rng(0)
    n = scene.master_count()
    assert n == 4 + 6
    dq0 = np.zeros(n)
    dq0[:4] = 0.1 * rng.standard_normal(4)
    scene.displace_masters(dq0)  # deformed, so the forces are not zero
    K = scene.static_tangent()
    for part in ("all", "rotation"):
        dq = 1e-3 * rng.standard_normal(n)
        if part == "rotation":
            dq[:-3] = 0.0
        fd = master_force_difference(scene, dq, 1e-4)
        assert np.abs(fd + K @ dq).max() < 1e-7 * np.abs(K @ dq).max()


def test_the_slave_of_an_embedded_attachment_is_refused_before_any_training(tmp_path):
    build = Builds(beam_with_a_sheet)
    rest = Training({"rest": ExcitationSchedule(np.array([0.0, 0.2]), {})}, 0.2, DT)
    with pytest.raises(
        InputError,
        match="embedded attachment 'membrane' embeds 'sheet' in 'fem': its slave cannot be reduced",
    ):
        reduce(ReducibleScene("sheet", build, "sheet", {}), rest, cache=tmp_path, progress=False)
    assert build.count == 1 and not list(tmp_path.glob("*.npz"))
    # and a reduced body of another body is not one the attachment can follow
    scene = beam_with_a_sheet()
    (att,) = scene.embedded_attachments
    reduced = reduce(
        MODEL,
        TRAINING,
        basis=Basis("pod", 2),
        points=Points(sampling="all"),
        cache=tmp_path,
        progress=False,
    )
    other = reduced.body(make_body(excitation=0.0, comm=MPI.COMM_SELF))
    with pytest.raises(InputError, match="is not a reduced body of its master 'fem'"):
        att.onto_reduced(other, None)


def test_the_masseter_with_two_bones_and_embedded_aponeuroses_reduces(tmp_path):
    from artifem.models.masseter.model import COARSE, MasseterConfig, build_model
    from artifem.scene import simulate

    config = MasseterConfig(**COARSE)
    model = ReducibleScene(
        "masseter",
        lambda: build_model(config, "conforming", "embedded").scene,
        "masseter (conforming)",
        {"model": "masseter"},
    )
    schedule = ExcitationSchedule.ramp_and_hold({"masseter": 0.8}, 0.05)
    training = Training({"ramp": schedule}, duration=0.1, dt=0.01, snapshot_every=1)
    reduced = reduce(
        model,
        training,
        basis=Basis("pod", 10),
        points=Points(sampling="all"),
        cache=tmp_path,
        progress=False,
    )
    jaw, arch = reduced.carriers  # each lift holds the other's nodes
    for mine, other in ((jaw.lift, arch.lift), (arch.lift, jaw.lift)):
        rows = (3 * other.dofs[:, None] + np.arange(3)).ravel()
        assert np.abs(mine.columns[rows]).max() == 0.0

    def run(scene):
        model.drive(scene, schedule)
        body = model.fem_body_or_full(scene)
        red = next(iter(scene.reduced_bodies), None)
        n = 3 * body.V.dofmap.index_map.size_local
        record = {
            "u": (lambda s: red.nodal_displacement().copy())
            if red
            else (lambda s: body.u.x.array[:n].copy()),
            "attached": lambda s: max(s.attachment_errors().values()),
        }
        return simulate(scene, 0.1, 0.01, record=record, progress=False).records

    full = run(model.build())
    scene = reduced.scene()
    assert sorted(a.name for a in scene.lift_attachments) == ["arch origin", "jaw insertion"]
    assert len(scene.embedded_attachments) == 3
    red = run(scene)
    scale = np.abs(full["u"]).max()
    assert scale > 1e-4
    assert np.abs(red["u"] - full["u"]).max() < 1e-6 * scale
    assert red["attached"].max() < 1e-12
