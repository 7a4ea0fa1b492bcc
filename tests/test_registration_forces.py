"""artifem.registration.RegistrationForces: its forces are minus the gradient of its
energy and its stiffness the derivative of its forces (both ways, by finite
differences), and a free FEM cube whose surface is pulled onto a rigidly moved
copy of itself is moved rigidly onto it by the static solve (zero energy, no strain)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import artifem as af
from artifem.errors import InputError
from artifem.registration import RegistrationForces, TriangleSurface
from artifem.registration.forces import _evaluate, _features


def _surfaces(rng):
    """A box's triangulated surface (vertices jittered by 3 cm) and an ellipsoid target."""
    import pyvista as pv

    box = pv.Box(bounds=(-1.0, 1.0, -0.8, 0.8, -0.6, 0.6), level=2).triangulate().clean()
    x = np.asarray(box.points) + 0.03 * rng.standard_normal((box.n_points, 3))
    faces = np.asarray(box.faces).reshape(-1, 4)[:, 1:]
    target = TriangleSurface.from_polydata(pv.ParametricEllipsoid(1.1, 0.9, 0.7))
    return x, faces, target


def _along(x, faces, target, both_ways, v, h, part):
    """The central difference of ``_terms(...)[part]`` along v with step h."""
    return (
        _terms(x + h * v, faces, target, both_ways)[part]
        - _terms(x - h * v, faces, target, both_ways)[part]
    ) / (2 * h)


def _terms(x, faces, target, both_ways):
    """(E, f, K) at x on the features found at x."""
    return _evaluate(x, _features(x, faces, target, both_ways))


@pytest.mark.parametrize("both_ways", [False, True])
def test_forces_are_minus_the_energy_gradient(rng, both_ways):
    x, faces, target = _surfaces(rng)
    _, f, _ = _terms(x, faces, target, both_ways)
    for v in rng.standard_normal((3, *x.shape)):
        slope = _along(x, faces, target, both_ways, v, 1e-6, 0)
        assert slope == pytest.approx(-np.sum(f * v), rel=1e-6)


@pytest.mark.parametrize("both_ways", [False, True])
def test_the_stiffness_is_the_derivative_of_the_forces(rng, both_ways):
    """df/dx = K along random directions (central differences of 1e-7 m, within which no
    closest point changes its feature), and K is symmetric (a Hessian)."""
    x, faces, target = _surfaces(rng)
    _, _, K = _terms(x, faces, target, both_ways)
    for v in rng.standard_normal((3, *x.shape)):
        Kv = K @ v.ravel()
        np.testing.assert_allclose(
            _along(x, faces, target, both_ways, v, 1e-7, 1).ravel(),
            Kv,
            rtol=0,
            atol=1e-6 * np.abs(Kv).max(),
        )
    assert abs(K - K.T).max() < 1e-12 * abs(K).max()


CENTRE = np.full(3, 0.1)
#: the target's rigid motion x -> R (x - CENTRE) + CENTRE + T: 10 degrees, (10, -5, 8) mm
R = Rotation.from_rotvec(
    np.radians(10.0) * np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
).as_matrix()
T = np.array([0.01, -0.005, 0.008])


def _ellipsoid():
    """An ellipsoid (8 x 6 x 4 cm, 112 vertices) centred in the cube: (vertices, faces)."""
    import pyvista as pv

    ellipsoid = pv.ParametricEllipsoid(0.08, 0.06, 0.04, u_res=12, v_res=12).triangulate()
    ellipsoid = ellipsoid.clean()
    return np.asarray(ellipsoid.points) + CENTRE, np.asarray(ellipsoid.faces).reshape(-1, 4)[:, 1:]


