"""Skin meshes over rigid and FEM masters (Lloyd et al. 2019, section 4.1, eq. 8)."""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.fem_body import FemBody
from artifem.multibody.rigid_body import Frame, RigidBody, exp_so3
from artifem.multibody.skin import RigidMaster, SkinMesh, skin_weights
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from reduced_beam import make_body, ndofs, random_basis

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="skins are serial for now")

BLENDINGS = ["linear", "dual_quaternion"]


def rigid(name, position, rotation=None):
    return RigidBody(name, 1.0, np.diag([1.0, 1.5, 2.0]), position=position, rotation=rotation)


def cylinder(radius=1.0, length=4.0, n_theta=24, n_z=9, caps=False, center=(0.0, 0.0, 0.0)):
    """Rings of vertices along z; side triangles outward; optional capped ends (closed)."""
    th = 2 * np.pi * np.arange(n_theta) / n_theta
    z = np.linspace(0.0, length, n_z)
    V = np.array([[radius * np.cos(t), radius * np.sin(t), zz] for zz in z for t in th])
    F = []
    for j in range(n_z - 1):
        for i in range(n_theta):
            a, b = j * n_theta + i, j * n_theta + (i + 1) % n_theta
            c, d = a + n_theta, b + n_theta
            F += [[a, b, d], [a, d, c]]
    if caps:
        bottom, top = len(V), len(V) + 1
        V = np.vstack([V, [0.0, 0.0, 0.0], [0.0, 0.0, length]])
        last = (n_z - 1) * n_theta
        for i in range(n_theta):
            F.append([bottom, (i + 1) % n_theta, i])
            F.append([top, last + i, last + (i + 1) % n_theta])
    return V + np.asarray(center), np.array(F, dtype=np.int64)


def move(body, h, twist):
    """Advance a rigid body's pose by h along the twist [v; w] (world)."""
    body.position = body.position + h * twist[:3]
    body.rotation = exp_so3(h * twist[3:]) @ body.rotation


def random_rigid_motion(rng):
    axis = rng.standard_normal(3)
    return exp_so3(2.5 * axis / np.linalg.norm(axis)), rng.standard_normal(3)


