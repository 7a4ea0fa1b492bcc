"""An elastic-foundation contact law (artifem.multibody.foundation): compliant contact rows.

(a) a rigid box on a plane with a foundation sinks d = m g t / (K A) (K the confined
    modulus, A the bottom's area; its corners' facing areas sum to A) to 1e-9, in dynamics
    once settled and in statics (held upright by a slider joint); the normal forces sum to
    m g; an FEM block's bottom nodes' facing areas are its lumped boundary areas;
(b) the same box on a rigid slab through MeshContact sinks the same;
(c) compliance 0 is the hard row exactly (both paths, bitwise);
(d) the Schur complement, the sparse KKT and the statics' saddle solve agree with
    compliance (many rows, friction bounds from the compliant normal impulses), and the
    complementarity of compliant rows holds;
(e) a box dropped on a foundation never gains energy (kinetic + gravity + the layer's
    elastic energy, backward Euler) and sinks less than an undamped drop would;
(f) bad input names the contact.
"""

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

import artifem as af  # (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.errors import InputError
from artifem.multibody.constraint_rows import RowBlock
from artifem.multibody.contact_pressure import boundary_areas
from artifem.scene.constraints import StepRows, solve_constrained, solve_saddle
from artifem.scene.direct_solver import DirectSolver

sys.path.insert(0, str(Path(__file__).parent))
from test_contact_mesh import box_surface, floor  # noqa: E402
from test_contact_scale import _points_problem  # noqa: E402

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")

G, H = 9.81, 0.01
SIZE, MASS = np.array([0.2, 0.2, 0.1]), 2.0
AREA = SIZE[0] * SIZE[1]
LAYER = af.ElasticFoundation(young=1e6, poisson=0.3, thickness=0.005)
MODULUS = 1e6 * 0.7 / (1.3 * 0.4)  # E (1 - nu) / ((1 + nu)(1 - 2 nu))
SINK = MASS * G * LAYER.thickness / (MODULUS * AREA)  # 1.822e-6 m


def rigid_box(lift=0.0):
    a, b, c = SIZE
    return af.RigidBody(
        "box",
        MASS,
        MASS / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b]),
        position=(0.0, 0.0, SIZE[2] / 2 + lift),
        surface=box_surface(SIZE),
    )


def box_scene(kind, lift=0.0, guide=False, foundation=LAYER):
    box = rigid_box(lift)
    if kind == "plane":
        other = ()
        contact = af.PlaneContact(
            box,
            (0.0, 0.0, 0.0),
            (0.0, 0.0, 1.0),
            tolerance=1e-6,
            margin=0.05,
            foundation=foundation,
            name="layer",
        )
    else:
        other = (floor(),)
        contact = af.MeshContact(
            box, other[0], tolerance=1e-6, margin=0.05, foundation=foundation, name="layer"
        )
    scene = af.Scene(gravity=(0.0, 0.0, -G))
    scene.add(box, *other, contact)
    if guide:
        scene.add(af.SliderJoint(af.Frame(box), af.Frame(None), name="guide"))
    return scene, box, contact


# ---- (a), (b) a rigid box resting on a foundation ------------------------------------------


def test_the_modulus_and_the_corners_areas():
    """K = E (1 - nu) / ((1 + nu)(1 - 2 nu)); the bottom's two triangles give its corners
    A/3, A/6, A/3, A/6 (opposite corners equal: no tilt), summing to A; the top's none."""
    assert LAYER.modulus == pytest.approx(MODULUS, rel=1e-15)
    points = rigid_box().contact_points()
    z = np.tile([0.0, 0.0, 1.0], (8, 1))
    areas = points.facing_areas(np.arange(8), z)
    bottom = points.local[:, 2] < 0
    assert areas[bottom].sum() == pytest.approx(AREA, rel=1e-14)
    assert np.all(areas[~bottom] == 0)
    assert sorted(areas[bottom] / AREA) == pytest.approx([1 / 6, 1 / 6, 1 / 3, 1 / 3])
    np.testing.assert_allclose(
        LAYER.compliance(areas[bottom]), LAYER.thickness / (MODULUS * areas[bottom]), rtol=1e-15
    )


