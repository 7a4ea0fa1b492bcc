"""Contact of a rigid body's points and an FEM body's boundary nodes with a fixed plane
(artifem.multibody.contact): hard normal rows and Coulomb friction in the step's KKT.

(1) a rigid box dropped flat on a horizontal plane: no rebound, the normal force at rest
    equals m g to 1e-9, no penetration beyond round-off (the contacts' tolerance is 1e-6
    throughout: a deeper step is refused, so the tests bound the measured depth instead),
    the same active rows and forces for 1,000 steps at rest;
(2) a rigid box on a 30-degree incline: mu = 0.6 sticks (slip < 1e-9 m over 1 s), mu = 0.5
    slides with g (sin 30 - mu cos 30) = 0.657 m/s^2 to 1e-3 (semi-implicit and implicit);
(3) a 4 x 4 x 4 neo-Hookean block dropped on the plane: it joins the coupled island, comes
    to rest, the sum of its nodes' normal forces equals its weight to 1e-9, no node below
    the plane beyond round-off at any step; on the incline, once settled, mu = 0.6
    sticks (slip < 1e-9 m over 1 s) and mu = 0.5 slides with g (sin 30 - mu cos 30);
(4) statics: a clamped beam's free end rests on the plane, the contact and the clamp
    carrying its weight; with friction, the nodes that
    stick did not move over the load increment and the others slid against their force;
(5) a point that comes from beyond the margin within one step fails the step (clear
    message); bad input before the run.
"""

import numpy as np
import pytest

import artifem as af  # (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.errors import InputError, StepFailed
from outputs import read_series, same_rows

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")

G, H = 9.81, 0.01
SIZE = np.array([0.2, 0.2, 0.1])  # the box (m), 2 kg
MASS = 2.0
CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * SIZE / 2
TOL = 1e-6


def rigid_box(**kwargs):
    a, b, c = SIZE
    inertia = MASS / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    return af.RigidBody("box", MASS, inertia, **kwargs)


def scene_of(*items, **kwargs):
    scene = af.Scene(gravity=(0.0, 0.0, -G), **kwargs)
    scene.add(*items)
    return scene


def fem_block(lift=0.0, name="block", rotation=np.eye(3), rayleigh=(10.0, 1e-3)):
    """A 0.1 m neo-Hookean cube of 4 x 4 x 4 hexahedra, 1 kg, its bottom face at z = lift
    (then turned by ``rotation`` about the origin)."""
    msh = dmesh.create_box(
        MPI.COMM_SELF,
        [np.array([0.0, 0.0, lift]), np.array([0.1, 0.1, 0.1 + lift])],
        [4, 4, 4],
        dmesh.CellType.hexahedron,
    )
    msh.geometry.x[:] = msh.geometry.x @ rotation.T
    return af.FemBody(
        msh, af.NeoHookean.from_young_poisson(1e5, 0.3), 1000.0, rayleigh=rayleigh, name=name
    )


def heights(body):
    return (body.V.tabulate_dof_coordinates() + body.u.x.array.reshape(-1, 3))[:, 2]


def bottom_dofs(body):
    """The dofs of the nodes on the block's lowest face (reference configuration)."""
    z = body.V.tabulate_dof_coordinates()[:, 2]
    return np.flatnonzero(np.isclose(z, z.min()))


# ---- (1) a rigid box dropped on a horizontal plane -----------------------------------------


