"""Embedded point sets, polylines and triangle surfaces in full and reduced FEM bodies."""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
import pyvista as pv
from dolfinx import geometry, mesh as dmesh
from mpi4py import MPI

from artifem.errors import OutsideMeshError
from artifem.embedding import EmbeddedMesh
from artifem.fem_body import FemBody
from artifem.forms import NeoHookean
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from reduced_beam import make_body, random_basis

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="embedding is serial for now")

A = np.array([[0.1, -0.2, 0.05], [0.3, 0.02, -0.1], [0.0, 0.15, -0.05]])
C = np.array([0.01, -0.02, 0.03])
CENTRE = np.array([0.5, 0.45, 0.4])


def box_body(cell_type, n=(5, 4, 3)):
    """A distorted box (so hexahedra are not parallelepipeds: a real Newton pull-back)."""
    ct = getattr(dmesh.CellType, cell_type)
    msh = dmesh.create_box(MPI.COMM_WORLD, [np.zeros(3), np.array([1.0, 0.9, 0.8])], list(n), ct)
    x = msh.geometry.x
    x[:, 0] += 0.03 * np.sin(3.0 * x[:, 1]) * np.sin(2.0 * x[:, 2])
    x[:, 2] += 0.02 * np.cos(4.0 * x[:, 0]) * x[:, 1]
    return FemBody(msh, NeoHookean.from_young_poisson(1.0e4, 0.3), 1000.0)


def sphere(radius=0.3, res=16):
    s = pv.Sphere(radius=radius, center=CENTRE, theta_resolution=res, phi_resolution=res)
    s = s.triangulate().clean()
    return np.asarray(s.points, dtype=float), s.faces.reshape(-1, 4)[:, 1:]


def helix(n=200):
    t = np.linspace(0.0, 4.0 * np.pi, n)
    pts = CENTRE + np.c_[0.3 * np.cos(t), 0.3 * np.sin(t), 0.3 * (t / (2 * np.pi) - 1.0)]
    return pts, np.c_[np.arange(n - 1), np.arange(1, n)]


def set_affine(body):
    x = body.V.tabulate_dof_coordinates()
    body.u.x.array[:] = (x @ A.T + C).ravel()


@pytest.mark.parametrize("cell_type", ["hexahedron", "tetrahedron"])
@pytest.mark.parametrize("kind", ["vertex", "line", "triangle"])
def test_affine_displacement_reproduced_exactly(cell_type, kind):
    body = box_body(cell_type)
    rng = np.random.default_rng(0)
    if kind == "vertex":
        pts, cells = CENTRE + 0.35 * (rng.random((500, 3)) - 0.5), None
    elif kind == "line":
        pts, cells = helix()
    else:
        pts, cells = sphere()
    emb = EmbeddedMesh(body, pts, cells, kind)
    np.testing.assert_allclose(emb.rest_positions, pts, atol=1e-13)
    assert np.all(emb.distance == 0.0)
    # Weights: partition of unity, nonnegative inside.
    row_sums = np.asarray(emb.G.sum(axis=1)).ravel()
    np.testing.assert_allclose(row_sums, 1.0, atol=1e-13)
    assert emb.G.data.min() > -1e-12
    set_affine(body)
    np.testing.assert_allclose(emb.positions(), pts + pts @ A.T + C, atol=1e-13)
    poly = emb.to_pyvista()
    assert poly.n_points == len(pts)
    if kind == "triangle":  # the surface deforms by F = I + A: volume scales by det F
        vol0 = pv.PolyData(pts, np.c_[np.full(len(cells), 3), cells].ravel()).volume
        assert poly.volume == pytest.approx(np.linalg.det(np.eye(3) + A) * vol0, rel=1e-12)


def evaluate(function, points):
    """function(points) (p, 3) by DOLFINx's own point evaluation (bounding-box tree, colliding
    cells, Function.eval): a reference that does not use the embedding's weights."""
    msh = function.function_space.mesh
    tree = geometry.bb_tree(msh, msh.topology.dim)
    cells = geometry.compute_colliding_cells(
        msh, geometry.compute_collisions_points(tree, points), points
    )
    first = np.array([cells.links(i)[0] for i in range(len(points))], dtype=np.int32)
    return function.eval(points, first)