def polygon_area(P):
    x, y = P[:, 0], P[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


@pytest.mark.parametrize("blending", BLENDINGS)
def test_common_rigid_motion_is_followed_exactly(blending):
    rng = np.random.default_rng(0)
    V, F = cylinder()
    bodies = [
        rigid("a", [0.0, 0.0, 0.0]),
        rigid("b", [0.3, 0.0, 4.0], exp_so3([0.2, 0.1, 0.0])),
        rigid("c", [0.0, 1.0, 2.0]),
    ]
    skin = SkinMesh(V, F, bodies, blending=blending, max_masters=3)
    np.testing.assert_allclose(skin.positions(), V, atol=1e-14)
    Rm, tm = random_rigid_motion(rng)
    for b in bodies:  # x -> Rm x + tm applied to every body's pose
        b.position = Rm @ b.position + tm
        b.rotation = Rm @ b.rotation
    np.testing.assert_allclose(skin.positions(), V @ Rm.T + tm, atol=1e-12)


def test_180_degree_twist_dqs_keeps_the_middle_section_lbs_collapses_it():
    V, F = cylinder(length=4.0, n_z=9)
    rings = V.reshape(9, -1, 3)
    mid = slice(4 * 24, 5 * 24)
    rest_area = polygon_area(rings[4])
    areas = {}
    for blending in BLENDINGS:
        a, b = rigid("a", [0.0, 0.0, 0.0]), rigid("b", [0.0, 0.0, 4.0])
        skin = SkinMesh(V, F, [a, b], blending=blending)
        np.testing.assert_allclose(skin.weights[mid], 0.5, atol=1e-12)  # equidistant
        b.rotation = exp_so3([0.0, 0.0, np.pi])
        x = skin.positions()
        areas[blending] = polygon_area(x[mid]) / rest_area
    assert areas["linear"] < 0.2, areas
    assert areas["dual_quaternion"] > 0.8, areas
    assert areas["linear"] < 1e-12 and abs(areas["dual_quaternion"] - 1.0) < 1e-12  # exact here


def test_dqs_aligns_quaternion_hemispheres():
    """Frames turned +170 and -170 degrees about z: their rotation quaternions lie in opposite
    hemispheres; aligned, the halfway blend is the short-path 180-degree turn, not identity."""
    V, F = cylinder(length=4.0, n_z=9)
    a = rigid("a", [0.0, 0.0, 0.0])
    b = rigid("b", [0.0, 0.0, 4.0])
    skin = SkinMesh(V, F, [a, b], blending="dual_quaternion")
    a.rotation = exp_so3([0.0, 0.0, np.radians(170.0)])
    b.rotation = exp_so3([0.0, 0.0, np.radians(-170.0)])
    mid = slice(4 * 24, 5 * 24)
    half_turn = np.diag([-1.0, -1.0, 1.0])
    np.testing.assert_allclose(skin.positions()[mid], V[mid] @ half_turn.T, atol=1e-12)


def test_weights_sum_to_one_and_the_closer_master_dominates():
    V = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 3.0], [0.0, 0.0, 2.0], [5.0, 0.0, 0.0]])
    a, b = rigid("a", [0.0, 0.0, 0.0]), rigid("b", [0.0, 0.0, 4.0])
    inv = SkinMesh(V, None, [a, b]).weights
    gauss = SkinMesh(V, None, [a, b], weighting="gaussian", sigma=1.0).weights
    for W in (inv, gauss):
        np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-15)
        assert W[0, 0] > W[0, 1] and W[1, 1] > W[1, 0]
        assert W[2, 0] == pytest.approx(0.5)
    # inverse square: 1/0.25 vs 1/12.25; Gaussian falls off faster than inverse square
    assert inv[0, 0] == pytest.approx(12.25 / 12.5)
    assert gauss[0, 0] > inv[0, 0]
    assert gauss[0, 0] == pytest.approx(1.0 / (1.0 + np.exp(-0.5 * (3.5**2 - 0.5**2))))
    # a master at zero distance takes it all; max_masters keeps the largest
    W = skin_weights(np.array([[0.0, 1.0, 2.0], [1.0, 2.0, 3.0]]), max_masters=2)
    np.testing.assert_allclose(W[0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(W[1], [0.8, 0.2, 0.0])
    # reference points on the body instead of the COM (a frame's origin)
    fr = Frame(a, position=[0.0, 0.0, 3.0])
    W = SkinMesh(V, None, [RigidMaster(fr), b]).weights
    assert W[1, 0] > W[1, 1]  # vertex at z = 3 sits on the frame's origin
    with pytest.raises(ValueError, match="sigma"):
        SkinMesh(V, None, [a, b], weighting="gaussian")


@pytest.mark.parametrize("blending", BLENDINGS)
def test_given_weights_are_renormalized_and_a_common_motion_is_followed(blending):
    """weights= rows that do not sum to 1 (here 2 to 7) are scaled to sum 1, in their
    proportions; so a rigid motion shared by both masters moves the skin rigidly."""
    rng = np.random.default_rng(21)
    V, F = cylinder(n_theta=8, n_z=4)
    a, b = rigid("a", [0.0, 0.0, 0.0]), rigid("b", [0.0, 0.0, 4.0])
    given = rng.uniform(1.0, 3.5, size=(len(V), 2))
    skin = SkinMesh(V, F, [a, b], weights=given, blending=blending)
    np.testing.assert_allclose(skin.weights.sum(axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(skin.weights, given / given.sum(axis=1, keepdims=True), rtol=1e-15)
    np.testing.assert_allclose(skin.positions(), V, atol=1e-14)
    R, t = random_rigid_motion(rng)
    for body in (a, b):
        body.position, body.rotation = R @ body.position + t, R @ body.rotation
    np.testing.assert_allclose(skin.positions(), V @ R.T + t, atol=1e-12)


def fd_velocity(skin, bodies, twists, fem=None, vfem=None, h=1e-6):
    """Central differences of the skin positions along the masters' velocities."""
    saved = [(b.position.copy(), b.rotation.copy()) for b in bodies]
    u0 = None if fem is None else fem.u.x.array.copy()
    out = []
    for sgn in (1.0, -1.0):
        for b, (p, R), tw in zip(bodies, saved, twists):
            b.position, b.rotation = p.copy(), R.copy()
            move(b, sgn * h, tw)
        if fem is not None:
            fem.u.x.array[:] = u0
            fem.u.x.array[: ndofs(fem)] += sgn * h * vfem
        out.append(skin.positions())
    for b, (p, R) in zip(bodies, saved):
        b.position, b.rotation = p, R
    if fem is not None:
        fem.u.x.array[:] = u0
    return (out[0] - out[1]) / (2 * h)


@pytest.mark.parametrize("blending", BLENDINGS)
def test_virtual_work_and_G_against_finite_differences(blending):
    """Rigid masters plus a FEM master; G is exact for both blendings (DQS analytically), so
    G u matches central differences of the skin positions to O(h^2), and the masters' forces
    G^T f do the work of the vertex forces f on those differences."""
    rng = np.random.default_rng(3)
    body = make_body()
    V = np.column_stack(
        [rng.uniform(0.05, 0.95, 40), rng.uniform(0.02, 0.28, 40), rng.uniform(0.02, 0.18, 40)]
    )
    bodies = [rigid("a", [-0.5, 0.1, 0.1]), rigid("b", [1.5, 0.2, 0.0], exp_so3([0.3, 0, 0]))]
    skin = SkinMesh(V, None, bodies + [body], weighting="gaussian", sigma=0.6, blending=blending)
    assert np.all(skin.weights > 1e-3)
    # move away from rest (large rotations) and set velocities
    move(bodies[0], 1.0, np.array([0.1, -0.2, 0.3, 0.4, -1.2, 0.7]))
    move(bodies[1], 1.0, np.array([0.2, 0.1, 0.0, -0.9, 0.5, 1.3]))
    body.u.x.array[: ndofs(body)] = 1e-2 * rng.standard_normal(ndofs(body))
    twists = [rng.standard_normal(6) for _ in bodies]
    vfem = rng.standard_normal(ndofs(body))
    for b, tw in zip(bodies, twists):
        b.set_twist(tw)
    body.v.x.array[: ndofs(body)] = vfem
    um = skin.master_velocities()
    G = skin.jacobian()
    assert G.shape == (3 * skin.n, 12 + ndofs(body))
    uv = (G @ um).reshape(-1, 3)
    fd = fd_velocity(skin, bodies, twists, body, vfem)
    err = np.abs(uv - fd).max() / np.abs(fd).max()
    assert err < 1e-7, err
    f = rng.standard_normal((skin.n, 3))
    fm = skin.master_forces(f, G)
    for direct, through_G in zip(skin.master_forces(f), fm):  # formed without assembling G
        np.testing.assert_allclose(direct, through_G, rtol=0, atol=1e-13 * np.abs(through_G).max())
    power_skin = float(np.sum(f * fd))
    power_masters = sum(float(fi @ ui) for fi, ui in zip(fm, np.split(um, [6, 12])))
    assert power_masters == pytest.approx(power_skin, rel=1e-7)
    # the rigid wrench of LBS is [f; r x f] weighted, r about the COM
    if blending == "linear":
        x_a = (
            skin.rest @ (bodies[0].rotation @ skin.masters[0].R0.T).T
            + skin.masters[0].transform()[1]
        )
        wa = skin.weights[:, 0, None] * f
        np.testing.assert_allclose(fm[0][:3], wa.sum(axis=0), atol=1e-13)
        np.testing.assert_allclose(
            fm[0][3:], np.cross(x_a - bodies[0].position, wa).sum(0), atol=1e-12
        )


def test_pressure_in_a_closed_skin_on_one_rigid_master_gives_no_net_wrench():
    V, F = cylinder(caps=True, center=[0.2, -0.1, 0.3])
    body = rigid("a", [1.0, 0.5, 2.0])
    skin = SkinMesh(V, F, [body], blending="dual_quaternion")
    move(body, 1.0, np.array([0.3, 0.1, -0.2, 0.5, 0.7, -0.4]))
    # the caps are outward: the enclosed volume is positive (pi r^2 L, polygonal)
    x = skin.positions()
    vol = np.einsum("ij,ij->", skin.face_area_vectors(x), x[F[:, 0]]) / 3.0
    assert vol == pytest.approx(0.5 * 24 * np.sin(2 * np.pi / 24) * 4.0, rel=1e-12)
    f = skin.pressure_forces(1.0e3)
    assert np.abs(f).max() > 10.0
    (wrench,) = skin.master_forces(f)
    assert np.abs(wrench).max() < 1e-9 * np.abs(f).sum()


def test_fem_skin_follows_affine_motion_and_pressure_sums_to_the_integral():
    body = make_body()
    rng = np.random.default_rng(5)
    # a flat sheet inside the beam (open surface) and some points just outside (snapped)
    s = np.linspace(0.05, 0.95, 7)
    t = np.linspace(0.03, 0.27, 4)
    V = np.array([[a, b, 0.13] for b in t for a in s])
    F = []
    for j in range(3):
        for i in range(6):
            p = j * 7 + i
            F += [[p, p + 1, p + 8], [p, p + 8, p + 7]]
    F = np.array(F, dtype=np.int64)
    skin = SkinMesh(V, F, [body])
    assert np.all(skin.masters[0].distance == 0.0)
    A = np.array([[0.1, -0.2, 0.05], [0.3, 0.02, -0.1], [0.0, 0.15, -0.05]])
    c = np.array([0.01, -0.02, 0.03])
    X = body.V.tabulate_dof_coordinates()
    body.u.x.array[:] = (X @ A.T + c).ravel()
    x = skin.positions()
    np.testing.assert_allclose(x, V + V @ A.T + c, atol=1e-14)
    # pressure: the nodal forces sum to p * sum(area * n) of the deformed sheet
    p = 250.0
    f = skin.pressure_forces(p)
    (fn,) = skin.master_forces(f)
    total = p * skin.face_area_vectors(x).sum(axis=0)
    np.testing.assert_allclose(fn.reshape(-1, 3).sum(axis=0), total, rtol=1e-13)
    np.testing.assert_allclose(fn.reshape(-1, 3).sum(axis=0), f.sum(axis=0), rtol=1e-13)
    # and their moment about the origin at rest equals the vertex forces' moment
    np.testing.assert_allclose(
        np.cross(X, fn.reshape(-1, 3)).sum(0), np.cross(V, f).sum(0), atol=1e-12
    )
    # the same skin on a reduced body matches the full one
    U = random_basis(body, 4, seed=2, scale=1e-2)
    red = ReducedFemBody(body, U, all_points(body))
    red.set_state((rng.standard_normal(4), rng.standard_normal(4)))
    rskin = SkinMesh(V, F, [red])
    red.to_full()
    np.testing.assert_allclose(rskin.positions(), skin.positions(), atol=1e-14)
    np.testing.assert_allclose(rskin.velocities(), skin.velocities(), atol=1e-13)
    fr = rskin.master_forces(f)[0]
    np.testing.assert_allclose(fr, U.T @ skin.master_forces(f)[0], atol=1e-12)
    # the reduced master's nodal displacement is the lifted state's (n, 3)
    np.testing.assert_allclose(
        rskin.masters[0].nodal_displacement(), skin.masters[0].nodal_displacement(), atol=1e-15
    )


def test_outside_vertices_are_snapped_and_bad_input_is_refused():
    body = make_body()
    V = np.array([[0.5, 0.15, 0.1], [0.5, 0.15, 0.3]])  # the second 0.1 above the top
    skin = SkinMesh(V, None, [body, rigid("a", [0.5, 0.15, 1.0])])
    np.testing.assert_allclose(skin.masters[0].distance, [0.0, 0.1], atol=1e-12)
    assert skin.weights[0, 0] == 1.0  # inside: zero distance
    assert skin.weights[1, 0] == pytest.approx(1 / 0.01 / (1 / 0.01 + 1 / 0.49))
    with pytest.raises(ValueError, match="blending"):
        SkinMesh(V, None, [body], blending="cubic")
    with pytest.raises(ValueError, match="weights"):
        SkinMesh(V, None, [body], weights=np.ones((3, 1)))
    with pytest.raises(TypeError):
        SkinMesh(V, None, ["jaw"])
    with pytest.raises(ValueError, match="faces"):
        SkinMesh(V, [[0, 1, 2]], [body])


def test_skin_pressure_load_element_is_G_transpose_and_does_the_same_work():
    """SkinPressure.master_loads: (body, G^T f_v) per master, f_m . u_m = f_v . u_v with u_v
    a central difference of the skin's positions along the masters' motion."""
    from artifem.multibody.skin import SkinPressure

    rng = np.random.default_rng(7)
    body = make_body()
    V, F = cylinder(radius=0.1, length=0.8, n_theta=12, n_z=5, caps=True, center=[0.1, 0.15, 0.1])
    V = V[:, [2, 1, 0]]  # along x, through the beam
    F = F[:, ::-1]  # the axis swap mirrors: re-orient outward
    jaw = rigid("jaw", [1.3, 0.15, 0.1])
    skin = SkinMesh(V, F, [body, jaw], weighting="gaussian", sigma=0.4)
    x = skin.positions()
    assert np.einsum("ij,ij->", skin.face_area_vectors(x), x[F[:, 0]]) > 0  # outward
    load = SkinPressure(skin, lambda t: 100.0 * t)
    move(jaw, 1.0, np.array([0.02, -0.01, 0.03, 0.2, -0.1, 0.3]))
    body.u.x.array[: ndofs(body)] = 1e-2 * rng.standard_normal(ndofs(body))
    jaw.set_twist(rng.standard_normal(6))
    body.v.x.array[: ndofs(body)] = rng.standard_normal(ndofs(body))
    loads = load.master_loads(2.0)
    assert [b for b, _ in loads] == [body, jaw]
    assert loads[0][1].shape == body.v.x.array.shape and loads[1][1].shape == (6,)
    f_v = skin.pressure_forces(200.0)
    # virtual work: the loads on the masters dotted with their motion (the FEM velocity and
    # the jaw's twist) equal the work of f_v on a central difference of the skin's positions
    # along that motion (SkinMesh.positions: no G involved; O(h^2), 1e-7 as above). (The
    # check this replaces, against skin.velocities() = G u, held for any G.)
    vfem, twist = body.v.x.array[: ndofs(body)].copy(), jaw.twist.copy()
    v_fd = fd_velocity(skin, [jaw], [twist], body, vfem)
    np.testing.assert_allclose(skin.velocities(), v_fd, rtol=0, atol=1e-7 * np.abs(v_fd).max())
    work_skin = float(np.sum(f_v * v_fd))
    work_fem, work_jaw = loads[0][1] @ body.v.x.array, loads[1][1] @ twist
    assert work_fem + work_jaw == pytest.approx(work_skin, rel=1e-7)
    # each master's share is real (>= 1 %), so dropping either load fails
    assert min(abs(work_fem), abs(work_jaw)) > 0.01 * abs(work_skin)
    # closed surface: the loads on all masters add up to no net force
    net = loads[0][1].reshape(-1, 3).sum(axis=0) + loads[1][1][:3]
    assert np.abs(net).max() < 1e-12 * np.abs(f_v).sum()
    with pytest.raises(ValueError, match="no faces"):
        SkinPressure(SkinMesh(V, None, [jaw]), 1.0)
    with pytest.raises(ValueError, match="finite"):
        SkinPressure(skin, float("nan"))
    with pytest.raises(ValueError, match="pressure"):
        SkinPressure(skin, lambda t: float("inf")).master_loads(0.0)


def test_skin_pressure_in_a_coupled_step_pushes_a_free_body():
    """An open sheet on a free rigid body: one step gives v = h p A n / m (explicit load)."""
    from artifem.scene import Scene
    from artifem.multibody.skin import SkinPressure

    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0], [0.0, 2.0, 0.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])  # normal +z, area 2
    body = RigidBody("plate", 0.5, np.eye(3), position=[0.5, 1.0, 0.0])
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(body, SkinPressure(SkinMesh(V, F, [body]), 3.0))
    h = 0.01
    scene.step(h)
    np.testing.assert_allclose(
        body.velocity, [0.0, 0.0, h * 3.0 * 2.0 / 0.5], rtol=1e-12, atol=1e-15
    )
    np.testing.assert_allclose(body.angular_velocity, 0.0, atol=1e-13)


def test_snapping_to_a_distorted_hexahedron_stays_in_the_element():
    """A point outside a strongly distorted (non-affine) hexahedron snaps to the closest point
    of the trilinear cell: weights in [0, 1], no farther than the nearest node, and the
    snapped point is a local minimum of the distance over the reference cube."""
    import basix
    from dolfinx import mesh as dmesh

    from artifem.fem_body import FemBody
    from artifem.forms import NeoHookean
    from artifem.multibody.skin import embedding_weights

    nodes = np.array(
        [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.3, 1.2, 0.4],
            [0.0, 0.0, 1.0],
            [1.0, -0.3, 1.1],
            [-0.2, 1.0, 1.0],
            [0.6, 0.7, 1.5],
        ]
    )
    element = basix.ufl.element("Lagrange", "hexahedron", 1, shape=(3,))
    msh = dmesh.create_mesh(
        MPI.COMM_SELF, np.arange(8, dtype=np.int64).reshape(1, 8), element, nodes
    )
    body = FemBody(msh, NeoHookean.from_young_poisson(1e4, 0.3), 1000.0)
    points = np.array([[1.8, 1.7, 0.3], [2.0, 0.5, 0.5], [0.5, 0.5, -0.7], [1.5, 1.5, 2.0]])
    b = basix.create_element(basix.ElementFamily.P, basix.CellType.hexahedron, 1)
    x_nodes = body.V.tabulate_dof_coordinates()
    grid = np.stack(np.meshgrid(*[np.linspace(0, 1, 21)] * 3, indexing="ij"), -1).reshape(-1, 3)
    on_cell = b.tabulate(0, grid)[0, :, :, 0] @ msh.geometry.x[msh.geometry.dofmaps[0][0]]
    for X, e in zip(points, embedding_weights(body, points)):
        assert e.weights.min() > -1e-12 and e.weights.max() < 1 + 1e-12
        assert e.distance == pytest.approx(np.linalg.norm(e.rest_position - X), rel=1e-12)
        assert e.distance <= np.linalg.norm(x_nodes - X, axis=1).min() + 1e-12
        # no sampled point of the cell is closer than the snapped one (up to the sampling)
        assert e.distance <= np.linalg.norm(on_cell - X, axis=1).min() + 1e-9


def _pressed_cantilever(pressure):
    """A clamped soft beam whose top face carries a skin (20 triangles) under a follower
    pressure: a load element on an FEM master."""
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    from artifem.forms import NeoHookean
    from artifem.multibody.skin import SkinPressure
    from artifem.scene import Scene

    msh = dmesh.create_box(
        MPI.COMM_SELF,
        [np.zeros(3), np.array([1.0, 0.2, 0.2])],
        [10, 2, 2],
        dmesh.CellType.hexahedron,
    )
    beam = FemBody(
        msh, NeoHookean.from_young_poisson(1e5, 0.3), 1000.0, name="beam", gravity=(0, 0, 0)
    )
    beam.fix_nodes(beam.find_nodes(lambda x: x[0] < 1e-12))
    V = np.array([[a, b, 0.2] for b in np.linspace(0, 0.2, 3) for a in np.linspace(0, 1, 11)])
    F = np.array(
        [
            f
            for j in range(2)
            for i in range(10)
            for f in (
                [j * 11 + i, j * 11 + i + 1, j * 11 + i + 12],
                [j * 11 + i, j * 11 + i + 12, j * 11 + i + 11],
            )
        ]
    )
    load = SkinPressure(SkinMesh(V, F, [beam]), pressure)
    scene = Scene(gravity=(0, 0, 0))
    scene.add(beam, load)
    return scene, beam, load


def test_follower_pressure_tangent_matches_finite_differences():
    """SkinPressure.master_load_jacobians enters the static tangent: -dF_m/dq by central
    differences of the master forces, at a bent state."""
    from coupled_fd import master_force_difference

    scene, beam, _ = _pressed_cantilever(-50.0)
    X = beam.V.tabulate_dof_coordinates()
    beam.u.x.array[2::3] = -0.05 * X[:, 0] ** 2
    beam.u.x.array[(3 * beam.fixed_dofs[:, None] + np.arange(3)).ravel()] = 0.0
    dq = np.random.default_rng(7).standard_normal(scene.master_count())
    K = scene.static_tangent()
    fd = master_force_difference(scene, dq, 1e-6)
    assert np.abs(fd + K @ dq).max() < 1e-8 * np.abs(fd).max()
    scene.loads.clear()  # without the load: a different K
    assert np.abs(fd + scene.static_tangent() @ dq).max() > 1e-4 * np.abs(fd).max()


def test_static_solve_with_a_follower_pressure_ramps_and_reaches_equilibrium():
    """The load element ramps with load_steps and its tangent enters Newton, so the static
    solve converges (it never did before); the converged state is the equilibrium of the
    final pressure forces, checked on a twin beam that carries them as dead nodal loads."""
    from artifem.scene import Scene

    scene, beam, load = _pressed_cantilever(-60.0)
    counts = scene.solve_static(load_steps=3, rtol=1e-11)
    assert len(counts) == 3 and max(counts) <= 12
    deflection = -beam.u.x.array[2::3].min()
    assert 0.02 < deflection < 0.2  # a large, real deflection
    F = scene._ready().load_vector(scene.t)  # the follower forces at the solution
    twin = FemBody(beam.mesh, beam.material, 1000.0, name="twin", gravity=(0, 0, 0))
    twin.fix_nodes(twin.find_nodes(lambda x: x[0] < 1e-12))
    node_of = {d: n for n, d in twin._input_node_to_dof().items()}
    nodes = np.array([node_of[d] for d in range(F.size // 3)])
    twin.add_nodal_load(nodes, F.reshape(-1, 3))
    reference = Scene(gravity=(0, 0, 0))
    reference.add(twin)
    reference.solve_static(load_steps=3, rtol=1e-11)
    assert np.abs(twin.u.x.array - beam.u.x.array).max() < 1e-7 * deflection