def test_rigid_box_dropped_on_a_plane_comes_to_rest_without_rebound():
    """Dropped flat from 5 cm (1 m/s at impact, 0.01 m per step; margin 5 cm): it lands in
    the step that reaches the plane and stops (an inelastic impact). Measured: no rebound
    (height after impact = rest height, exactly), |sum N / (m g) - 1| = 0 after the impact
    step, penetration at most 7e-18 m (bound 1e-12), 2 active normal rows (of the 4 bottom
    corners: the impulses of the redundant rows are indeterminate) and the same forces for
    1,000 steps."""
    box = rigid_box(position=(0.0, 0.0, SIZE[2] / 2 + 0.05))
    contact = af.PlaneContact(
        box, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), points=CORNERS, tolerance=TOL, margin=0.05
    )
    scene = scene_of(box, contact)
    rest = SIZE[2] / 2
    landed, lowest = None, []
    for k in range(60):
        scene.step(H)
        lowest.append(contact.distances().min())
        if landed is None and box.position[2] - rest < 1e-12:
            landed = k
        if landed is not None:  # no rebound
            assert abs(box.position[2] - rest) < 1e-12
    assert min(lowest) >= -1e-12
    assert landed is not None and landed < 15
    first = scene.contact_forces(contact)
    np.testing.assert_array_equal(np.sort(first.points), [0, 2, 4, 6])  # the bottom corners
    active = first.normal > 0
    rows = scene.last_solve["constraint_rows"]
    for _ in range(1000):
        scene.step(H)
        forces = scene.contact_forces(contact)
        np.testing.assert_array_equal(forces.points, first.points)
        np.testing.assert_array_equal(forces.normal > 0, active)
        assert scene.last_solve["constraint_rows"] == rows
        assert abs(forces.normal.sum() / (MASS * G) - 1.0) < 1e-9
        assert np.all(forces.normal >= 0.0) and not forces.friction.any()
        assert abs(box.position[2] - rest) < 1e-12
    assert contact.distances().min() >= -1e-12
    assert np.abs(box.twist).max() < 1e-12


# ---- (2) a rigid box on a 30-degree incline -----------------------------------------------

THETA = np.radians(30.0)
NORMAL = np.array([-np.sin(THETA), 0.0, np.cos(THETA)])
UPHILL = np.array([np.cos(THETA), 0.0, np.sin(THETA)])  # t_1 of the plane


@pytest.mark.parametrize("integrator", ["semi-implicit", "implicit"])
@pytest.mark.parametrize("mu", [0.6, 0.5])
def test_rigid_box_on_an_incline_sticks_or_slides_with_coulomb_friction(mu, integrator):
    """At rest on the incline for 1 s (100 steps): tan 30 = 0.577 < 0.6 sticks (measured
    slip below 1e-16 m), 0.5 slides along the slope with g (sin 30 - mu cos 30) = 0.6571 m/s^2
    (measured to 2e-15 relative: the friction bound takes the normal impulses of the same
    step, so the first step slides with friction too). The normal force is m g cos 30. The
    box neither sinks nor lifts: measured 3e-17 m below the plane at most, and the slip
    along the normal 3e-17 m; the bounds are 1e-12."""
    box = rigid_box(
        position=NORMAL * SIZE[2] / 2, rotation=np.column_stack([UPHILL, [0.0, 1.0, 0.0], NORMAL])
    )
    contact = af.PlaneContact(
        box, (0.0, 0.0, 0.0), NORMAL, mu=mu, points=CORNERS, tolerance=TOL, margin=0.05
    )
    scene = scene_of(box, contact, integrator=integrator)
    start = box.position.copy()
    for _ in range(100):
        scene.step(H)
    forces = scene.contact_forces(contact)
    assert abs(forces.normal.sum() / (MASS * G * np.cos(THETA)) - 1.0) < 1e-9
    slip = box.position - start
    if mu == 0.6:
        assert np.linalg.norm(slip) < 1e-9
        np.testing.assert_allclose(
            forces.friction.sum(axis=0) @ UPHILL, MASS * G * np.sin(THETA), rtol=1e-9
        )
    else:
        a = G * (np.sin(THETA) - mu * np.cos(THETA))
        assert abs(a - 0.657) < 1e-3
        assert abs(-box.velocity @ UPHILL / (100 * H) / a - 1.0) < 1e-3
        assert abs(slip @ NORMAL) < 1e-12 and abs(slip[1]) < 1e-12
        np.testing.assert_allclose(
            forces.friction.sum(axis=0) @ UPHILL, mu * MASS * G * np.cos(THETA), rtol=1e-9
        )
    assert contact.distances().min() >= -1e-12


