"""Contact between closed triangle surfaces (artifem.multibody.mesh_contact):

(1) a rigid box resting on a fixed rigid box "floor": after settling the normal forces sum
    to m g to 1e-9, no penetration beyond round-off (the depth measured, not the contact's
    tolerance, which every step enforces), the same pose and resultant as a PlaneContact on
    a plane at the floor's top; with an offset, at that distance above it;
(2) bad input: an open surface; a surface oriented inward; a start in intersection
    (InputError naming both bodies);
(3) an FEM block dropped on the rigid floor rests as on a plane;
(4) bone on bone: a tessellated ball in a fixed cup under gravity and a side load is held
    as by a spherical joint;
(5) two elastic balls colliding: momentum conserved, energy never grows, no pass-through;
(6) a stack of four boxes; (7) friction between meshes on an incline; (8) a surface
    embedded in an FEM grid;
(9) the queries: the signed distances on a prebuilt tree are libigl's, and a rigid
    body's pairs found in its body frame are those found in the world;
(10) how the rows turn: each pair kind's distance Hessian, and a block's stiffness
    d(G^T lambda)/dq, against finite differences.
"""

import numpy as np
import pytest

import artifem as af  # (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.errors import InputError

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")

G, H, TOL = 9.81, 0.01, 1e-6
SIZE, MASS = np.array([0.2, 0.2, 0.1]), 2.0
CUBE = np.array(
    [
        [0, 1, 3],
        [0, 3, 2],
        [4, 6, 7],
        [4, 7, 5],
        [0, 4, 5],
        [0, 5, 1],
        [2, 3, 7],
        [2, 7, 6],
        [0, 2, 6],
        [0, 6, 4],
        [1, 5, 7],
        [1, 7, 3],
    ]
)


def box_surface(size, turn=0.0):
    """A box's 8 corners (centred) and 12 outward triangles, turned by ``turn`` about z."""
    corners = (
        np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
        * np.asarray(size)
        / 2
    )
    c, s = np.cos(turn), np.sin(turn)
    return corners @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T, CUBE


def floor(top=0.0):
    """A fixed 2 x 2 x 1 m box, its top face at z = top, turned 0.3 rad about z (so that no
    edge of it is parallel to an edge of the boxes above)."""
    return af.RigidBody(
        "floor",
        1.0,
        np.eye(3),
        position=(0.0, 0.0, top - 0.5),
        motion="fixed",
        surface=box_surface([2.0, 2.0, 1.0], 0.3),
    )


def rigid_box(lift):
    a, b, c = SIZE
    return af.RigidBody(
        "box",
        MASS,
        MASS / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b]),
        position=(0.0, 0.0, SIZE[2] / 2 + lift),
        surface=box_surface(SIZE),
    )


def scene_of(*items):
    scene = af.Scene(gravity=(0.0, 0.0, -G))
    scene.add(*items)
    return scene


def least_gap(contact) -> float:
    """The least signed distance between the contact's surfaces now (m, negative inside,
    net of the offset): its deepest vertex or crossed edge pair, the depth that
    ``constraint_failure`` holds within the tolerance (a deeper step is refused), measured
    here itself."""
    deepest = contact._pairs().deepest
    return np.inf if deepest is None else float(deepest[0])


# ---- (1) a rigid box on a rigid floor -------------------------------------------------------


def test_rigid_box_rests_on_a_rigid_floor_like_on_a_plane():
    """Dropped from 1 cm: its 4 bottom corners on the floor's top triangles and the crossing
    edges give redundant rows; measured: sum N = m g to 2e-16, the pose the PlaneContact
    run's to 3e-17 m (position) and 6e-19 (rotation), penetration at most 1.1e-16 m over
    the 50 steps: the bounds are 1e-12, round-off (the contact's tolerance is 1e-6)."""
    box = rigid_box(0.01)
    ground = floor()
    contact = af.MeshContact(box, ground, tolerance=TOL, margin=0.05)
    scene = scene_of(box, ground, contact)
    plane_box = rigid_box(0.01)
    plane = af.PlaneContact(plane_box, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), tolerance=TOL, margin=0.05)
    plane_scene = scene_of(plane_box, plane)
    gaps = []
    for _ in range(50):
        scene.step(H)
        plane_scene.step(H)
        gaps += [least_gap(contact), box.position[2] - SIZE[2] / 2]  # surfaces; box bottom
    assert min(gaps) >= -1e-12
    forces = scene.contact_forces(contact)
    assert np.all(forces.normal >= 0)
    assert abs(forces.normal @ forces.directions[:, 2] / (MASS * G) - 1.0) < 1e-9
    np.testing.assert_allclose(forces.resultant, [0.0, 0.0, MASS * G], atol=1e-9 * MASS * G)
    np.testing.assert_allclose(
        forces.resultant,
        plane_scene.contact_forces(plane).normal.sum() * np.array([0.0, 0.0, 1.0]),
        atol=1e-9 * MASS * G,
    )
    np.testing.assert_allclose(box.position, plane_box.position, rtol=0, atol=1e-12)
    np.testing.assert_allclose(box.rotation, plane_box.rotation, rtol=0, atol=1e-12)
    assert np.abs(box.twist).max() < 1e-9


