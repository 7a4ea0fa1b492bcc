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
from artifem.registration.forces import _terms


def _surfaces(rng):
    """A box's triangulated surface (vertices jittered by 3 cm) and an ellipsoid target."""
    import pyvista as pv

    box = pv.Box(bounds=(-1.0, 1.0, -0.8, 0.8, -0.6, 0.6), level=2).triangulate().clean()
    x = np.asarray(box.points) + 0.03 * rng.standard_normal((box.n_points, 3))
    faces = np.asarray(box.faces).reshape(-1, 4)[:, 1:]
    target = TriangleSurface.from_polydata(pv.ParametricEllipsoid(1.1, 0.9, 0.7))
    return x, faces, target


@pytest.mark.parametrize("both_ways", [False, True])
def test_forces_are_minus_the_energy_gradient(rng, both_ways):
    x, faces, target = _surfaces(rng)
    energy, f, _ = _terms(x, faces, target, both_ways)
    for _ in range(3):
        v = rng.standard_normal(x.shape)
        h = 1e-6
        slope = (_terms(x + h * v, faces, target, both_ways)[0]
                 - _terms(x - h * v, faces, target, both_ways)[0]) / (2 * h)
        assert slope == pytest.approx(-np.sum(f * v), rel=1e-6)


@pytest.mark.parametrize("both_ways", [False, True])
def test_the_stiffness_is_the_derivative_of_the_forces(rng, both_ways):
    """df/dx = K along random directions (central differences of 1e-7 m, within which no
    closest point changes its feature), and K is symmetric (a Hessian)."""
    x, faces, target = _surfaces(rng)
    _, _, K = _terms(x, faces, target, both_ways)
    for _ in range(3):
        v = rng.standard_normal(x.shape)
        h = 1e-7
        df = (_terms(x + h * v, faces, target, both_ways)[1]
              - _terms(x - h * v, faces, target, both_ways)[1]) / (2 * h)
        np.testing.assert_allclose(df.ravel(), K @ v.ravel(), rtol=0,
                                   atol=1e-6 * np.abs(K @ v.ravel()).max())
    assert abs(K - K.T).max() < 1e-12 * abs(K).max()


def test_a_free_cube_is_registered_rigidly_onto_its_moved_surface():
    """A 4 x 4 x 4 hex cube (0.2 m, neo-Hookean, no support, no gravity) with an ellipsoid
    (8 x 6 x 4 cm, 112 vertices) embedded at its centre as the model surface; the target
    is the ellipsoid turned by 10 degrees and moved by (10, -5, 8) mm. The rigid motion
    is the only state of zero energy and zero strain: Scene.solve_static (one load step)
    reaches it, every node moved by (R - I) X + t to 1e-9 m (measured 6e-15, in 5 Newton
    iterations), both ways and with the model-to-target term alone."""
    import pyvista as pv
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    centre = np.full(3, 0.1)
    ellipsoid = pv.ParametricEllipsoid(0.08, 0.06, 0.04, u_res=12, v_res=12).triangulate()
    ellipsoid = ellipsoid.clean()
    vertices = np.asarray(ellipsoid.points) + centre
    faces = np.asarray(ellipsoid.faces).reshape(-1, 4)[:, 1:]
    axis = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    R = Rotation.from_rotvec(np.radians(10.0) * axis).as_matrix()
    t = np.array([0.01, -0.005, 0.008])
    target = TriangleSurface((vertices - centre) @ R.T + centre + t, faces)
    for both_ways in (True, False):
        msh = dmesh.create_box(MPI.COMM_SELF, [np.zeros(3), np.full(3, 0.2)], [4, 4, 4],
                               dmesh.CellType.hexahedron)
        body = af.FemBody(msh, af.NeoHookean.from_young_poisson(1e4, 0.3), 1000.0,
                          name="cube")
        skin = af.SkinMesh(vertices, faces, masters=[body], name="bone")
        forces = RegistrationForces(skin, target, weight=1e3, both_ways=both_ways)
        scene = af.Scene(gravity=(0.0, 0.0, 0.0))
        scene.add(body, forces)
        scene.solve_static()
        X = body.V.tabulate_dof_coordinates()
        expected = (X - centre) @ R.T + centre + t - X
        np.testing.assert_allclose(body.u.x.array.reshape(-1, 3), expected, rtol=0,
                                   atol=1e-9)
        assert forces.potential_energy(0.0) < 1e-18
    with pytest.raises(InputError, match="weight"):
        forces.weight = -1.0


def test_landmarks_alone_register_a_rigid_motion():
    """Three landmarks on the ellipsoid's axes (w = 0 for the surfaces: landmarks alone)
    pull the free cube through the same rigid motion: the static solve reaches it (the
    only state of zero energy and strain with three non-collinear pairs) to 1e-9 m; the
    landmark forces are minus the gradient of their energy."""
    import pyvista as pv
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    centre = np.full(3, 0.1)
    ellipsoid = pv.ParametricEllipsoid(0.08, 0.06, 0.04, u_res=12, v_res=12).triangulate()
    ellipsoid = ellipsoid.clean()
    vertices = np.asarray(ellipsoid.points) + centre
    faces = np.asarray(ellipsoid.faces).reshape(-1, 4)[:, 1:]
    axis = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    R = Rotation.from_rotvec(np.radians(10.0) * axis).as_matrix()
    t = np.array([0.01, -0.005, 0.008])
    moved = (vertices - centre) @ R.T + centre + t
    picks = [int(np.argmax(vertices[:, k])) for k in range(3)]
    msh = dmesh.create_box(MPI.COMM_SELF, [np.zeros(3), np.full(3, 0.2)], [4, 4, 4],
                           dmesh.CellType.hexahedron)
    body = af.FemBody(msh, af.NeoHookean.from_young_poisson(1e4, 0.3), 1000.0, name="cube")
    skin = af.SkinMesh(vertices, faces, masters=[body], name="bone")
    forces = RegistrationForces(skin, TriangleSurface(moved, faces), weight=0.0,
                                landmarks=(picks, moved[picks]), landmark_weight=1e3)
    gaps = moved[picks] - vertices[picks]
    assert forces.potential_energy(0.0) == pytest.approx(0.5e3 * np.sum(gaps ** 2))
    np.testing.assert_allclose(forces.vertex_forces()[picks], 1e3 * gaps)
    scene = af.Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(body, forces)
    scene.solve_static()
    X = body.V.tabulate_dof_coordinates()
    np.testing.assert_allclose(body.u.x.array.reshape(-1, 3), (X - centre) @ R.T + centre + t - X,
                               rtol=0, atol=1e-9)
    with pytest.raises(InputError, match="landmarks"):
        RegistrationForces(skin, forces.target, 1.0, landmarks=([0, skin.n], moved[:2]))