# ---- (3) an FEM block dropped on the plane -------------------------------------------------


def test_fem_block_dropped_on_a_plane_comes_to_rest_on_its_bottom_nodes():
    """A 0.1 m cube (1 kg, E = 1e5 Pa, Rayleigh (10, 1e-3)) dropped from 1 cm: the contact
    puts it in the coupled island; its 25 bottom nodes take rows and it comes to rest.
    Measured: |sum N / (m g) - 1| <= 6e-16 and max |v| <= 5e-16 m/s at every 100th step
    from 1.5 s to 10.5 s (a run of 1,050 steps), lowest node at -2e-18 m over all steps
    (bound 1e-12); the same 25 active rows from step 50 to the end (3 s here), one trial
    of the warm-started active set per step, and no rebound (the bottom nodes stay on the
    plane: within 2e-18 m, bound 1e-12)."""
    block = fem_block(lift=0.01)
    contact = af.PlaneContact(block, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), tolerance=TOL, margin=0.02)
    scene = scene_of(block, contact)
    assert scene.islands() == ([], [block])
    weight = block.total_mass() * G
    lowest = []
    for k in range(300):
        scene.step(H)
        lowest.append(heights(block).min())
        if k >= 50:
            forces = scene.contact_forces(contact)
            assert np.count_nonzero(forces.normal > 0) == 25
            assert scene.last_solve["constraint_rows"] == 25
            assert scene.last_solve["trials"] == 1
            assert np.abs(heights(block)[bottom_dofs(block)]).max() < 1e-12
    assert min(lowest) >= -1e-12
    bottom = np.flatnonzero(np.isclose(block.mesh.geometry.x[:, 2], 0.01))
    np.testing.assert_array_equal(
        np.sort(forces.points), np.sort(block.mesh.geometry.input_global_indices[bottom])
    )
    assert abs(forces.normal.sum() / weight - 1.0) < 1e-9
    assert np.abs(block.v.x.array).max() < 1e-9


@pytest.mark.parametrize("mu", [0.6, 0.5])
def test_fem_block_on_an_incline_sticks_or_slides_once_settled(mu):
    """The cube put undeformed on the incline (stiffness damping only: mass damping would
    brake the sliding) settles within 0.5 s: its uphill edge lifts (20 of 25 bottom nodes
    press) and the low-pressure nodes slip locally while it settles. Then mu = 0.6 holds:
    the bottom nodes slip 8e-11 m from 1 s to 2 s (measured); mu = 0.5 slides: the mean
    velocity gains g (sin 30 - mu cos 30) per second from 0.5 s to 1 s (measured to 1e-9).
    No node goes below the plane by more than 2.2e-17 m (measured; the bound is 1e-12)."""
    turn = np.column_stack([UPHILL, [0.0, 1.0, 0.0], NORMAL])
    block = fem_block(rotation=turn, rayleigh=(0.0, 1e-3))
    contact = af.PlaneContact(block, (0.0, 0.0, 0.0), NORMAL, mu=mu, tolerance=TOL, margin=0.02)
    scene = scene_of(block, contact)
    mass = block.total_mass()
    bottom = np.flatnonzero(np.abs(block.V.tabulate_dof_coordinates() @ NORMAL) < 1e-12)
    assert bottom.size == 25

    lowest = []

    def run(steps):
        for _ in range(steps):
            scene.step(H)
            lowest.append(contact.distances().min())

    if mu == 0.6:
        run(100)
        settled = block.u.x.array.reshape(-1, 3)[bottom].copy()
        run(100)
        assert np.abs(block.u.x.array.reshape(-1, 3)[bottom] - settled).max() < 1e-9
    else:
        run(50)
        v0 = scene.momentum() @ UPHILL / mass
        run(50)
        a = G * (np.sin(THETA) - mu * np.cos(THETA))
        assert abs((v0 - scene.momentum() @ UPHILL / mass) / (50 * H) / a - 1.0) < 1e-3
    assert min(lowest) >= -1e-12
    forces = scene.contact_forces(contact)
    assert np.count_nonzero(forces.normal > 0) == 20
    assert abs(forces.normal.sum() / (mass * G * np.cos(THETA)) - 1.0) < 1e-6