@pytest.mark.parametrize("kind", ["plane", "mesh"])
def test_a_rigid_box_sinks_into_the_layer_by_m_g_t_over_K_A(kind):
    """Set on the layer at rest, 40 steps of 0.01 s (omega h = 23: backward Euler settles
    it within a few steps, overshooting d once by 0.185 %, measured on both paths; the
    bound is 0.25 %). Measured: |sink / d - 1| = 8e-13 (plane), 1e-11 (mesh), d =
    1.822e-6 m; the normal forces sum to m g to 1e-12; no rotation."""
    scene, box, contact = box_scene(kind)
    sinks = []
    for _ in range(40):
        scene.step(H)
        sinks.append(SIZE[2] / 2 - box.position[2])
    assert SINK < max(sinks) < 1.0025 * SINK
    sink = SIZE[2] / 2 - box.position[2]
    assert sink == pytest.approx(SINK, rel=1e-9)
    forces = scene.contact_forces(contact)
    assert forces.normal.sum() == pytest.approx(MASS * G, rel=1e-9)
    np.testing.assert_allclose(box.rotation, np.eye(3), atol=1e-9)


@pytest.mark.parametrize("kind", ["plane", "mesh"])
def test_statics_of_a_box_held_by_the_layer(kind):
    """Scene.solve_static with a slider joint (the frictionless box is free sideways): the
    compliant rows make the saddle system regular; one Newton iteration (linear), |sink /
    d - 1| = 8e-13."""
    scene, box, _ = box_scene(kind, guide=True)
    scene.solve_static()
    assert SIZE[2] / 2 - box.position[2] == pytest.approx(SINK, rel=1e-9)


def test_fem_nodes_facing_areas_are_the_lumped_boundary_areas_of_the_bottom():
    """A 4 x 4 x 4 hexahedral cube: the bottom nodes' areas facing +z (its quadrilaterals
    by quarters) sum to the bottom's area and equal boundary_areas at the nodes inside
    the bottom face (which have no side facets), to 1e-15."""
    msh = dmesh.create_box(
        MPI.COMM_SELF, [np.zeros(3), np.full(3, 0.1)], [4, 4, 4], dmesh.CellType.hexahedron
    )
    body = af.FemBody(msh, af.NeoHookean.from_young_poisson(1e5, 0.3), 1000.0, name="block")
    nodes = body.contact_points()
    x = nodes.positions()
    bottom = np.flatnonzero(np.isclose(x[:, 2], 0.0))
    areas = nodes.facing_areas(bottom, np.tile([0.0, 0.0, 1.0], (len(bottom), 1)))
    assert areas.sum() == pytest.approx(0.01, rel=1e-14)
    inside = np.all((x[bottom, :2] > 1e-9) & (x[bottom, :2] < 0.1 - 1e-9), axis=1)
    lumped = boundary_areas(body)[nodes.dofs[bottom[inside]]]
    np.testing.assert_allclose(areas[inside], lumped, rtol=1e-13)


# ---- (c), (d) the solve with compliant rows ------------------------------------------------


def _compliant(rows, C):
    """The problem's rows with compliance C on its normal rows (C / h^2 on the step)."""
    g = rows[0]
    b = g.block
    full = np.zeros(len(g.c))
    full[: len(C)] = C
    block = RowBlock(
        b.owner, b.phi, b.jacobians, b.lo, b.hi, b.stiffness, b.friction, b.keys, compliance=full
    )
    return [StepRows(block, g.G, g.c, full / H**2)]