def _registered_cube(vertices, faces, **forces):
    """A free 4 x 4 x 4 hex cube (0.2 m, neo-Hookean, no gravity) carrying the surface
    (vertices, faces), registered by RegistrationForces(**forces) in one static solve:
    (its nodes' displacement error against the rigid motion (R, T), the forces)."""
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    msh = dmesh.create_box(
        MPI.COMM_SELF, [np.zeros(3), np.full(3, 0.2)], [4, 4, 4], dmesh.CellType.hexahedron
    )
    body = af.FemBody(msh, af.NeoHookean.from_young_poisson(1e4, 0.3), 1000.0, name="cube")
    element = RegistrationForces(
        af.SkinMesh(vertices, faces, masters=[body], name="bone"), **forces
    )
    scene = af.Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(body, element)
    scene.solve_static()
    X = body.V.tabulate_dof_coordinates()
    expected = (X - CENTRE) @ R.T + CENTRE + T - X
    return np.abs(body.u.x.array.reshape(-1, 3) - expected).max(), element


def test_a_free_cube_is_registered_rigidly_onto_its_moved_surface():
    """The cube with the ellipsoid embedded as the model surface; the target is the
    ellipsoid moved by (R, T). The rigid motion is the only state of zero energy and
    zero strain: Scene.solve_static (one load step) reaches it, every node moved by
    (R - I) X + T to 1e-9 m (measured 6e-15, in 5 Newton iterations), both ways and
    with the model-to-target term alone."""
    vertices, faces = _ellipsoid()
    target = TriangleSurface((vertices - CENTRE) @ R.T + CENTRE + T, faces)
    for both_ways in (True, False):
        error, forces = _registered_cube(
            vertices, faces, target=target, weight=1e3, both_ways=both_ways
        )
        assert error < 1e-9
        assert forces.potential_energy(0.0) < 1e-18
    with pytest.raises(InputError, match="weight"):
        forces.weight = -1.0


def test_landmarks_alone_register_a_rigid_motion():
    """Three landmarks at the ellipsoid's extreme vertices along x, y and z (w = 0 for the
    surfaces: landmarks alone) pull the cube through the same rigid motion: the static
    solve reaches it (the only state of zero energy and strain with three non-collinear
    pairs) to 1e-9 m; the landmarks' energy and forces are w_l/2 |y - x|^2 and
    w_l (y - x)."""
    vertices, faces = _ellipsoid()
    moved = (vertices - CENTRE) @ R.T + CENTRE + T
    picks = [int(np.argmax(vertices[:, k])) for k in range(3)]
    gaps = moved[picks] - vertices[picks]
    skin = af.SkinMesh(vertices, faces, masters=[af.RigidBody("b", 1.0, np.eye(3))])
    unmoved = RegistrationForces(
        skin,
        TriangleSurface(moved, faces),
        0.0,
        landmarks=(picks, moved[picks]),
        landmark_weight=1e3,
    )
    assert unmoved.potential_energy(0.0) == pytest.approx(0.5e3 * np.sum(gaps**2))
    np.testing.assert_allclose(unmoved.vertex_forces()[picks], 1e3 * gaps)
    error, _ = _registered_cube(
        vertices,
        faces,
        target=TriangleSurface(moved, faces),
        weight=0.0,
        landmarks=(picks, moved[picks]),
        landmark_weight=1e3,
    )
    assert error < 1e-9
    with pytest.raises(InputError, match="landmarks"):
        RegistrationForces(skin, unmoved.target, 1.0, landmarks=([0, skin.n], moved[:2]))


def test_a_partial_target_registers_by_the_pairs_off_its_border():
    """The moved ellipsoid with its faces of z > 0.015 m (in its own frame) removed, the
    top third of its surface: the model vertices there find their closest points on the
    target's border and are dropped (Turk and Levoy), so the rigid motion is again the
    state of zero energy and the static solve reaches it (measured: 3e-12 m); keeping
    them (the border treated as any edge) leaves the cube 8 cm off."""
    vertices, faces = _ellipsoid()
    moved = (vertices - CENTRE) @ R.T + CENTRE + T
    keep = vertices[faces].mean(axis=1)[:, 2] - CENTRE[2] <= 0.015
    partial = TriangleSurface(moved, faces[keep])
    assert 0.2 < 1 - keep.mean() < 0.45 and partial.border_edges.size
    assert not TriangleSurface(moved, faces).border_edges.size
    error, forces = _registered_cube(vertices, faces, target=partial, weight=1e3)
    assert error < 1e-9
    assert (~forces.features().kept).sum() > 0.1 * len(vertices)  # pairs dropped
    assert forces.distances().max() < 1e-9