# ---- (4) statics ----------------------------------------------------------------------------


def cantilever():
    """A 0.3 x 0.03 x 0.03 m beam (E = 1e6 Pa, 10 x 2 x 2 hexahedra) clamped at x = 0."""
    msh = dmesh.create_box(
        MPI.COMM_SELF,
        [np.zeros(3), np.array([0.3, 0.03, 0.03])],
        [10, 2, 2],
        dmesh.CellType.hexahedron,
    )
    body = af.FemBody(msh, af.NeoHookean.from_young_poisson(1e6, 0.3), 1000.0, name="beam")
    body.fix_nodes(body.find_nodes(lambda x: np.isclose(x[0], 0.0)))
    return body


def test_static_cantilever_rests_its_free_end_on_the_plane():
    """A clamped 0.3 m beam (E = 1e6 Pa) whose free equilibrium sags 8.5 cm, over a plane
    1 cm below it: the static solve (the contact's rows in the Newton's active set, rows
    entering the margin between iterations) leaves every node at or above the plane
    (measured: the lowest 3.5e-18 m below; the bound is 1e-12), only nodes on it press
    (measured: 6 nodes of the free end, 0.9042879 N of the 2.6487 N weight, pinned to
    rel 1e-6), and the contact forces are the static solve's: with the clamp's reaction
    (the residual dPi/du at the fixed nodes) they carry the weight (measured to 2e-16;
    the bound is 1e-9)."""
    free = cantilever()
    scene_of(free).solve_static()
    assert heights(free).min() < -0.05
    body = cantilever()
    contact = af.PlaneContact(body, (0.0, 0.0, -0.01), (0.0, 0.0, 1.0), tolerance=TOL, margin=0.03)
    scene = scene_of(body, contact)
    scene.solve_static(load_steps=4)
    phi = contact.distances()
    assert phi.min() >= -1e-12
    forces = scene.contact_forces(contact)
    pressing = forces.points[forces.normal > 1e-9]
    assert pressing.size >= 2
    on_plane = contact.labels[phi < 1e-12]
    assert set(pressing.tolist()) <= set(on_plane.tolist())
    assert np.all(forces.normal >= -1e-12)
    weight = body.total_mass() * G
    body.assemble(tangent=False)  # R = dPi/du: the clamp's reaction at its fixed nodes
    clamp = body.R.array.reshape(-1, 3)[body.fixed_dofs, 2].sum()
    assert forces.normal.sum() + clamp == pytest.approx(weight, rel=1e-9)
    assert forces.normal.sum() == pytest.approx(0.9042878782, rel=1e-6)


def test_static_friction_sticks_to_where_the_increment_found_the_point():
    """The same beam over the plane with friction (mu = 0.3), its load in one increment:
    statics' Coulomb law holds over the increment (IncrementSlip): every pressing node
    whose friction force is inside the pyramid did not move along the plane (measured
    1e-18 m; 0.2 mm when sticking was asked of each Newton correction, where the iterates
    had left the node), and every other one slid against its friction force."""
    mu = 0.3
    body = cantilever()
    contact = af.PlaneContact(
        body, (0.0, 0.0, -0.01), (0.0, 0.0, 1.0), mu=mu, tolerance=TOL, margin=0.03
    )
    scene = scene_of(body, contact)
    start = contact._points.positions().copy()
    scene.solve_static(load_steps=1)
    forces = scene.contact_forces(contact)
    index = {int(label): i for i, label in enumerate(contact.labels)}
    at = np.array([index[int(p)] for p in forces.points])
    slip = (contact._points.positions()[at] - start[at]) @ contact.tangents.T
    friction = forces.friction @ contact.tangents.T
    pressing = (forces.normal > 1e-9)[:, None] & np.ones((1, 2), dtype=bool)
    sticking = pressing & (np.abs(friction) < (1.0 - 1e-6) * mu * forces.normal[:, None])
    sliding = pressing & ~sticking
    assert sticking.any() and sliding.any()
    assert np.abs(slip[sticking]).max() < 1e-12
    assert np.all(slip[sliding] * friction[sliding] < 0)