@pytest.mark.parametrize("path", ["kkt", "schur"])
def test_zero_compliance_is_the_hard_row_exactly(rng, path):
    """60 contacts with friction: compliance zeros gives bitwise the z and lambda of the
    hard block."""
    A, b, rows = _points_problem(rng, mu=0.5)
    z0, lam0, n0 = solve_constrained(DirectSolver(), A, b, rows, "t", path=path)
    z1, lam1, n1 = solve_constrained(
        DirectSolver(), A, b, _compliant(rows, np.zeros(60)), "t", path=path
    )
    assert n0 == n1
    assert np.array_equal(z0, z1) and np.array_equal(lam0, lam1)


@pytest.mark.parametrize("mu", [0.0, 0.5])
def test_schur_kkt_and_saddle_agree_with_compliance(rng, mu):
    """60 contacts on 600 dofs, compliance C / h^2 of the order of the rows' S diagonal:
    the KKT, the Schur complement and solve_saddle (statics' solve on the same matrix)
    give the same z and lambda to 1e-10 (measured 2e-15; 51 / 81 rows active; lambda
    74-78 % off the hard rows'); complementarity: lambda_n >= 0, G z - c +
    C lambda / h^2 >= 0, their product 0 (to 1e-10); some compliant rows active with
    lambda_n > 0, and stiffer than hard: their G z > c."""
    A, b, rows = _points_problem(rng, mu=mu)
    C = rng.uniform(0.5, 2.0, 60) * H**2  # S_ii ~ 1 / m_i ~ 0.7
    rows = _compliant(rows, C)
    info = {}
    z1, lam1, n1 = solve_constrained(DirectSolver(), A, b, rows, "t", path="kkt", info=info)
    assert info["path"] == "kkt"  # no fallback to the Schur complement
    z2, lam2, n2 = solve_constrained(DirectSolver(), A, b, rows, "t", path="schur")

    def kkt(K, G_on):
        return sparse.bmat([[K, G_on.T], [G_on, None]], format="csr")

    z3, lam3, _ = solve_saddle(DirectSolver(), kkt, A, b, rows, "t")
    assert n1 == n2
    for z, lam in ((z1, lam1), (z3, lam3)):
        np.testing.assert_allclose(z, z2, rtol=0, atol=1e-10 * np.abs(z2).max())
        np.testing.assert_allclose(lam, lam2, rtol=0, atol=1e-10 * np.abs(lam2).max())
    g = rows[0]
    slack = np.asarray(g.G @ z2).ravel()[:60] - g.c[:60] + C / H**2 * lam2[:60]
    scale = np.abs(g.c).max()
    assert lam2[:60].min() >= 0 and slack.min() >= -1e-10 * scale
    assert np.abs(lam2[:60] * slack).max() <= 1e-10 * scale * np.abs(lam2).max()
    pressed = lam2[:60] > 0
    assert pressed.sum() >= 10
    assert np.all((np.asarray(g.G @ z2).ravel()[:60] - g.c[:60])[pressed] < 0)


# ---- (e) energy of a drop --------------------------------------------------------------------


def test_a_box_dropped_on_the_layer_never_gains_energy():
    """Dropped from 2 cm (0.63 m/s at impact), h = 1e-3 (omega h = 2.3): kinetic + m g z +
    sum d_k^2 / (2 C_k) never grows (to 1e-12 J; measured: at most 1e-16, from 1.373 J
    to 0.981 J at rest); the deepest sink, 6.3402e-5 m measured (pinned to rel 1e-6), is
    below the undamped drop's, m g (lift + d) = k d^2 / 2 with k = K A / t: 2.7e-4 m (the
    energy check implies it), and beyond the rest sink; it bounces (backward Euler takes part
    of the energy each bounce) and comes to rest at d."""
    scene, box, contact = box_scene("plane", lift=0.02)
    bottom = np.flatnonzero(box.contact_points().local[:, 2] < 0)
    areas = box.contact_points().facing_areas(bottom, np.tile([0.0, 0.0, 1.0], (4, 1)))
    C = LAYER.compliance(areas)

    def energy():
        d = np.maximum(-contact.distances()[bottom], 0.0)
        return box.kinetic_energy() + MASS * G * box.position[2] + float(np.sum(d * d / C)) / 2

    e, deepest = energy(), 0.0
    for _ in range(300):
        scene.step(1e-3)
        e_new = energy()
        assert e_new <= e + 1e-12
        e = e_new
        deepest = max(deepest, -contact.distances().min())
    k, weight = MODULUS * AREA / LAYER.thickness, MASS * G
    undamped = (weight + np.sqrt(weight**2 + 2 * k * weight * 0.02)) / k  # 2.72e-4 m
    assert SINK < deepest < undamped
    assert deepest == pytest.approx(6.340240964e-5, rel=1e-6)
    assert SIZE[2] / 2 - box.position[2] == pytest.approx(SINK, rel=1e-6)