def test_an_offset_keeps_the_surfaces_that_far_apart():
    """With offset d the box rests d above the floor's top (a layer of thickness d between
    them), carrying its weight; dropped from 1 cm + d it never comes closer. Measured: the
    least gap over the 50 steps d - 1.1e-16 m, at rest d - 1e-17 m; the bounds are 1e-12
    (round-off; the contact's tolerance is 1e-6)."""
    d = 0.004
    box = rigid_box(0.01 + d)
    contact = af.MeshContact(box, floor(), tolerance=TOL, margin=0.05, offset=d)
    scene = scene_of(box, contact.b, contact)
    gaps = []
    for _ in range(50):
        scene.step(H)
        gaps += [least_gap(contact), box.position[2] - SIZE[2] / 2 - d]  # net of the offset
    assert min(gaps) >= -1e-12
    assert box.position[2] - SIZE[2] / 2 == pytest.approx(d, abs=1e-12)
    forces = scene.contact_forces(contact)
    np.testing.assert_allclose(forces.resultant, [0.0, 0.0, MASS * G], atol=1e-9 * MASS * G)
    with pytest.raises(InputError, match="'c': offset must be finite and >= 0"):
        af.MeshContact(box, floor(), offset=-1e-3, name="c")


# ---- (2) bad input ---------------------------------------------------------------------------


def test_open_or_inward_surfaces_are_refused_naming_the_body():
    V, F = box_surface(SIZE)
    open_box = af.RigidBody("lid-less", MASS, np.eye(3), surface=(V, F[2:]))
    with pytest.raises(InputError, match="'lid-less' is not closed"):
        af.MeshContact(open_box, floor())
    inward = af.RigidBody("inside-out", MASS, np.eye(3), surface=(V, F[:, ::-1]))
    with pytest.raises(InputError, match="'inside-out' encloses a non-positive volume"):
        af.MeshContact(inward, floor())
    with pytest.raises(InputError, match="'bare' has no surface"):
        af.MeshContact(af.RigidBody("bare", MASS, np.eye(3)), floor())


def test_self_contact_and_bad_options_are_refused_naming_the_contact(icosphere):
    """A body against itself, and an embedded surface against its own master (the same
    coordinates on both sides), are not supported; mu < 0 and a margin not above the
    tolerance are InputErrors naming the contact."""
    from artifem.embedding.embedded_mesh import EmbeddedMesh

    box = rigid_box(0.0)
    with pytest.raises(InputError, match=r"'self': a body against itself \(self-contact\)"):
        af.MeshContact(box, box, name="self")
    grid = fem_block(0.0)
    V, F = icosphere(1, 0.03)
    ball = EmbeddedMesh(grid, V + 0.05, F, "triangle", name="ball")
    with pytest.raises(InputError, match="both surfaces move with 'fem'"):
        af.MeshContact(ball, grid)
    with pytest.raises(InputError, match="'c': .*mu must be >= 0"):
        af.MeshContact(box, floor(), mu=-0.1, name="c")
    with pytest.raises(InputError, match="'c': .*margin must be finite and > tolerance"):
        af.MeshContact(box, floor(), tolerance=0.01, margin=0.01, name="c")


def test_a_start_in_intersection_is_refused_naming_both_bodies():
    """The box sunk 1 cm into the floor (within the margin) and 4 cm (beyond it): the first
    step is an InputError that names the box's vertex, the floor's triangle and the depth
    (every vertex inside the other's bounding box is queried, whatever the margin)."""
    for depth, margin in ((0.01, 0.05), (0.04, 0.005)):
        box = rigid_box(-depth)
        ground = floor()
        scene = scene_of(box, ground, af.MeshContact(box, ground, tolerance=TOL, margin=margin))
        with pytest.raises(
            InputError,
            match=rf"at the start.*vertex \d+ of 'box' and triangle "
            rf"\d+ of 'floor': the vertex is {depth:g} inside",
        ):
            scene.step(H)


# ---- (3) an FEM block on a rigid floor -----------------------------------------------------


def fem_block(lift):
    """A 0.1 m neo-Hookean cube of 4 x 4 x 4 hexahedra (1 kg, E = 1e5 Pa, Rayleigh
    (10, 1e-3)), its bottom face at z = lift (tests/test_contact_plane.py's)."""
    msh = dmesh.create_box(
        MPI.COMM_SELF,
        [np.array([0.0, 0.0, lift]), np.array([0.1, 0.1, 0.1 + lift])],
        [4, 4, 4],
        dmesh.CellType.hexahedron,
    )
    return af.FemBody(
        msh, af.NeoHookean.from_young_poisson(1e5, 0.3), 1000.0, rayleigh=(10.0, 1e-3)
    )


