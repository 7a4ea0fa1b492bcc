"""The distributed (Schur) island: FEM bodies carried by rigid bodies with distributed FEM
blocks (artifem.scene.schur_island).

(1) Serial: the Schur step equals the direct KKT step on a scene with every supported
    part (a beam whose end rides on a hinged bone that turns onto its limit, a second bone
    welded to the first carrying more nodes, a spring from the world to the bone, gravity)
    to round-off with MUMPS (measured 7e-16); and on a smaller scene whose bone is tied by
    a damped spring to a moving prescribed body (known velocities z_k in the right-hand
    side). The Schur island with the default iterative solver (DEFAULT_METHOD) is checked
    against MUMPS, within the bound its rtol implies, in tests/test_default_solver.py
    (test_schur_island_agrees_with_mumps): the FEM block solves are the same there, the
    joints, limit and springs act on the small dense master system.
(2) 2 MPI ranks: the same script under ``mpiexec -n 2`` (the Schur island is the
    default there) equals the serial direct step.
(3) What it does not cover yet is a clear error.
"""

import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import artifem as af  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.errors import InputError

MPIEXEC = Path(sys.executable).parent / "mpiexec"

#: The scene, as a script: the test imports it in serial and runs it under mpiexec.
SCENE = textwrap.dedent('''
    import numpy as np
    import artifem as af  # noqa: F401  (before dolfinx)
    from dolfinx import mesh as dmesh
    from mpi4py import MPI


    def build(comm, island_solver=None, linear_solver="mumps"):
        """A soft beam clamped at x = 0; its far end rides on a bone hinged at the world
        (a limit), a second bone welded to the first carries the beam's top nodes near
        the end, a spring pulls the bone up."""
        L, W, H = 1.0, 0.2, 0.2
        box = dmesh.create_box(comm, [np.zeros(3), np.array([L, W, H])], [8, 2, 2],
                               dmesh.CellType.hexahedron)
        beam = af.FemBody(box, af.NeoHookean.from_young_poisson(2e4, 0.3), 1000.0,
                          rayleigh=(0.5, 0.002), name="beam")
        beam.fix_nodes(beam.find_nodes(lambda x: x[0] < 1e-12))
        bone = af.RigidBody("bone", 2.0, 0.05 * np.eye(3), position=(L + 0.1, 0.1, 0.1))
        plate = af.RigidBody("plate", 0.5, 0.01 * np.eye(3), position=(0.85, 0.1, 0.25))
        hinge = af.RevoluteJoint.at_world(bone, None, (L + 0.3, 0.1, 0.1),
                                          af.axis_rotation((0, 1, 0)), limits=(-0.05, 0.05),
                                          name="hinge")
        weld = af.RigidAttachment(plate, bone)
        end = af.NodeAttachment(beam, beam.find_nodes(lambda x: x[0] > L - 1e-9), bone)
        top = af.NodeAttachment(beam, beam.find_nodes(
            lambda x: (np.abs(x[0] - 0.875) < 1e-9) & (x[2] > H - 1e-9)), plate)
        spring = af.FramePath(af.AxialSpring(300.0, rest_length=0.1, damping=1.0),
                              [af.Frame(None, (L + 0.1, 0.1, 0.5)),
                               af.Frame.at_world(bone, (L + 0.1, 0.1, 0.1))])
        scene = af.Scene(gravity=(0, 0, -9.81), linear_solver=linear_solver,
                         island_solver=island_solver)
        scene.add(beam, bone, plate, hinge, weld, end, top, spring)
        return scene, beam, bone


    def run(scene, beam, bone, steps=12, h=0.01):
        for _ in range(steps):
            scene.step(h)
        rows = np.arange(beam.mesh.geometry.index_map().size_global)
        return {"u": beam.displacement_at(rows).tolist(), "bone": bone.position.tolist(),
                "angle": float(scene.joints[0].angle()), "ranks": beam.mesh.comm.size,
                "schur": scene._schur is not None, "energy": scene.energy()}
''')


@pytest.fixture(scope="module")
def scene_module(script_scene):
    return script_scene(SCENE, "schur_scene")


@pytest.fixture(scope="module")
def direct(scene_module):
    _, ns = scene_module
    return ns["run"](*ns["build"](MPI.COMM_SELF, island_solver="direct"))


def compare(result, reference, rtol):
    u, u_ref = np.array(result["u"]), np.array(reference["u"])
    scale = np.abs(u_ref).max()
    assert scale > 1e-3  # the beam moved
    assert np.abs(u - u_ref).max() <= rtol * scale
    assert np.abs(np.array(result["bone"]) - reference["bone"]).max() <= rtol * scale
    assert abs(result["angle"] - reference["angle"]) <= rtol * max(abs(reference["angle"]), 1e-3)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial comparison")
def test_schur_step_equals_the_direct_step(scene_module, direct):
    _, ns = scene_module
    schur = ns["run"](*ns["build"](MPI.COMM_SELF, island_solver="schur"))
    assert schur["schur"] and not direct["schur"]
    # the hinge turned onto its limit (from step 9 of 12; without it, -0.10 rad at the end)
    assert direct["angle"] == pytest.approx(-0.05, abs=1e-12)
    compare(schur, direct, 1e-9)