def test_deeper_than_the_layer_fails_the_step():
    """The step check allows the layer's thickness, not more."""
    scene, box, contact = box_scene("plane", lift=-0.004)
    assert contact.constraint_failure() is None
    box.position = box.position - np.array([0.0, 0.0, 0.002])
    assert "below the plane" in contact.constraint_failure()


# ---- (f) bad input ----------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["plane", "mesh"])
@pytest.mark.parametrize(
    "bad, word",
    [
        ((0.0, 0.3, 0.005), "Young"),
        ((-1e6, 0.3, 0.005), "Young"),
        ((1e6, 0.5, 0.005), "Poisson"),
        ((1e6, -1.0, 0.005), "Poisson"),
        ((1e6, 0.3, 0.0), "thickness"),
        ((1e6, 0.3, -1.0), "thickness"),
    ],
)
def test_bad_foundations_name_the_contact(kind, bad, word):
    with pytest.raises(InputError, match=f"contact 'layer'.*{word}"):
        box_scene(kind, foundation=af.ElasticFoundation(*bad))


def test_a_foundation_needs_a_rigid_body_s_surface_vertices():
    box = rigid_box()
    corners = box_surface(SIZE)[0][:4]
    with pytest.raises(InputError, match="surface vertices"):
        af.PlaneContact(box, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), points=corners, foundation=LAYER)


# ---- friction on the compliant normal impulses ------------------------------------------------

THETA = np.radians(30.0)
NORMAL = np.array([-np.sin(THETA), 0.0, np.cos(THETA)])
UPHILL = np.array([np.cos(THETA), 0.0, np.sin(THETA)])  # t_1 of the plane


@pytest.mark.parametrize("integrator", ["semi-implicit", "implicit"])
@pytest.mark.parametrize("mu", [0.6, 0.5])
def test_a_box_on_a_compliant_incline_sticks_or_slides(mu, integrator):
    """On a 30-degree incline with the layer, 100 steps: the normal forces sum to m g cos 30
    (1e-14), mu = 0.6 sticks (friction m g sin 30) and 0.5 slides with g (sin 30 - mu cos
    30) (measured to 4e-10): the friction bounds take the compliant normal impulses.
    Sticking, the friction's moment tilts the box on the layer: the corners' areas A/3,
    A/6, A/3, A/6 (the bottom's two triangles) couple the tilts about the two axes
    (stiffnesses S = 6 k0 (a/2)^2 and P = 2 k0 (a/2)^2 off the diagonal, k0 = K A / (6 t)),
    so it tilts S / (S^2 - P^2) = 9/8 of the equal-corner value about y (measured 1.1250
    to 1e-4) and -1/3 of that about x."""
    a, b, c = SIZE
    R0 = np.column_stack([UPHILL, [0.0, 1.0, 0.0], NORMAL])
    box = af.RigidBody(
        "box",
        MASS,
        MASS / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b]),
        position=NORMAL * c / 2,
        rotation=R0,
        surface=box_surface(SIZE),
    )
    contact = af.PlaneContact(
        box,
        (0.0, 0.0, 0.0),
        NORMAL,
        mu=mu,
        tolerance=1e-6,
        margin=0.05,
        foundation=LAYER,
        name="layer",
    )
    scene = af.Scene(gravity=(0.0, 0.0, -G), integrator=integrator)
    scene.add(box, contact)
    for _ in range(100):
        scene.step(H)
    forces = scene.contact_forces(contact)
    assert forces.normal.sum() == pytest.approx(MASS * G * np.cos(THETA), rel=1e-9)
    friction = forces.friction.sum(axis=0) @ UPHILL
    if mu == 0.6:
        assert friction == pytest.approx(MASS * G * np.sin(THETA), rel=1e-9)
        turn = R0.T @ box.rotation
        equal = MASS * G * np.sin(THETA) * c / 2 / (MODULUS * AREA * (a / 2) ** 2 / LAYER.thickness)
        assert turn[2, 0] / equal == pytest.approx(9 / 8, rel=1e-3)
        assert turn[2, 1] / turn[2, 0] == pytest.approx(-1 / 3, rel=1e-3)
        assert np.linalg.norm(box.velocity) < 1e-9
    else:
        acc = G * (np.sin(THETA) - mu * np.cos(THETA))
        assert -box.velocity @ UPHILL / (100 * H) == pytest.approx(acc, rel=1e-8)
        assert friction == pytest.approx(mu * MASS * G * np.cos(THETA), rel=1e-9)