@pytest.mark.parametrize("cell_type", ["hexahedron", "tetrahedron"])
def test_velocities_and_forces_against_dolfinx_point_evaluation(cell_type):
    """Under a random (not affine) nodal velocity field v, the embedded vertices' velocities
    are v_h at their rest positions, as DOLFINx evaluates it; the nodal forces G^T f do
    the vertices' virtual work, f . v_h(X), and a central difference of the positions
    along v is the velocity. (f . G v = G^T f . v, the check this replaces, holds for any G.)"""
    body = box_body(cell_type)
    pts, tris = sphere()
    emb = EmbeddedMesh(body, pts, tris, "triangle")
    rng = np.random.default_rng(1)
    n3 = emb.G.shape[1]
    v = rng.standard_normal(n3)
    body.v.x.array[:n3] = v
    v_h = evaluate(body.v, emb.rest_positions)
    np.testing.assert_allclose(emb.velocities(), v_h, rtol=0, atol=1e-10 * np.abs(v_h).max())
    f = rng.standard_normal((emb.num_points, 3))
    work = float(np.sum(f * v_h))
    assert abs(work) > 1.0
    assert float(emb.force_to_nodes(f) @ v) == pytest.approx(work, rel=1e-10)
    # Total force is preserved (weights sum to one).
    np.testing.assert_allclose(
        emb.force_to_nodes(f).reshape(-1, 3).sum(axis=0), f.sum(axis=0), atol=1e-12
    )
    # positions: x_rest + u_h(X), also against DOLFINx, and their derivative along v
    u = 0.01 * rng.standard_normal(n3)
    body.u.x.array[:n3] = u
    x = emb.positions()
    np.testing.assert_allclose(
        x, emb.rest_positions + evaluate(body.u, emb.rest_positions), rtol=0, atol=1e-12
    )
    body.u.x.array[:n3] = u + 1e-3 * v
    np.testing.assert_allclose(
        (emb.positions() - x) / 1e-3, v_h, rtol=0, atol=1e-9 * np.abs(v_h).max()
    )


def test_outside_points_raise_or_snap_with_distance():
    # Undistorted box for exact distances.
    plain = FemBody(
        dmesh.create_box(
            MPI.COMM_WORLD, [np.zeros(3), np.ones(3)], [4, 4, 4], dmesh.CellType.hexahedron
        ),
        NeoHookean.from_young_poisson(1.0e4, 0.3),
        1000.0,
    )
    pts = np.array(
        [
            [0.5, 0.5, 0.5],  # inside
            [1.2, 0.5, 0.5],  # 0.2 beyond the face x = 1
            [-0.3, -0.4, 0.5],  # beyond the edge x = y = 0: distance 0.5
            [1.1, 1.2, 1.3],
        ]
    )  # beyond the corner: distance sqrt(.01+.04+.09)
    with pytest.raises(OutsideMeshError, match=r"3 embedded point\(s\).*point 2 at distance 0.5"):
        EmbeddedMesh(plain, pts)
    emb = EmbeddedMesh(plain, pts, snap=True)
    np.testing.assert_allclose(emb.distance, [0.0, 0.2, 0.5, np.sqrt(0.14)], atol=1e-12)
    np.testing.assert_allclose(emb.rest_positions, np.clip(pts, 0.0, 1.0), atol=1e-12)
    np.testing.assert_allclose(emb.G.sum(axis=1), 1.0, atol=1e-13)
    set_affine(plain)
    snapped = np.clip(pts, 0.0, 1.0)
    np.testing.assert_allclose(emb.positions(), snapped + snapped @ A.T + C, atol=1e-13)


def test_reduced_body_G_is_full_G_times_U():
    body = make_body()
    U = random_basis(body, 6, seed=3)
    reduced = ReducedFemBody(body, U, all_points(body))
    rng = np.random.default_rng(2)
    pts = np.array([0.0, 0.0, 0.0]) + rng.random((40, 3)) * np.array([1.0, 0.3, 0.2])
    emb_full = EmbeddedMesh(body, pts)
    emb_red = EmbeddedMesh(reduced, pts)
    np.testing.assert_allclose(emb_red.G_reduced, emb_full.G @ reduced.U, atol=1e-14)
    q = rng.standard_normal(reduced.r) * 1e-2
    qdot = rng.standard_normal(reduced.r)
    reduced.set_q(q)
    reduced.qdot = qdot
    n3 = emb_full.G.shape[1]
    body.u.x.array[:n3] = reduced.nodal_displacement()
    body.v.x.array[:n3] = reduced.nodal_velocity()
    np.testing.assert_allclose(emb_red.positions(), emb_full.positions(), atol=1e-14)
    np.testing.assert_allclose(emb_red.velocities(), emb_full.velocities(), atol=1e-13)
    f = rng.standard_normal((40, 3))
    # the generalized force is U^T of the full body's nodal force (itself checked against
    # DOLFINx's point evaluation above)
    np.testing.assert_allclose(
        emb_red.force_to_nodes(f), U.T @ emb_full.force_to_nodes(f), atol=1e-12
    )


def test_bad_input():
    body = box_body("tetrahedron", (2, 2, 2))
    with pytest.raises(ValueError, match="cell_type"):
        EmbeddedMesh(body, np.zeros((1, 3)) + 0.5, cell_type="quad")
    with pytest.raises(ValueError, match="shape"):
        EmbeddedMesh(body, np.zeros((2, 3)) + 0.5, [[0, 1, 2]], "line")
    with pytest.raises(ValueError, match="out of range"):
        EmbeddedMesh(body, np.zeros((2, 3)) + 0.5, [[0, 2]], "line")
    emb = EmbeddedMesh(body, np.zeros((2, 3)) + 0.5)
    with pytest.raises(ValueError, match="forces"):
        emb.force_to_nodes(np.zeros(3))