def test_fem_block_rests_on_a_rigid_floor_like_on_a_plane():
    """Dropped from 1 cm on the turned rigid floor: its bottom surface's vertices meet the
    floor's top triangles; after 1 s the normal forces sum to its weight and every node
    is where the same block on a PlaneContact at the floor's top is (measured: to 6e-17 m of
    a 1 cm sag; penetration at most 3e-16 m; the bounds are 1e-12, round-off, against the
    contact's tolerance of 1e-6)."""
    block, twin = fem_block(0.01), fem_block(0.01)
    ground = floor()
    contact = af.MeshContact(block, ground, tolerance=TOL, margin=0.02)
    scene = scene_of(block, ground, contact)
    plane = af.PlaneContact(twin, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), tolerance=TOL, margin=0.02)
    plane_scene = scene_of(twin, plane)
    gaps = []
    for _ in range(100):
        scene.step(H)
        plane_scene.step(H)
        gaps += [least_gap(contact), plane.distances().min()]
    assert min(gaps) >= -1e-12
    forces = scene.contact_forces(contact)
    weight = block.total_mass() * G
    np.testing.assert_allclose(forces.resultant, [0.0, 0.0, weight], atol=1e-6 * weight)
    np.testing.assert_allclose(block.u.x.array, twin.u.x.array, rtol=0, atol=1e-12)
    # the contact pressure on the block's nodes (the floor is rigid: none there) is the
    # plane's, and integrates to the weight
    pressure = scene.contact_pressure(contact)
    assert list(pressure) == [block.name]
    p, p_plane = pressure[block.name], plane_scene.contact_pressure(plane)[twin.name]
    assert abs((p.pressure * p.area).sum() / weight - 1.0) < 1e-6
    np.testing.assert_allclose(p.nodal, p_plane.nodal, rtol=0, atol=1e-4 * p.nodal.max())


# ---- (4) bone on bone: a ball in a cup --------------------------------------------------------


def cup_surface(r_in, r_out, n_lat=8, n_lon=24):
    """A hemispherical cup (z <= 0) of inner radius r_in and outer r_out about the origin:
    outer and inner hemispheres (latitude-longitude grids, a vertex at each pole) and the
    flat rim between them, as a closed outward triangle surface."""
    theta = np.pi / 2 + np.linspace(0.0, np.pi / 2, n_lat + 1)[:-1]
    phi = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)
    rings = np.stack(
        [
            np.outer(np.sin(theta), np.cos(phi)),
            np.outer(np.sin(theta), np.sin(phi)),
            np.outer(np.cos(theta), np.ones_like(phi)),
        ],
        axis=-1,
    )
    vertices, triangles = [], []
    for r in (r_out, r_in):
        base = len(vertices)
        vertices += list(r * rings.reshape(-1, 3)) + [np.array([0.0, 0.0, -r])]
        pole = len(vertices) - 1
        for k in range(n_lat):
            for j in range(n_lon):
                a, b = base + k * n_lon + j, base + k * n_lon + (j + 1) % n_lon
                if k + 1 < n_lat:
                    c, d = a + n_lon, b + n_lon
                    triangles += [(a, c, d), (a, d, b)]
                else:
                    triangles.append((a, pole, b))
    inner = len(rings.reshape(-1, 3)) + 1  # the inner hemisphere's first vertex
    for j in range(n_lon):
        a, b = j, (j + 1) % n_lon
        triangles += [(a, b, inner + b), (a, inner + b, inner + a)]
    x, t = np.array(vertices), np.array(triangles)
    n = np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]])
    c = x[t].mean(axis=1)
    radius = np.linalg.norm(c, axis=1)
    rim = np.abs(c[:, 2]) < 1e-12
    want = np.where(
        rim[:, None], [0.0, 0.0, 1.0], np.where((radius > 0.5 * (r_in + r_out))[:, None], c, -c)
    )
    flip = np.einsum("ij,ij->i", n, want) < 0
    t[flip] = t[flip][:, ::-1]
    return x, t


class SideLoad:
    """A constant force at a rigid body's COM."""

    def __init__(self, body, force):
        self.body, self.force = body, np.asarray(force, dtype=float)
        self.bodies = (body,)

    def master_loads(self, t):
        return [(self.body, np.concatenate([self.force, np.zeros(3)]))]


def test_ball_in_a_cup_is_held_like_a_spherical_joint(icosphere):
    """A tessellated ball (radius 0.98 of the cup's: 1 mm clearance) dropped in a fixed cup,
    under gravity and a side load at its centre: a few hundred vertex-face rows both ways
    within the margin, redundant; the contact forces' resultant balances gravity and the
    load to 1e-9 (a spherical joint's reaction), the ball is at rest and its centre within
    the clearance of the cup's. The rows hold the contact linearized over the step on the
    curved surfaces: the deepest vertex over the 100 steps is measured 1.02e-7 m inside
    (the tolerance is 1e-6); the bound is that x 1.25."""
    r_cup, mass = 0.05, 1.0
    cup = af.RigidBody(
        "cup", 1.0, np.eye(3), motion="fixed", surface=cup_surface(r_cup, 1.4 * r_cup)
    )
    V, F = icosphere(2, 0.98 * r_cup)
    ball = af.RigidBody(
        "ball",
        mass,
        0.4 * mass * (0.98 * r_cup) ** 2 * np.eye(3),
        position=(0.0, 0.0, 0.002),
        surface=(V, F),
    )
    side = np.array([0.3 * mass * G, 0.0, 0.0])
    contact = af.MeshContact(ball, cup, tolerance=TOL, margin=0.01)
    scene = scene_of(ball, cup, contact, SideLoad(ball, side))
    gaps = []
    for _ in range(100):
        scene.step(H)
        gaps.append(least_gap(contact))
    assert min(gaps) > -1.25e-7
    forces = scene.contact_forces(contact)
    applied = side + np.array([0.0, 0.0, -mass * G])
    assert len(forces.normal) > 3 and np.all(forces.normal >= 0)
    np.testing.assert_allclose(forces.resultant, -applied, atol=1e-9 * mass * G)
    assert np.linalg.norm(ball.position) < 0.02 * r_cup
    assert np.abs(ball.twist[:3]).max() < 1e-6