# ---- an FEM block on a compliant incline, both paths -----------------------------------------


def test_an_fem_block_on_a_compliant_incline_is_the_same_on_both_paths(sliding_block):
    """A 6 x 6 x 3 hex block (588 dofs) thrown sideways at 0.3 m/s onto a plane tilted by 11
    degrees with a layer (E = 2e5 Pa, t = 4 mm), mu = 0.3: 219 rows (73 nodes with
    friction); over 40 steps of 5 ms the KKT path and the Schur complement give the same
    velocities and forces to the passes of the friction bounds' tolerance (they stop when
    the bounds change by 1e-10 of the largest impulse, each path from its own iterates: the
    KKT's searched on trials with the regularization's 1e-10 left in, then refined;
    measured 1.8e-14 m/s against 3.7e-5 m/s, and 2e-11 N against 0.15 N); each node's normal force
    is K A_k d_k / t with d_k its depth after the step
    and A_k its facing area at the start of the step (measured to 7e-13 of the largest
    force, the round-off of depths of 1e-5 m read off coordinates of 0.05 m; with the
    areas after the step, 6e-6: the block deforms); the deepest node, 1.15922563e-5 m on
    both paths (measured; pinned to rel 1e-6), is deeper than the tolerance (1e-5 m),
    allowed by the layer."""
    from artifem.bench_contact import forced_path

    soft = af.ElasticFoundation(2e5, 0.3, 0.004)
    runs = {}
    for path in ("kkt", "schur"):
        scene, body, pc = sliding_block(0.002, foundation=soft)
        nodes = body.contact_points()
        with forced_path(path):
            for step in range(40):
                if step == 39:  # the areas of the last step's rows
                    area = nodes.facing_areas(
                        np.arange(len(nodes)), np.tile(pc.normal, (len(nodes), 1))
                    )
                scene.step(0.005)
        assert scene.last_solve["path"] == path
        forces = scene.contact_forces(pc)
        runs[path] = (body.v.x.array.copy(), forces)
        index = {int(label): i for i, label in enumerate(nodes.labels)}
        k = np.array([index[int(p)] for p in forces.points])
        depth = np.maximum(-pc.distances()[k], 0.0)
        area = area[k]
        np.testing.assert_allclose(
            forces.normal,
            soft.modulus * area * depth / soft.thickness,
            rtol=0,
            atol=1e-11 * forces.normal.max(),
        )
        assert -pc.distances().min() == pytest.approx(1.15922563e-5, rel=1e-6)
    (v1, f1), (v2, f2) = runs["kkt"], runs["schur"]
    assert len(f2.normal) == 73 and np.count_nonzero(f2.normal) > 30
    np.testing.assert_allclose(v1, v2, rtol=0, atol=1e-9 * np.abs(v2).max())
    np.testing.assert_allclose(f1.normal, f2.normal, rtol=0, atol=1e-9 * f2.normal.max())
    np.testing.assert_allclose(f1.friction, f2.friction, rtol=0, atol=1e-9 * f2.normal.max())