def test_point_attachment_snapping_to_a_hex_mesh_stays_in_the_element():
    """shape_function_weights(snap=True) delegates to locate_points: beyond a face and beyond a
    corner of a box, the closest point of the mesh with weights in [0, 1] summing to one."""
    from artifem.multibody.point_attachments import shape_function_weights

    body = FemBody(
        dmesh.create_box(
            MPI.COMM_WORLD, [np.zeros(3), np.ones(3)], [3, 4, 5], dmesh.CellType.hexahedron
        ),
        NeoHookean.from_young_poisson(1.0e4, 0.3),
        1000.0,
    )
    x_nodes = body.V.tabulate_dof_coordinates()
    for X, closest in (
        ([0.4, 1.25, 0.55], [0.4, 1.0, 0.55]),  # beyond the face y = 1
        ([-0.1, 1.2, 1.3], [0.0, 1.0, 1.0]),
    ):  # beyond a corner
        w = shape_function_weights(body, X, snap=True)
        assert w.weights.min() >= -1e-14 and w.weights.max() <= 1 + 1e-14
        assert w.weights.sum() == pytest.approx(1.0, abs=1e-14)
        np.testing.assert_allclose(w.rest_position, closest, atol=1e-12)
        np.testing.assert_allclose(w.weights @ x_nodes[w.dofs], closest, atol=1e-12)
        assert w.distance == pytest.approx(np.linalg.norm(np.subtract(X, closest)), rel=1e-12)
        with pytest.raises(ValueError, match=f"outside FEM body .*distance {w.distance:.4g}"):
            shape_function_weights(body, X)
    # A strongly distorted (trilinear) hexahedron: the old pull-back of the convex hull's
    # closest point extrapolated to weights of -0.05; now in [0, 1], and no sampled point of
    # the cell is closer than the snapped one.
    import basix
    import basix.ufl

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
    msh = dmesh.create_mesh(
        MPI.COMM_SELF,
        np.arange(8, dtype=np.int64).reshape(1, 8),
        basix.ufl.element("Lagrange", "hexahedron", 1, shape=(3,)),
        nodes,
    )
    body = FemBody(msh, NeoHookean.from_young_poisson(1.0e4, 0.3), 1000.0)
    grid = np.stack(np.meshgrid(*[np.linspace(0, 1, 21)] * 3, indexing="ij"), -1).reshape(-1, 3)
    hexahedron = basix.create_element(basix.ElementFamily.P, basix.CellType.hexahedron, 1)
    on_cell = hexahedron.tabulate(0, grid)[0, :, :, 0] @ msh.geometry.x[msh.geometry.dofmaps[0][0]]
    for X in ([2.0, 0.5, 0.5], [0.5, 0.5, -0.7]):
        w = shape_function_weights(body, X, snap=True)
        assert w.weights.min() >= -1e-14 and w.weights.max() <= 1 + 1e-14
        assert w.distance == pytest.approx(np.linalg.norm(w.rest_position - X), rel=1e-12)
        assert w.distance <= np.linalg.norm(on_cell - X, axis=1).min() + 1e-9


def test_a_point_just_past_a_slanted_face_is_located_in_the_tetrahedron_holding_it():
    """Points 1e-9 inside a tetrahedron across each interior face from the neighbour whose
    reference face xi_1 + xi_2 + xi_3 = 1 (the one opposite its first vertex) that face is:
    both cells collide within dolfinx's distance tolerance, and the one holding the point
    (all weights >= 0) is taken, not the neighbour it lies 1e-9 outside."""
    from artifem.embedding.embedded_mesh import locate_points

    body = box_body("tetrahedron", n=(2, 2, 2))
    msh = body.mesh
    msh.topology.create_connectivity(2, 3)
    msh.topology.create_connectivity(3, 2)
    faces_of, cells_of = msh.topology.connectivity(3, 2), msh.topology.connectivity(2, 3)
    x, dofs = msh.geometry.x, msh.geometry.dofmaps[0]
    points, holders = [], []
    for cell in range(msh.topology.index_map(3).size_local):
        slanted = set(dofs[cell][1:])  # the face opposite local vertex 0
        for face in faces_of.links(cell):
            pair = cells_of.links(face)
            if len(pair) != 2:
                continue
            other = int(pair[0] if pair[1] == cell else pair[1])
            if set(dofs[other]) - set(dofs[cell]) and slanted <= set(dofs[other]):
                inward = x[list(set(dofs[other]) - slanted)[0]] - x[list(slanted)].mean(axis=0)
                points.append(
                    x[list(slanted)].mean(axis=0) + 1e-9 * inward / np.linalg.norm(inward)
                )
                holders.append(other)
    assert len(points) > 10
    where = locate_points(body, np.array(points))
    np.testing.assert_array_equal(where.cells, holders)
    assert where.weights.min() >= 0.0 and np.all(where.distance == 0.0)