# ---- (5) two elastic balls colliding ---------------------------------------------------------


def fem_ball(center, radius=0.05, size=0.025, name="ball"):
    """A neo-Hookean ball (E = 1e5 Pa, 1000 kg/m^3) of P1 tetrahedra meshed by gmsh."""
    import gmsh
    from dolfinx.io import gmsh as dgmsh

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(name)
        gmsh.model.occ.addSphere(*center, radius)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [1], 1)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.model.mesh.generate(3)
        msh = dgmsh.model_to_mesh(gmsh.model, MPI.COMM_SELF, 0, gdim=3).mesh
    finally:
        gmsh.finalize()
    return af.FemBody(msh, af.NeoHookean.from_young_poisson(1e5, 0.3), 1000.0, name=name)


def test_colliding_elastic_balls_keep_momentum_and_never_gain_energy():
    """Two elastic balls (radius 5 cm, 208 nodes each) meet off-centre at 1 m/s each (no
    gravity, no damping): both surfaces' vertices give rows (FEM on FEM); the contact
    impulses are equal and opposite (W sums to zero over each pair), so the momentum stays
    what it was to round-off; the energy never grows (the contact is inelastic); the
    deepest vertex is measured 0.082 mm inside, within the tolerance of 0.1 mm that the steps
    hold (the rows hold the contact linearized over the step: the triangles turn and the
    vertices slide 2 cm/step across them, and 3 steps are halved), the bound 0.09 mm; they
    part again."""
    left, right = fem_ball((0.0, 0.0, 0.0), name="left"), fem_ball((0.102, 0.02, 0.0), name="right")
    left.v.x.array.reshape(-1, 3)[:, 0] = 1.0
    right.v.x.array.reshape(-1, 3)[:, 0] = -1.0
    contact = af.MeshContact(left, right, tolerance=1e-4, margin=0.03)
    scene = af.Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(left, right, contact)
    momentum, energy = scene.momentum(), [scene.energy()]
    touched = 0
    gaps = []
    for _ in range(30):
        scene.step(H)
        gaps.append(least_gap(contact))
        np.testing.assert_allclose(scene.momentum(), momentum, atol=1e-12)
        energy.append(scene.energy())
        touched += len(scene.contact_forces(contact).normal) > 0
    assert touched > 2
    assert min(gaps) > -9e-5
    assert np.all(np.diff(energy) <= 1e-12 * energy[0]), np.diff(energy).max()
    assert energy[-1] < energy[0]
    mean_v = [b.v.x.array.reshape(-1, 3).mean(axis=0) for b in (left, right)]
    assert mean_v[0][0] < mean_v[1][0]  # parting


# ---- (6) a stack of boxes -------------------------------------------------------------------


@pytest.mark.parametrize("turn", [0.0, 0.3], ids=["aligned", "turned"])
def test_a_stack_of_four_boxes_carries_the_weight_above_each_interface(turn):
    """Four rigid boxes (2 kg each) stacked on a plane, each on the one below through a
    mesh contact (aligned: their corners and edges coincide; turned: each 0.3 rad about z
    from the one below), dropped from 1 mm gaps: at rest the normal force of each
    interface carries the weight above it to 1e-9 and the stack stands still. No surface
    sinks into the one below, or into the plane, by more than the contact solve's round-off:
    measured 3.5e-17 m aligned, 9.8e-13 m turned (the contacts' tolerance is 1e-6); the
    bound is 1e-11."""
    boxes = []
    for k in range(4):
        a, b, c = SIZE
        boxes.append(
            af.RigidBody(
                f"box {k}",
                MASS,
                MASS / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b]),
                position=(0.0, 0.0, (k + 0.5) * SIZE[2] + (k + 1) * 0.001),
                surface=box_surface(SIZE, turn * k),
            )
        )
    plane = af.PlaneContact(boxes[0], (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), tolerance=TOL, margin=0.02)
    contacts = [
        af.MeshContact(upper, lower, tolerance=TOL, margin=0.02)
        for lower, upper in zip(boxes, boxes[1:])
    ]
    scene = scene_of(*boxes, plane, *contacts)
    gaps = []
    for _ in range(60):
        scene.step(H)
        gaps += [least_gap(c) for c in contacts] + [plane.distances().min()]
    assert min(gaps) >= -1e-11
    weight = MASS * G
    assert abs(scene.contact_forces(plane).normal.sum() / (4 * weight) - 1.0) < 1e-9
    for k, contact in enumerate(contacts):  # box k + 1 on box k
        resultant = scene.contact_forces(contact).resultant
        np.testing.assert_allclose(resultant, [0.0, 0.0, (3 - k) * weight], atol=1e-9 * weight)
    for box in boxes:
        assert np.abs(box.twist).max() < 1e-9
        np.testing.assert_allclose(box.position[:2], 0.0, atol=1e-9)