def test_a_reduced_block_on_a_layer_is_the_full_block():
    """The 4 x 4 x 4 cube dropped on a layer with friction, full and reduced (the identity
    basis, every integration point; the contact by ``onto_reduced``, which keeps the
    foundation): the reduced nodes' facing areas (the full mesh's facets at x = X + u_bar
    + U q) give the same compliances, so it lands and rests as the full body to
    round-off, with the same forces."""
    from artifem.reduction.reduced_body import ReducedFemBody, all_points
    from test_contact_plane import fem_block

    soft = af.ElasticFoundation(2e5, 0.3, 0.004)
    block, twin = fem_block(lift=0.005), fem_block(lift=0.005)
    contact = af.PlaneContact(
        block,
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 1.0),
        mu=0.5,
        tolerance=1e-6,
        margin=0.02,
        foundation=soft,
    )
    n = 3 * twin.V.dofmap.index_map.size_local
    reduced = ReducedFemBody(twin, np.eye(n), all_points(twin), name="reduced block")
    twin_contact = af.PlaneContact(
        twin, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), mu=0.5, tolerance=1e-6, margin=0.02, foundation=soft
    ).onto_reduced(reduced)
    assert twin_contact.foundation is soft
    scenes = []
    for body, c in ((block, contact), (reduced, twin_contact)):
        scenes.append(af.Scene(gravity=(0.0, 0.0, -G)))
        scenes[-1].add(body, c)
    for _ in range(40):
        for scene in scenes:
            scene.step(H)
    u = block.u.x.array[:n]
    assert contact.distances().min() < -1e-6  # sunk into the layer
    np.testing.assert_allclose(
        reduced.nodal_displacement(), u, rtol=0, atol=1e-10 * np.abs(u).max()
    )
    full, red = scenes[0].contact_forces(contact), scenes[1].contact_forces(twin_contact)
    np.testing.assert_array_equal(full.points, red.points)
    np.testing.assert_allclose(red.normal, full.normal, rtol=0, atol=1e-9 * block.total_mass() * G)


def test_an_fem_block_on_a_layer_rests_the_same_on_a_slab_as_on_a_plane():
    """The 4 x 4 x 4 cube (1 kg) set on a layer (E = 2e5 Pa, t = 4 mm), 30 steps: through
    MeshContact on the rigid slab (its bottom nodes over the slab's top triangles, e =
    +z) and through PlaneContact, the same springs: the corner node at the slab's centre
    lies on the diagonal of its top face and has a row over each triangle, which share its
    area (without the sharing its spring counted twice: 8e-3 off in the first step). The
    same displacements (measured 3e-15 relative after the first step, 7e-10 after 30:
    the slab's rows are formed from its turned triangles, another round-off, carried by
    the settling block; not pinned down further) and forces; the forces sum to m g."""
    from test_contact_plane import fem_block

    soft = af.ElasticFoundation(2e5, 0.3, 0.004)
    runs = []
    for kind in ("plane", "mesh"):
        block = fem_block()
        if kind == "plane":
            other, contact = (
                (),
                af.PlaneContact(
                    block,
                    (0.0, 0.0, 0.0),
                    (0.0, 0.0, 1.0),
                    tolerance=1e-6,
                    margin=0.02,
                    foundation=soft,
                ),
            )
        else:
            other = (floor(),)
            contact = af.MeshContact(block, other[0], tolerance=1e-6, margin=0.02, foundation=soft)
        scene = af.Scene(gravity=(0.0, 0.0, -G))
        scene.add(block, *other, contact)
        for _ in range(30):
            scene.step(H)
        forces = scene.contact_forces(contact)
        assert forces.normal.sum() == pytest.approx(block.total_mass() * G, rel=1e-6)
        runs.append((block.u.x.array.copy(), np.sort(forces.normal)))
    (u1, f1), (u2, f2) = runs
    assert np.abs(u1).max() > 1e-5
    np.testing.assert_allclose(u2, u1, rtol=0, atol=1e-8 * np.abs(u1).max())
    np.testing.assert_allclose(f2, f1, rtol=0, atol=1e-8 * f1.max())


