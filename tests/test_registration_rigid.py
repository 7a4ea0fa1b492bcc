"""artifem.registration's rigid tools against known transforms: Kabsch recovers a rotation
and translation to round-off (and refuses a reflection), the closest points of a triangle
surface are exact on a cube, and ICP brings a moved copy of a surface's points back onto
it, trimmed ICP also when a fifth of the points have no counterpart."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from artifem.errors import InputError
from artifem.registration import TriangleSurface, icp, kabsch


def _box():
    """The unit cube's 8 vertices and 12 outward triangles."""
    v = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return v, np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])


def test_kabsch_recovers_a_rigid_motion_and_not_a_reflection(rng):
    p = rng.standard_normal((20, 3))
    R = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    t = np.array([0.5, -2.0, 1.0])
    R_fit, t_fit = kabsch(p, p @ R.T + t)
    np.testing.assert_allclose(R_fit, R, atol=1e-13)
    np.testing.assert_allclose(t_fit, t, atol=1e-13)
    mirrored = p * np.array([1.0, 1.0, -1.0])  # the best proper rotation, det +1
    R_fit, _ = kabsch(p, mirrored)
    assert np.linalg.det(R_fit) == pytest.approx(1.0, abs=1e-12)
    with pytest.raises(InputError, match="kabsch"):
        kabsch(p[:2], p[:2])


def test_closest_points_on_a_cube_are_exact():
    v, f = _box()
    cube = TriangleSurface(v, f)
    points = np.array([[0.5, 0.5, 2.0], [2.0, 2.0, 2.0], [0.5, 0.25, 0.5], [-1.0, 0.3, 0.5]])
    d, c = cube.closest(points)
    np.testing.assert_allclose(
        c, [[0.5, 0.5, 1.0], [1.0, 1.0, 1.0], [0.5, 0.0, 0.5], [0.0, 0.3, 0.5]], atol=1e-15
    )
    np.testing.assert_allclose(d, [1.0, np.sqrt(3.0), 0.25, 1.0], atol=1e-15)
    with pytest.raises(InputError, match="outside"):
        TriangleSurface(v, f + 8)


def _cube_surface():
    """pyvista's box [-1, 1]^3, each face split into 5 x 5 squares of two triangles."""
    import pyvista as pv

    return TriangleSurface.from_polydata(pv.Box(level=4))


def test_icp_brings_moved_points_back_onto_their_surface(rng):
    """100 of the cube's 152 vertices moved by 10 degrees and 5 cm: ICP from the identity
    finds the inverse motion (ICP converges linearly; the cube's faces meet at right
    angles, so no point can slide along the surface and it converges in about 80
    iterations: distances measured 1e-10, the rotation's entries to 7e-11)."""
    surface = _cube_surface()
    p = surface.vertices[rng.choice(len(surface.vertices), 100, replace=False)]
    R = Rotation.from_rotvec(np.radians(10.0) * np.array([0.6, 0.0, 0.8])).as_matrix()
    t = np.array([0.05, -0.03, 0.02])
    fit = icp(p @ R.T + t, surface, iterations=300)
    assert fit.iterations < 300
    assert fit.distances.max() < 1e-8 and fit.score < 1e-8
    np.testing.assert_allclose(fit.R, R.T, atol=1e-8)
    np.testing.assert_allclose(fit.t, -R.T @ t, atol=1e-8)


def test_trimmed_icp_ignores_points_without_a_counterpart(rng):
    """The same with 30 points 0.2-0.4 off the cube added (outliers, 23 % of 130): plain
    ICP is pulled off the motion; ICP on the closest 70 % of the pairs finds it."""
    surface = _cube_surface()
    p = surface.vertices[rng.choice(len(surface.vertices), 100, replace=False)]
    direction = rng.standard_normal((30, 3))
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    _, foot = surface.closest(3.0 * direction)
    outliers = foot + (0.2 + 0.2 * rng.random((30, 1))) * direction
    R = Rotation.from_rotvec(np.radians(8.0) * np.array([0.0, 1.0, 0.0])).as_matrix()
    t = np.array([0.03, 0.0, -0.02])
    moved = np.vstack([p, outliers]) @ R.T + t
    plain = icp(moved, surface, iterations=300)
    trimmed = icp(moved, surface, trim=0.7, iterations=300)
    np.testing.assert_allclose(trimmed.R, R.T, atol=1e-8)
    np.testing.assert_allclose(trimmed.t, -R.T @ t, atol=1e-8)
    assert trimmed.distances[:100].max() < 1e-8
    assert np.abs(plain.R - R.T).max() > 1e-3


def test_affine_fit_and_affine_icp_recover_a_scaled_and_sheared_motion(rng):
    """A map with scales 1.1, 0.95, 1.05, a shear and a rotation: affine_fit recovers it
    from exact pairs to round-off and refuses coplanar points; affine ICP of 100 of the
    cube's vertices onto the cube, started from the identity, finds its inverse (the
    points back on the surface to 1e-8), where rigid ICP cannot (distances of mm)."""
    from artifem.registration import affine_fit

    p = rng.standard_normal((30, 3))
    A = Rotation.from_rotvec([0.1, 0.2, -0.1]).as_matrix() @ np.array(
        [[1.1, 0.05, 0.0], [0.0, 0.95, 0.02], [0.0, 0.0, 1.05]]
    )
    t = np.array([0.02, -0.01, 0.03])
    A_fit, t_fit = affine_fit(p, p @ A.T + t)
    np.testing.assert_allclose(A_fit, A, atol=1e-13)
    np.testing.assert_allclose(t_fit, t, atol=1e-13)
    with pytest.raises(InputError, match="plane"):
        affine_fit(p * np.array([1.0, 1.0, 0.0]), p)
    surface = _cube_surface()
    q = surface.vertices[rng.choice(len(surface.vertices), 100, replace=False)]
    small = Rotation.from_rotvec([0.05, 0.0, 0.03]).as_matrix() @ np.diag([1.04, 0.97, 1.02])
    moved = q @ small.T + np.array([0.01, 0.02, -0.01])
    fit = icp(moved, surface, affine=True, iterations=300)
    assert fit.distances.max() < 1e-8
    assert icp(moved, surface, iterations=300).distances.max() > 1e-3


def test_the_border_of_an_open_surface():
    """The unit square as two triangles (0, 1, 2), (0, 2, 3): its four sides are border
    edges, the diagonal is not; points on a side or at a corner are on the border, on the
    diagonal or inside are not."""
    square = TriangleSurface([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    assert square.border_vertices.all() and square.border_edges.size == 4
    points = np.array(
        [[0.5, 0.0, 0.0], [1.0, 1.0, 0.0], [0.5, 0.5, 0.0], [0.7, 0.2, 0.0], [0.0, 0.3, 0.0]]
    )
    _, c, tri = square.closest_triangles(points + [0.0, 0.0, 0.2])
    assert square.on_border(tri, square.barycentric(c, tri)).tolist() == [
        True,
        True,
        False,
        False,
        True,
    ]