@pytest.mark.slow
@pytest.mark.skipif(not MPIEXEC.exists(), reason=f"no mpiexec next to the interpreter ({MPIEXEC})")
@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="launches its own ranks")
def test_two_ranks_equal_the_serial_direct_step(scene_module, direct, tmp_path, two_ranks):
    parallel = two_ranks(scene_module[0], tmp_path)
    assert parallel["ranks"] == 2 and parallel["schur"]
    compare(parallel, direct, 1e-8)
    assert parallel["energy"] == pytest.approx(direct["energy"], rel=1e-8)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial")
def test_what_the_schur_island_does_not_take_is_a_clear_error(scene_module):
    _, ns = scene_module
    scene, beam, bone = ns["build"](MPI.COMM_SELF, island_solver="schur")
    with pytest.raises(InputError, match="solve_static: not available with the distributed"):
        scene.solve_static()
    scene, beam, bone = ns["build"](MPI.COMM_SELF, island_solver="schur")
    scene.integrator = af.Scene(integrator="implicit").integrator
    with pytest.raises(InputError, match="steps semi-implicitly only"):
        scene.step(0.01)
    scene, beam, bone = ns["build"](MPI.COMM_SELF, island_solver="schur")
    scene.add(
        af.PointPath(
            af.AxialSpring(10.0),
            [af.FemPoint(beam, af.shape_function_weights(beam, (0.5, 0.1, 0.1))), (0.5, 0.1, 1.0)],
        )
    )
    with pytest.raises(InputError, match="also has point paths"):
        scene.step(0.01)
    scene, beam, bone = ns["build"](MPI.COMM_SELF, island_solver="schur")
    cam = af.RigidBody(
        "cam",
        1.0,
        np.eye(3),
        position=(0.5, 0.1, 0.3),
        motion="prescribed",
        trajectory=lambda t: ((0.5, 0.1, 0.3), np.eye(3), np.zeros(3), np.zeros(3)),
    )
    on_top = beam.find_nodes(lambda x: (np.abs(x[0] - 0.5) < 1e-9) & (x[2] > 0.2 - 1e-9))
    scene.add(cam, af.NodeAttachment(beam, on_top, cam, name="on the cam"))
    with pytest.raises(InputError, match="'on the cam': nodes on the prescribed body 'cam'"):
        scene.step(0.01)
    with pytest.raises(InputError, match="island_solver must be"):
        af.Scene(island_solver="lu")


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial comparison")
def test_schur_step_with_a_moving_prescribed_body_equals_the_direct_step():
    """A bone carrying the end of a clamped beam, tied by a damped spring to a prescribed
    body that moves (known velocities z_k != 0, coupled to the bone through the spring's
    stiffness and damping blocks): the Schur step's right-hand side P^T (b - A z_k) is the
    direct step's, so the two agree to round-off with MUMPS."""
    from dolfinx import mesh as dmesh

    from artifem.multibody.rigid_body import BodyState, exp_so3

    def trajectory(t):
        w = 3.0
        return BodyState(
            (0.9 + 0.1 * np.sin(w * t), 0.1, 0.6 - 0.1 * np.cos(w * t)),
            exp_so3((0.0, 0.0, 0.5 * t)),
            (0.1 * w * np.cos(w * t), 0.0, 0.1 * w * np.sin(w * t)),
            (0.0, 0.0, 0.5),
        )

    def build(island_solver):
        box = dmesh.create_box(
            MPI.COMM_SELF,
            [np.zeros(3), np.array([0.6, 0.2, 0.2])],
            [4, 2, 2],
            dmesh.CellType.hexahedron,
        )
        beam = af.FemBody(
            box,
            af.NeoHookean.from_young_poisson(2e4, 0.3),
            1000.0,
            rayleigh=(0.5, 0.002),
            name="beam",
        )
        beam.fix_nodes(beam.find_nodes(lambda x: x[0] < 1e-12))
        bone = af.RigidBody("bone", 2.0, 0.05 * np.eye(3), position=(0.7, 0.1, 0.1))
        p0, R0, _, _ = trajectory(0.0)
        anchor = af.RigidBody(
            "anchor",
            1.0,
            np.eye(3),
            position=p0,
            rotation=R0,
            motion="prescribed",
            trajectory=trajectory,
        )
        end = af.NodeAttachment(beam, beam.find_nodes(lambda x: x[0] > 0.6 - 1e-9), bone)
        spring = af.FramePath(
            af.AxialSpring(300.0, rest_length=0.2, damping=5.0),
            [af.Frame.at_world(anchor, (0.9, 0.1, 0.5)), af.Frame.at_world(bone, (0.7, 0.1, 0.1))],
        )
        scene = af.Scene(gravity=(0, 0, -9.81), linear_solver="mumps", island_solver=island_solver)
        scene.add(beam, bone, anchor, end, spring)
        for _ in range(6):
            scene.step(0.01)
        return scene, beam, bone

    schur, beam_s, bone_s = build("schur")
    direct, beam_d, bone_d = build("direct")
    assert schur._schur is not None and direct._schur is None
    u, u_ref = beam_s.u.x.array, beam_d.u.x.array
    assert np.abs(u_ref).max() > 1e-3  # the beam moved
    assert np.abs(u - u_ref).max() <= 1e-9 * np.abs(u_ref).max()
    v_ref = bone_d.velocity
    assert np.abs(bone_s.velocity - v_ref).max() <= 1e-9 * np.abs(v_ref).max()
    assert (
        np.abs(bone_s.angular_velocity - bone_d.angular_velocity).max()
        <= 1e-9 * np.abs(bone_d.angular_velocity).max()
    )