@pytest.mark.parametrize("scale", [1.0, 1e-14])
def test_redundant_compliant_rows_solve_alike_on_both_paths(rng, scale):
    """10 normal rows doubled (two springs on one dof), compliance C / h^2 = scale x (0.5
    .. 2), with friction: S + C / h^2 is positive definite on the normal rows, so their
    impulses are unique and both paths give the same z, normal impulses and forces G^T
    lambda (to 1e-10; the doubled friction rows stay hard, their split is not unique),
    the KKT without falling back.
    A compliance far below the KKT's regularization (scale 1e-14) is factored as eps
    and restored by the refinement: the hard solution's velocities to 1e-10."""
    A, b, rows = _points_problem(rng, redundant=10)
    hard = solve_constrained(DirectSolver(), A, b, rows, "t", path="schur")
    C = scale * rng.uniform(0.5, 2.0, 70) * H**2
    rows = _compliant(rows, C)
    info = {}
    z1, lam1, _ = solve_constrained(DirectSolver(), A, b, rows, "t", path="kkt", info=info)
    z2, lam2, _ = solve_constrained(DirectSolver(), A, b, rows, "t", path="schur")
    assert info["path"] == "kkt"
    np.testing.assert_allclose(z1, z2, rtol=0, atol=1e-10 * np.abs(z2).max())
    if scale == 1.0:  # the doubled friction rows stay hard: their sum unique
        np.testing.assert_allclose(lam1[:70], lam2[:70], rtol=0, atol=1e-10 * np.abs(lam2).max())
        Gm = rows[0].G
        np.testing.assert_allclose(
            Gm.T @ lam1, Gm.T @ lam2, rtol=0, atol=1e-10 * np.abs(lam2).max()
        )
    else:
        np.testing.assert_allclose(z1, hard[0], rtol=0, atol=1e-10 * np.abs(z2).max())


def test_the_contact_pressure_of_a_block_on_a_layer_is_the_law_s():
    """The 4 x 4 x 4 cube resting on a layer (E = 2e5 Pa, t = 4 mm), 30 steps:
    Scene.contact_pressure (f / the lumped boundary area, current configuration) at the
    nodes inside the bottom face is the layer's K d / t, d their depth (measured to 2e-5
    relative: the rows' areas are those at the start of the last step, and the block is
    still settling)."""
    from test_contact_plane import fem_block

    soft = af.ElasticFoundation(2e5, 0.3, 0.004)
    block = fem_block()
    contact = af.PlaneContact(
        block, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), tolerance=1e-6, margin=0.02, foundation=soft
    )
    scene = af.Scene(gravity=(0.0, 0.0, -G))
    scene.add(block, contact)
    for _ in range(30):
        scene.step(H)
    p = scene.contact_pressure(contact, configuration="current")[block.name]
    x0 = block.V.tabulate_dof_coordinates()
    dofs = block.local_dofs(p.points)
    inside = np.all((x0[dofs, :2] > 1e-9) & (x0[dofs, :2] < 0.1 - 1e-9), axis=1) & (
        np.abs(x0[dofs, 2]) < 1e-12
    )
    assert inside.sum() == 9
    x = x0 + block.u.x.array.reshape(-1, 3)
    depth = -x[dofs[inside], 2]
    np.testing.assert_allclose(p.pressure[inside], soft.modulus * depth / soft.thickness, rtol=1e-4)