# ---- (7) friction between meshes -------------------------------------------------------------


@pytest.mark.parametrize("mu", [0.6, 0.5])
def test_rigid_box_on_an_inclined_rigid_slab_sticks_or_slides(mu):
    """A rigid box resting on a fixed rigid slab inclined at 30 degrees (its top face the
    incline; the box turned about the normal so that no edges line up), friction between the
    meshes: tan 30 = 0.577 < 0.6 sticks (slip below 1e-9 m over 1 s); 0.5 slides down the
    slope with g (sin 30 - mu cos 30) = 0.657 m/s^2 to 1e-3 relative (the same checks as
    the plane's, tests/test_contact_plane.py), neither sinking into the slab nor leaving it:
    measured penetration 5.5e-16 m and off-slope slip 4e-17 m, the bounds 1e-12 (round-off;
    the contact's tolerance is 1e-6)."""
    theta = np.radians(30.0)
    normal = np.array([-np.sin(theta), 0.0, np.cos(theta)])
    uphill = np.array([np.cos(theta), 0.0, np.sin(theta)])
    frame = np.column_stack([uphill, [0.0, 1.0, 0.0], normal])
    slab = af.RigidBody(
        "slab",
        1.0,
        np.eye(3),
        position=-0.5 * normal,
        rotation=frame,
        motion="fixed",
        surface=box_surface([3.0, 2.0, 1.0]),
    )
    box = rigid_box(0.0)
    box.rotation = frame @ np.array(
        [[np.cos(0.2), -np.sin(0.2), 0.0], [np.sin(0.2), np.cos(0.2), 0.0], [0.0, 0.0, 1.0]]
    )
    box.position = 0.5 * SIZE[2] * normal
    contact = af.MeshContact(box, slab, mu=mu, tolerance=TOL, margin=0.05)
    scene = scene_of(box, slab, contact)
    start = box.position.copy()
    gaps = []
    for _ in range(100):
        scene.step(H)
        gaps.append(least_gap(contact))
    assert min(gaps) >= -1e-12
    slip = box.position - start
    forces = scene.contact_forces(contact)
    assert (
        abs((forces.normal @ forces.directions) @ normal / (MASS * G * np.cos(theta)) - 1.0) < 1e-9
    )
    if mu == 0.6:
        assert np.linalg.norm(slip) < 1e-9
    else:
        a = G * (np.sin(theta) - mu * np.cos(theta))
        assert abs(-box.velocity @ uphill / (100 * H) / a - 1.0) < 1e-3
        assert abs(slip @ normal) < 1e-12


def test_a_pad_draped_over_a_ball_with_friction_settles_its_friction_passes():
    """A soft pad dropped on a fixed rigid ball with friction (the contact demo's scene):
    the passes of the friction bounds cycled there (rows sliding in one pass, sticking in
    the next: 'did not settle in 50 passes' at t = 0.063 s, after 4 halvings); their
    bounds now take the mean of the last impulses after RELAX_PASSES, and the run goes on
    without a halving. The settled passes' impulses of the last step obey Coulomb's pyramid
    on every row (measured to 7e-11 of the largest normal impulse; the bound is 1e-9), and
    the contact's lift is the pad's momentum balance over that step, h F = dP_z + h (m g +
    alpha P_z), the Rayleigh term at the step's end momentum (alpha = 5; measured to 5e-15,
    the bound 1e-9): it carries the weight and brakes the fall (F = 1.63 m g). The deepest
    vertex is measured 1.05e-6 m inside (the tolerance is 1e-5); the bound is 1.3e-6."""
    import pyvista as pv

    ball = pv.Sphere(radius=0.03, theta_resolution=32, phi_resolution=32).triangulate()
    condyle = af.RigidBody.from_surface(
        "condyle", ball.points, ball.faces.reshape(-1, 4)[:, 1:], 1900.0, motion="fixed"
    )
    box = dmesh.create_box(
        MPI.COMM_SELF,
        [np.array([-0.05, -0.05, 0.032]), np.array([0.05, 0.05, 0.047])],
        [10, 10, 2],
        dmesh.CellType.hexahedron,
    )
    pad = af.FemBody(
        box, af.NeoHookean.from_young_poisson(2e4, 0.45), 1050.0, rayleigh=(5.0, 0.002), name="pad"
    )
    contact = af.MeshContact(pad, condyle, mu=0.4, tolerance=1e-5, margin=0.01)
    scene = scene_of(pad, condyle, contact)
    gaps = []
    for _ in range(16):
        momentum = scene.momentum()  # before the last step
        scene.step(0.005)
        gaps.append(least_gap(contact))
    assert scene.t == pytest.approx(0.08) and scene.halvings == 0
    assert min(gaps) > -1.3e-6
    ((block, lam),) = scene._impulses[contact]  # [normal; along t_1; along t_2] per point
    normal, along = lam[: len(block.points)], lam[len(block.points) :].reshape(2, -1)
    assert normal.max() > 0 and np.all(normal >= 0)
    assert np.all(np.abs(along) <= 0.4 * normal + 1e-9 * normal.max())
    lift = scene.contact_forces(contact).resultant[2]
    p_z = scene.momentum()[2]
    balance = p_z - momentum[2] + 0.005 * (pad.total_mass() * G + 5.0 * p_z)
    assert 0.005 * lift == pytest.approx(balance, rel=1e-9)