# ---- (5) failures and bad input ------------------------------------------------------------


def test_a_point_from_beyond_the_margin_fails_the_step_with_a_clear_message():
    """1 m/s at 1 cm per step against a 1 mm margin: the corners cross the plane by up to
    0.01 m within a step that had no rows for them; with no fallback and no halving the
    step fails and says what to change."""
    box = rigid_box(position=(0.0, 0.0, SIZE[2] / 2 + 0.002), velocity=(0.0, 0.0, -1.0))
    contact = af.PlaneContact(
        box, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), points=CORNERS, tolerance=TOL, margin=1e-3
    )
    scene = scene_of(box, contact, fallback=None, max_halvings=0)
    with pytest.raises(StepFailed, match="below the plane.*margin should be at least"):
        scene.step(H)
    assert scene.t == 0.0 and box.position[2] > SIZE[2] / 2


def test_bad_contact_input_is_a_clear_error_before_the_run():
    box = rigid_box(position=(0.0, 0.0, SIZE[2] / 2))
    plane = ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    with pytest.raises(InputError, match="mu must be >= 0"):
        af.PlaneContact(box, *plane, mu=-0.1, points=CORNERS)
    with pytest.raises(InputError, match="normal must be a non-zero"):
        af.PlaneContact(box, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), points=CORNERS)
    with pytest.raises(InputError, match="no surface: give the contact points"):
        af.PlaneContact(box, *plane)
    with pytest.raises(InputError, match="margin must be"):
        af.PlaneContact(box, *plane, points=CORNERS, tolerance=1e-3, margin=1e-4)
    # a start in intersection: the body and its first offending point are named
    sunk = rigid_box(position=(0.0, 0.0, SIZE[2] / 2 - 1e-3))
    scene = scene_of(sunk, af.PlaneContact(sunk, *plane, points=CORNERS, tolerance=TOL))
    with pytest.raises(InputError, match=r"at the start .*point 0 .* of 'box' is 0.001 below"):
        scene.step(H)
    block = fem_block(lift=-1e-3)
    scene = scene_of(block, af.PlaneContact(block, *plane, tolerance=TOL))
    with pytest.raises(
        InputError,
        match=r"node \d+ of 'block' is 0.001 below the plane "
        r"\(25 points",
    ):
        scene.check()
    # a contact on a body that is not in the scene
    other = fem_block(name="other")
    scene = scene_of(box, af.PlaneContact(other, *plane, name="floor"))
    with pytest.raises(InputError, match="'floor' acts on 'other', which is not a body"):
        scene.check()
    with pytest.raises(InputError, match="contact 'wall' is not in the scene"):
        scene.contact_forces(af.PlaneContact(box, *plane, points=CORNERS, name="wall"))


def test_the_distributed_island_refuses_a_contact_on_an_fem_body():
    """island_solver="schur" keeps FEM rows on their ranks and takes constraints on rigid
    bodies only: a contact on an FEM body is refused at the first step, before any work,
    saying what to run instead."""
    block = fem_block(lift=0.01)
    contact = af.PlaneContact(block, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), margin=0.02)
    scene = scene_of(block, contact, island_solver="schur")
    with pytest.raises(
        InputError,
        match=r"constraints on FEM bodies \(contact\) \(run it in "
        r"serial with island_solver='direct'\)",
    ):
        scene.step(H)
    assert scene.t == 0.0 and np.abs(block.u.x.array).max() == 0.0


