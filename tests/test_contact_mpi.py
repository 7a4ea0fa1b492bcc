"""Contact under MPI (docs/contact.md, "Under mpiexec"): contacts between rigid bodies run
distributed, with FEM bodies carried by them; a contact that touches an FEM body is
refused by the distributed island before any work (tests/test_contact_plane.py).

The scene: a soft beam whose end nodes ride on a rigid bone (NodeAttachment); the bone,
a box with a surface, falls with the beam onto a fixed rigid block (MeshContact with
friction). Under ``mpiexec -n 2`` (the Schur island, the beam distributed) it equals the
serial direct step.
"""

import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import artifem as af  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

MPIEXEC = Path(sys.executable).parent / "mpiexec"

SCENE = textwrap.dedent('''
    import numpy as np
    import artifem as af  # noqa: F401  (before dolfinx)
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    CUBE = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


    def box(size):
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)],
                           dtype=float)
        return corners * np.asarray(size) / 2, CUBE


    def build(comm, island_solver=None):
        """A 0.6 m soft beam clamped at x = 0 whose far end rides on a 1 kg bone; the bone
        falls 2 mm onto a fixed block turned 0.2 rad about z."""
        beam = af.FemBody(dmesh.create_box(comm, [np.zeros(3), np.array([0.6, 0.1, 0.1])],
                                           [6, 2, 2], dmesh.CellType.hexahedron),
                          af.NeoHookean.from_young_poisson(5e4, 0.3), 1000.0,
                          rayleigh=(1.0, 0.002), name="beam")
        beam.fix_nodes(beam.find_nodes(lambda x: x[0] < 1e-12))
        bone = af.RigidBody("bone", 1.0, 0.002 * np.eye(3), position=(0.65, 0.05, 0.05),
                            surface=box([0.1, 0.1, 0.1]))
        block = af.RigidBody("block", 1.0, np.eye(3), position=(0.65, 0.05, -0.052),
                             motion="fixed", surface=box([0.2, 0.2, 0.1]))
        block.rotation = np.array([[np.cos(0.2), -np.sin(0.2), 0], [np.sin(0.2), np.cos(0.2), 0],
                                   [0, 0, 1.0]])
        end = af.NodeAttachment(beam, beam.find_nodes(lambda x: x[0] > 0.6 - 1e-9), bone)
        contact = af.MeshContact(bone, block, mu=0.4, tolerance=1e-6, margin=0.02,
                                 name="bone on block")
        scene = af.Scene(gravity=(0, 0, -9.81), linear_solver="mumps",
                         island_solver=island_solver)
        scene.add(beam, bone, block, end, contact)
        return scene, beam, bone, contact


    def run(scene, beam, bone, contact, steps=15, h=0.01):
        for _ in range(steps):
            scene.step(h)
        rows = np.arange(beam.mesh.geometry.index_map().size_global)
        forces = scene.contact_forces(contact)
        return {"u": beam.displacement_at(rows).tolist(), "bone": bone.position.tolist(),
                "resultant": forces.resultant.tolist(), "ranks": beam.mesh.comm.size,
                "schur": scene._schur is not None}
''')


@pytest.fixture(scope="module")
def scene_module(script_scene):
    return script_scene(SCENE, "contact_scene")


@pytest.fixture(scope="module")
def direct(scene_module):
    _, ns = scene_module
    return ns["run"](*ns["build"](MPI.COMM_SELF, island_solver="direct"))


def compare(result, reference, rtol):
    u, u_ref = np.array(result["u"]), np.array(reference["u"])
    scale = np.abs(u_ref).max()
    assert scale > 1e-3  # the beam sagged with the bone
    assert np.abs(u - u_ref).max() <= rtol * scale
    assert np.abs(np.array(result["bone"]) - reference["bone"]).max() <= rtol * scale
    np.testing.assert_allclose(
        result["resultant"],
        reference["resultant"],
        rtol=0,
        atol=rtol * np.abs(reference["resultant"]).max(),
    )


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial comparison")
def test_rigid_contact_with_carried_fem_in_the_schur_island_equals_the_direct_step(
    scene_module, direct
):
    _, ns = scene_module
    schur = ns["run"](*ns["build"](MPI.COMM_SELF, island_solver="schur"))
    assert schur["schur"] and not direct["schur"]
    assert np.array(direct["resultant"])[2] > 1.0  # the bone rests on the block
    compare(schur, direct, 1e-9)


@pytest.mark.slow
@pytest.mark.skipif(not MPIEXEC.exists(), reason=f"no mpiexec next to the interpreter ({MPIEXEC})")
@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="launches its own ranks")
def test_two_ranks_equal_the_serial_direct_step(scene_module, direct, tmp_path, two_ranks):
    parallel = two_ranks(scene_module[0], tmp_path)
    assert parallel["ranks"] == 2 and parallel["schur"]
    compare(parallel, direct, 1e-8)