# ---- (8) a surface embedded in an FEM grid --------------------------------------------------


@pytest.mark.parametrize("kind", ["plane", "mesh"])
def test_an_embedded_surface_carries_its_grid_on_the_floor(kind, icosphere):
    """A ball's surface (radius 35 mm) embedded in a coarse 0.1 m FEM grid, the grid dropped
    on a floor, a plane or the rigid floor mesh: the contact is the embedded surface's (its
    rows act on the grid through the embedding weights, G = e^T W J), so the grid's own
    bottom sinks below the floor while the ball's surface rests on it, carrying the weight.
    Measured: the surface's least height over the 100 steps -1.7e-18 m (plane) and
    -2.7e-16 m (mesh), at rest within 5e-17 m of the floor; the bounds are 1e-12 (round-off;
    the contacts' tolerance is 1e-6)."""
    from artifem.embedding.embedded_mesh import EmbeddedMesh

    grid = fem_block(0.0)
    V, F = icosphere(2, 0.035)
    ball = EmbeddedMesh(grid, V + [0.05, 0.05, 0.05], F, "triangle", name="ball")
    lowest = ball.positions()[:, 2].min()
    floor_at = lowest - 0.002
    if kind == "plane":
        contact = af.PlaneContact(
            ball, (0.0, 0.0, floor_at), (0.0, 0.0, 1.0), tolerance=TOL, margin=0.02
        )
        scene = scene_of(grid, contact)
    else:
        ground = floor(floor_at)
        contact = af.MeshContact(ball, ground, tolerance=TOL, margin=0.02)
        scene = scene_of(grid, ground, contact)
    assert contact.bodies[0] is grid
    gaps = []
    for _ in range(100):
        scene.step(H)
        gaps.append(least_gap(contact) if kind == "mesh" else contact.distances().min())
    assert min(gaps) >= -1e-12
    heights = ball.positions()[:, 2] - floor_at
    assert abs(heights.min()) < 1e-12
    assert heights_of(grid).min() < floor_at - 0.01  # the grid went through
    weight = grid.total_mass() * G
    forces = scene.contact_forces(contact)
    total = forces.normal.sum() if kind == "plane" else forces.resultant[2]
    assert abs(total / weight - 1.0) < 1e-6


def heights_of(body):
    return (body.V.tabulate_dof_coordinates() + body.u.x.array.reshape(-1, 3))[:, 2]


# ---- (9) the queries ------------------------------------------------------------------------


def test_signed_distances_on_a_prebuilt_tree_are_libigls(icosphere):
    """_signed_distance (libigl's AABB tree built once, the pseudonormal of the closest
    feature chosen by the closest point's barycentric coordinates) against
    igl.signed_distance on a box, whose closest features are faces, sharp edges and
    corners, and a sphere: points in the box and around it, points just off the vertices
    and edge midpoints (where a face's normal would give the wrong sign)."""
    import igl
    from artifem.multibody import mesh_contact as mc

    rng = np.random.default_rng(3)
    for x, t in (box_surface([1.0, 2.0, 0.5], 0.3), icosphere(2, 1.0)):
        x, t = np.asarray(x, float), np.asarray(t, np.int64)
        mids = 0.5 * (x[t[:, 0]] + x[t[:, 1]])
        points = np.vstack(
            [
                rng.uniform(1.3 * x.min(axis=0), 1.3 * x.max(axis=0), (2000, 3)),
                1.02 * x + 1e-3 * rng.normal(size=x.shape),
                1.02 * mids + 1e-3 * rng.normal(size=mids.shape),
            ]
        )
        S0, I0, C0, N0 = igl.signed_distance(
            points, x, t, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL
        )
        S, I, C, N = mc._signed_distance(mc._geometry(x, t, mc._edges(t)), points)
        assert (S < 0).sum() > 100 and (S > 0).sum() > 100
        np.testing.assert_allclose(S, S0, rtol=0, atol=1e-14)
        np.testing.assert_allclose(C, C0, rtol=0, atol=1e-14)
        same = I == I0  # a tie between two triangles may pick either
        assert same.mean() > 0.99
        np.testing.assert_allclose(N[same], N0[same], rtol=0, atol=1e-12)


def pressed_balls(icosphere):
    """A fine ball (radius 0.06) pressed into a coarse one (0.08), both turned: vertex-face
    and closest-point pairs both ways."""
    from scipy.spatial.transform import Rotation

    V, F = icosphere(2, 0.06)
    ball = af.RigidBody(
        "ball",
        1.0,
        np.eye(3),
        position=(0.03, -0.02, 0.1 + 0.055),
        rotation=Rotation.from_rotvec([0.4, -0.7, 1.1]).as_matrix(),
        surface=(V, F),
    )
    V, F = icosphere(1, 0.08)
    other = af.RigidBody(
        "coarse ball",
        1.0,
        np.eye(3),
        position=(0.0, 0.0, 0.05),
        rotation=Rotation.from_rotvec([0.05, 0.1, -0.6]).as_matrix(),
        surface=(V, F),
    )
    return ball, other