def test_a_reduced_block_with_the_complete_basis_is_the_full_block():
    """The cube dropped on the plane with friction, full and reduced (the identity basis,
    every integration point; its contact made by ``PlaneContact.onto_reduced``, as the
    reductor does): the reduced body's contact rows are U_i^T e on q, and it falls,
    lands and rests as the full body to round-off, with the same contact forces."""
    from artifem.reduction.reduced_body import ReducedFemBody, all_points

    block, twin = fem_block(lift=0.005), fem_block(lift=0.005)
    contact = af.PlaneContact(
        block, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), mu=0.5, tolerance=TOL, margin=0.02
    )
    n = 3 * twin.V.dofmap.index_map.size_local
    reduced = ReducedFemBody(twin, np.eye(n), all_points(twin), name="reduced block")
    twin_contact = af.PlaneContact(
        twin, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), mu=0.5, tolerance=TOL, margin=0.02
    ).onto_reduced(reduced)
    assert twin_contact.bodies == (reduced,)
    scene, reduced_scene = scene_of(block, contact), scene_of(reduced, twin_contact)
    for _ in range(40):
        scene.step(H)
        reduced_scene.step(H)
    u = block.u.x.array[:n]
    assert heights(block).min() < 1e-6  # landed
    np.testing.assert_allclose(
        reduced.nodal_displacement(), u, rtol=0, atol=1e-10 * np.abs(u).max()
    )
    full_forces = scene.contact_forces(contact)
    reduced_forces = reduced_scene.contact_forces(twin_contact)
    np.testing.assert_array_equal(full_forces.points, reduced_forces.points)
    np.testing.assert_allclose(
        reduced_forces.normal, full_forces.normal, rtol=0, atol=1e-9 * block.total_mass() * G
    )


def test_simulate_records_contact_forces_per_point_and_writes_the_pressure(tmp_path):
    """``af.simulate`` with a contact: a record of the forces per point (their number
    changes as the block lands: kept as an object array), a record of the nodal contact
    pressure (fixed length), and with ``vtx`` the series ``block_contact_pressure.bp``
    beside the displacement's, both read back: 31 steps (t = 0 ... 0.3 s), their last step
    the recorded pressure and the final displacement. At rest the pressure times the nodes'
    areas is the weight."""
    block = fem_block(lift=0.005)
    contact = af.PlaneContact(block, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), tolerance=TOL, margin=0.02)
    scene = scene_of(block, contact)
    run = af.simulate(
        scene,
        0.3,
        H,
        vtx=tmp_path,
        progress=False,
        record={
            "normal": lambda s: s.contact_forces(contact).normal,
            "pressure": lambda s: s.contact_pressure(contact)["block"].nodal,
        },
    )
    counts = [len(f) for f in run.records["normal"]]
    assert run.records["normal"].dtype == object and counts[0] == 0 and counts[-1] == 25
    assert run.records["pressure"].shape == (31, len(block.V.tabulate_dof_coordinates()))
    pressure = scene.contact_pressure(contact)["block"]
    weight = block.total_mass() * G
    assert abs((pressure.pressure * pressure.area).sum() / weight - 1.0) < 1e-6
    np.testing.assert_array_equal(run.records["pressure"][-1], pressure.nodal)
    displacement = read_series(tmp_path / "block.bp")
    written = read_series(tmp_path / "block_contact_pressure.bp")
    for series in (displacement, written):
        np.testing.assert_allclose(series.times, run.times, rtol=0, atol=1e-12)
    assert len(written.times) == 31
    assert displacement.fields == {"displacement"} and written.fields == {"contact_pressure"}
    assert same_rows(displacement.at("displacement"), block.u.x.array.reshape(-1, 3))
    assert same_rows(written.at("contact_pressure"), run.records["pressure"][-1][:, None])
