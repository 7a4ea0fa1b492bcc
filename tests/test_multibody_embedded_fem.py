"""FEM bodies embedded in FEM bodies, and load elements, in the coupled step.

(1) a twin embedded node-for-node (W = I) doubles mass, stiffness and load: the
    master moves exactly as it does alone, step by step;
(2) a non-matching slave inside a master follows any affine master displacement
    exactly (embedding weights reproduce affine fields);
(3) the static tangent through a chain (slave in a beam whose end rides on a
    free bone) matches finite differences, the slave's forces reaching the
    bone's lever stiffness through W^T;
(4) a load element's nodal force equals the same FEM nodal load, statically;
(5) bad input.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.fem_body import FemBody
from artifem.forms import NeoHookean
from artifem.multibody.attachments import EmbeddedFemAttachment, NodeAttachment
from artifem.scene import Scene
from artifem.multibody.rigid_body import RigidBody, exp_so3
from coupled_fd import master_force_difference

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")

G = 9.81


def box(lo, hi, cells, young=1e5, density=1000.0, name="fem", cell=dmesh.CellType.hexahedron):
    msh = dmesh.create_box(
        MPI.COMM_SELF, [np.asarray(lo, float), np.asarray(hi, float)], list(cells), cell
    )
    return FemBody(
        msh,
        NeoHookean.from_young_poisson(young, 0.3),
        density,
        rayleigh=(0.3, 0.002),
        gravity=(0, 0, -G),
        name=name,
    )


def beam(name="beam"):
    body = box((0, 0, 0), (1.0, 0.2, 0.2), (8, 2, 2), name=name)
    body.fix_nodes(body.find_nodes(lambda x: x[0] < 1e-12))
    return body


def test_embedded_twin_doubles_everything_and_changes_nothing():
    """The beam alone is an island of its own (SemiImplicitEuler, MUMPS); with the twin
    it is the coupled island's master (the layout's step). Measured: max |u_with_twin -
    u_alone| = 3e-17 m on 0.15 m after 20 steps."""
    alone = beam()
    scene_alone = Scene(gravity=(0, 0, -G), linear_solver="mumps")
    scene_alone.add(alone)
    assert scene_alone.islands() == ([alone], [])
    master = beam()
    twin = box((0, 0, 0), (1.0, 0.2, 0.2), (8, 2, 2), name="twin")
    scene = Scene(gravity=(0, 0, -G))
    scene.add(master, twin, EmbeddedFemAttachment(twin, master))
    n_nodes = master.u.x.array.size // 3
    assert scene.master_count() == 3 * (n_nodes - master.fixed_dofs.size)
    for _ in range(20):
        scene_alone.step(0.01)
        scene.step(0.01)
    u = alone.u.x.array
    assert np.abs(u).max() > 0.05
    assert np.abs(master.u.x.array - u).max() < 1e-12 * np.abs(u).max()
    X_t = twin.V.tabulate_dof_coordinates()
    x_master_at = master.V.tabulate_dof_coordinates() + master.u.x.array.reshape(-1, 3)
    order = np.lexsort(X_t.T)  # twin and master nodes pair up by position
    assert (
        np.abs(
            (X_t + twin.u.x.array.reshape(-1, 3))[order]
            - x_master_at[np.lexsort(master.V.tabulate_dof_coordinates().T)]
        ).max()
        < 1e-13
    )
    assert (
        abs(scene.kinetic_energy() - 2 * scene_alone.kinetic_energy())
        < 1e-10 * scene_alone.kinetic_energy()
    )


def test_non_matching_slave_follows_an_affine_master_field_exactly():
    master = box((0, 0, 0), (1.0, 0.5, 0.4), (5, 3, 2))
    slave = box(
        (0.13, 0.07, 0.11),
        (0.81, 0.33, 0.29),
        (4, 3, 3),
        name="slab",
        cell=dmesh.CellType.tetrahedron,
    )
    att = EmbeddedFemAttachment(slave, master)
    scene = Scene()
    scene.add(master, slave, att)
    A, c = (
        np.array([[0.1, -0.3, 0.2], [0.05, 0.02, -0.4], [0.3, 0.1, 0.0]]),
        np.array([0.01, -0.02, 0.03]),
    )
    X = master.V.tabulate_dof_coordinates()
    dq = (X @ A.T + c).ravel()
    scene.displace_masters(dq)
    Xs = slave.V.tabulate_dof_coordinates()
    assert np.abs(slave.u.x.array.reshape(-1, 3) - (Xs @ A.T + c)).max() < 1e-14
    assert np.all(att.distance == 0.0)


def test_static_tangent_through_an_embedded_chain_matches_finite_differences():
    """Slave in a beam whose end nodes ride on a free bone (K_geo sees the slave's forces
    through W^T)."""
    rng = np.random.default_rng(0)
    master = box((0, 0, 0), (0.3, 0.1, 0.1), (4, 2, 2), young=2e4)
    master.fix_nodes(master.find_nodes(lambda x: x[0] > 0.3 - 1e-12))
    slave = box(
        (0.02, 0.01, 0.02),
        (0.2, 0.09, 0.08),
        (3, 2, 2),
        young=5e4,
        name="slave",
        cell=dmesh.CellType.tetrahedron,
    )
    b = RigidBody(
        "bone",
        0.5,
        np.diag([1e-3, 2e-3, 2.5e-3]),
        position=(-0.03, 0.05, 0.05),
        rotation=exp_so3([0.3, -0.2, 0.5]),
    )
    scene = Scene(gravity=(0, 0, -G))
    scene.add(master, slave, b, EmbeddedFemAttachment(slave, master))
    scene.add(NodeAttachment(master, master.find_nodes(lambda x: x[0] < 1e-12), b))
    dq0 = 0.005 * rng.standard_normal(scene.master_count())
    dq0[-6:] = 0.0
    scene.displace_masters(dq0)  # deformed, so the forces are not zero
    n = scene.master_count()
    K = scene.static_tangent()
    for part in ("all", "rotation"):
        dq = 1e-3 * rng.standard_normal(n)
        if part == "rotation":
            dq[:-3] = 0.0
        eps = 1e-4
        fd = master_force_difference(scene, dq, eps)
        assert np.abs(fd + K @ dq).max() < 1e-7 * np.abs(K @ dq).max()


class TipLoad:
    """A constant force on some nodes of a FEM body (a LoadElement)."""

    def __init__(self, body, nodes, force):
        self.body, self.force = body, np.asarray(force, float)
        self.dofs = body.local_dofs(nodes)
        self.bodies = (body,)

    def master_loads(self, t):
        f = np.zeros(self.body.v.x.array.size)
        f.reshape(-1, 3)[self.dofs] = self.force
        return [(self.body, f)]


def test_load_element_equals_the_fem_nodal_load():
    with_load, with_element = beam(), beam()
    tip = with_load.find_nodes(lambda x: x[0] > 1.0 - 1e-12)
    with_load.add_nodal_load(tip, [0.0, 2.0, -1.0])
    s1, s2 = Scene(gravity=(0, 0, -G)), Scene(gravity=(0, 0, -G))
    s1.add(with_load)
    s2.add(with_element, TipLoad(with_element, tip, [0.0, 2.0, -1.0]))
    s1.solve_static()
    s2.solve_static()
    u = with_load.u.x.array
    assert np.abs(u).max() > 0.01
    assert np.abs(with_element.u.x.array - u).max() < 1e-9 * np.abs(u).max()


def test_bad_embedding_and_loads_are_clear_errors():
    master = beam()
    outside = box((0.9, 0.0, 0.0), (1.2, 0.2, 0.2), (2, 1, 1), name="outside")
    with pytest.raises(ValueError, match="outside"):
        EmbeddedFemAttachment(outside, master)
    snapped = EmbeddedFemAttachment(outside, master, snap=True)
    assert snapped.distance.max() == pytest.approx(0.2)
    with pytest.raises(ValueError, match="itself"):
        EmbeddedFemAttachment(master, master)
    slave = box((0.1, 0.05, 0.05), (0.5, 0.15, 0.15), (2, 1, 1), name="slave")
    scene = Scene()
    scene.add(master, EmbeddedFemAttachment(slave, master))
    with pytest.raises(ValueError, match="not in the scene"):
        scene.check()
    scene.add(slave)
    slave.fix_nodes(slave.find_nodes(lambda x: x[0] < 0.1 + 1e-12))
    with pytest.raises(ValueError, match="fixed nodes"):
        scene.check()
    a, b = (
        box((0, 0, 0), (1, 1, 1), (1, 1, 1), name="a"),
        box((0, 0, 0), (1, 1, 1), (1, 1, 1), name="b"),
    )
    loop = Scene()
    loop.add(a, b, EmbeddedFemAttachment(a, b), EmbeddedFemAttachment(b, a))
    with pytest.raises(ValueError, match="cycle"):
        loop.check()
    scene2 = Scene()
    other = beam("other")
    scene2.add(master, TipLoad(other, [0], [1.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="not a body of this scene"):
        scene2.step(0.01)