def test_pairs_in_a_rigid_bodys_frame_are_the_pairs_in_the_world(icosphere):
    """A fine ball turned and pressed into a coarse one (vertex-over-triangle pairs both
    ways, and closest-point pairs): the pairs found with each rigid body's surface kept in its
    body frame (its tree built once) equal, to round-off, those found with both surfaces
    rebuilt in the world at their current vertices, as a deformable body's are."""
    from artifem.multibody import mesh_contact as mc

    ball, box = pressed_balls(icosphere)
    contact = af.MeshContact(ball, box, tolerance=0.02, margin=0.03)
    framed = contact._pairs()
    world = af.MeshContact(ball, box, tolerance=0.02, margin=0.03)
    world._in_frame = lambda side, x: (
        mc._geometry(x, world._tris[side], world._edges[side]),
        np.eye(3),
        np.zeros(3),
    )
    plain = world._pairs()
    assert len(framed.phi) > 20 and set(framed.which[:, 0]) == {0, 1}
    assert framed.phi.min() < 0  # pressed in
    # the same vertices, distances, directions and closest points (W x = x_v - c); the
    # triangle of a closest point on a shared edge or vertex is a tie either may pick
    np.testing.assert_array_equal(framed.which[:, :2], plain.which[:, :2])
    for a, b in (
        (framed.phi, plain.phi),
        (framed.e, plain.e),
        (framed.W @ framed.x, plain.W @ plain.x),
    ):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert framed.deepest[:3] == pytest.approx(plain.deepest[:3], abs=1e-12)


# ---- (10) how the rows turn: the second derivative of the pairs' distances -------------------


def _features(kind, X):
    """(w, e, s, spans, count) of one pair of ``kind`` at its points X (4, 3), from first
    principles (distance_hessian's docstring): a vertex over a face, a vertex and an edge,
    two vertices, two edges."""
    if kind == "face":
        x, y0, y1, y2 = X
        n = np.cross(y1 - y0, y2 - y0)
        n /= np.linalg.norm(n)
        E = np.column_stack([y1 - y0, y2 - y0])
        b = np.linalg.solve(E.T @ E, E.T @ (x - y0))
        return (
            np.array([1.0, b.sum() - 1.0, -b[0], -b[1]]),
            n,
            n @ (x - y0),
            [[0, -1, 1, 0], [0, -1, 0, 1]],
            2,
        )
    if kind in ("edge", "vertex"):
        x, y, z, _ = X
        t = (x - y) @ (z - y) / ((z - y) @ (z - y)) if kind == "edge" else 0.0
        d = x - y - t * (z - y)
        return (
            np.array([1.0, t - 1.0, -t, 0.0]),
            d / np.linalg.norm(d),
            np.linalg.norm(d),
            [[0, -1, 1, 0], [0, 0, 0, 0]],
            1 if kind == "edge" else 0,
        )
    a0, a1, b0, b1 = X
    u, v = a1 - a0, b1 - b0
    s, t = np.linalg.solve([[u @ u, -u @ v], [-u @ v, v @ v]], [-u @ (a0 - b0), v @ (a0 - b0)])
    d = a0 + s * u - b0 - t * v
    return (
        np.array([1.0 - s, s, t - 1.0, -t]),
        d / np.linalg.norm(d),
        np.linalg.norm(d),
        [[-1, 1, 0, 0], [0, 0, -1, 1]],
        2,
    )


@pytest.mark.parametrize("kind", ["face", "edge", "vertex", "edges"])
def test_the_distance_hessian_is_the_derivative_of_the_rows(kind, rng):
    """distance_hessians against central differences of the gradient w_j e (the rows'
    coefficients) of each kind of pair at random points."""
    from artifem.multibody.distance_hessian import distance_hessians

    def gradient(X):
        w, e, *_ = _features(kind, X.reshape(4, 3))
        return np.outer(w, e).ravel()

    for _ in range(3):
        X = rng.normal(size=(4, 3))
        w, e, s, spans, count = _features(kind, X)
        H = distance_hessians(
            X[None],
            w[None],
            np.array(spans, float)[None],
            np.array([count]),
            e[None],
            np.array([s]),
        )[0]
        h = 1e-6
        fd = np.column_stack(
            [
                (gradient(X.ravel() + h * d) - gradient(X.ravel() - h * d)) / (2 * h)
                for d in np.eye(12)
            ]
        )
        np.testing.assert_allclose(H, fd, rtol=0, atol=1e-7 * np.abs(fd).max())


def test_a_pressed_pair_of_balls_rows_turn_by_their_stiffness(icosphere):
    """MeshContactRows.stiffness(lambda) = d(G^T lambda)/dq at fixed normal forces, by
    central differences over both rigid bodies' six coordinates (rotations R <- exp([d]x) R),
    for a fine ball pressed into a coarse one (vertex-face and closest-point pairs both
    ways): the levers' turning and the pairs' own (distance_hessian)."""
    from artifem.multibody.rigid_body import exp_so3

    ball, other = pressed_balls(icosphere)
    contact = af.MeshContact(ball, other, tolerance=0.02, margin=0.03)

    def lam_of(rows):  # by (side, vertex): a closest point on a shared edge or vertex
        keys = np.asarray(rows.keys)  # may take either triangle (same row)
        return 1.0 + (keys[:, 0] + 3 * keys[:, 1]) % 5 / 4.0

    (block,) = contact.row_blocks()
    lam = lam_of(block)
    K = block.stiffness(lam).toarray()
    pairs = contact._pairs()
    assert set(pairs.span_count) >= {0, 2} or set(pairs.span_count) >= {1, 2}

    def forces():
        (rows,) = contact.row_blocks()
        np.testing.assert_array_equal(
            np.sort(np.asarray(rows.keys)[:, :2], axis=0),
            np.sort(np.asarray(block.keys)[:, :2], axis=0),
        )
        return np.concatenate([G.T @ lam_of(rows) for _, G in rows.jacobians])

    h = 1e-7
    fd = []
    for body in (ball, other):
        p, R = body.position.copy(), body.rotation.copy()
        for i in range(6):
            out = []
            for sign in (1.0, -1.0):
                d = sign * h * np.eye(6)[i]
                body.position, body.rotation = p + d[:3], exp_so3(d[3:]) @ R
                out.append(forces())
            body.position, body.rotation = p, R
            fd.append((out[0] - out[1]) / (2 * h))
    np.testing.assert_allclose(K, np.column_stack(fd), rtol=0, atol=1e-6 * np.abs(K).max())


# ---- (11) statics holds the pairs' features -------------------------------------------------


def test_held_pairs_keep_their_features_and_measure_them_exactly(icosphere):
    """MeshContact.hold_pairs: held where they were found, the pairs are the found ones
    (to round-off); after the fine ball moves 6 mm and turns, every vertex that had pairs
    keeps its triangles, edges and vertices (the same keys, while a fresh contact pairs
    some with others), and each pair measures its own feature exactly: W x = x_v - c =
    phi e with e normal to the triangle (a vertex-over-triangle pair: the height over its
    plane) or to the edge (a closest-point pair); vertices without pairs get the fresh
    ones; released, the pairs are found again."""
    from scipy.spatial.transform import Rotation

    ball, other = pressed_balls(icosphere)
    contact = af.MeshContact(ball, other, tolerance=0.02, margin=0.03)
    order = lambda p: np.lexsort(p.which.T[::-1])  # noqa: E731

    def keyed(p):
        k = order(p)
        return p.which[k], p.phi[k], p.e[k], (p.W @ p.x)[k]

    found = contact._pairs()
    contact.hold_pairs(True)
    for a, b in zip(keyed(found), keyed(contact._pairs())):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    ball.position = ball.position + np.array([0.006, -0.003, 0.0])
    ball.rotation = Rotation.from_rotvec([0.0, 0.0, 0.05]).as_matrix() @ ball.rotation
    held = contact._pairs()
    fresh = af.MeshContact(ball, other, tolerance=0.02, margin=0.03)._pairs()

    def by_vertex(p):
        return {
            (int(s), int(v)): {
                tuple(w) for w in p.which[(p.which[:, 0] == s) & (p.which[:, 1] == v)]
            }
            for s, v in p.which[p.which[:, 0] < 2, :2]
        }

    before, now, new = by_vertex(found), by_vertex(held), by_vertex(fresh)
    assert all(now[v] == before[v] for v in before)
    assert any(new.get(v) != before[v] for v in before)
    assert all(now[v] == new[v] for v in now if v not in before)
    vertex = (held.which[:, 0] < 2) & (held.span_count >= 0)
    d = (held.W @ held.x)[vertex]
    np.testing.assert_allclose(d, held.phi[vertex, None] * held.e[vertex], rtol=0, atol=1e-12)
    y = held.x[held.cols[vertex]]  # (k, 4, 3): x_v, y_0, y_1, y_2
    spans = np.einsum("kij,kjl->kil", held.spans[vertex], y)
    count = held.span_count[vertex]
    for i in range(2):
        along = np.einsum("kl,kl->k", spans[:, i], held.e[vertex])
        assert np.abs(along[count > i]).max() < 1e-12
    contact.hold_pairs(False)
    for a, b in zip(keyed(fresh), keyed(contact._pairs())):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("degrees", "sharp"), [(29.5, False), (30.5, True), (-30.5, False)])
def test_an_edge_is_sharp_past_thirty_degrees_and_only_on_a_ridge(degrees, sharp):
    """Two triangles meeting on the x-axis, the second folded by ``degrees`` about it:
    down (a ridge) it is sharp past SHARP_ANGLE = 30 degrees, up (a valley) never."""
    from artifem.multibody.mesh_contact import _sharp

    a = np.radians(degrees)
    x = np.array([[0, 0, 0], [1, 0, 0], [0.5, -1, 0], [0.5, np.cos(a), -np.sin(a)]], float)
    tris = np.array([[0, 1, 2], [1, 0, 3]])
    normals = np.array([[0.0, 0.0, 1.0], [0.0, np.sin(a), np.cos(a)]])
    got = _sharp(x, tris, np.array([[0, 1]]), np.array([[0, 1]]), normals)
    assert got.tolist() == [sharp]
