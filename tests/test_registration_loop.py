"""artifem.registration.register: the continuation of static solves under a rising
registration weight. On a free FEM cube whose embedded ellipsoid must grow by 10 % to
meet its target, the mean distance falls at every stage (the penalty method's
monotonicity: a larger weight never leaves more registration energy at the minimum),
the loop stops when it changes by less than its tolerance, and a run interrupted after
two stages and resumed from its checkpoint ends where the uninterrupted run does."""

import numpy as np
import pytest

import artifem as af
from artifem.errors import InputError, StepFailed
from artifem.registration import RegistrationForces, TriangleSurface, register

WEIGHTS = [1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8]


def _scene():
    import pyvista as pv
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    centre = np.full(3, 0.1)
    ellipsoid = pv.ParametricEllipsoid(0.07, 0.05, 0.035, u_res=10, v_res=10).triangulate()
    ellipsoid = ellipsoid.clean()
    vertices = np.asarray(ellipsoid.points) + centre
    faces = np.asarray(ellipsoid.faces).reshape(-1, 4)[:, 1:]
    target = TriangleSurface(1.1 * (vertices - centre) + centre, faces)
    msh = dmesh.create_box(
        MPI.COMM_SELF, [np.zeros(3), np.full(3, 0.2)], [4, 4, 4], dmesh.CellType.hexahedron
    )
    body = af.FemBody(msh, af.NeoHookean.from_young_poisson(1e4, 0.3), 1000.0, name="cube")
    forces = RegistrationForces(af.SkinMesh(vertices, faces, masters=[body]), target, 1.0)
    scene = af.Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(body, forces)
    return scene, body, forces


def test_the_mean_distance_falls_with_the_weight_and_the_loop_stops(tmp_path):
    scene, body, forces = _scene()
    result = register(scene, [forces], WEIGHTS, tol=1e-4)
    d = np.array(result.mean_distance)
    assert d[0] > 1e-3  # the cube resists at w = 10
    assert np.all(np.diff(d) < 0)
    assert result.converged and len(d) < len(WEIGHTS)
    assert abs(d[-1] - d[-2]) < 1e-4 <= abs(d[-2] - d[-3])


def test_a_stage_stops_after_max_sweeps():
    """A tolerance no sweep meets (1e-300 m): each stage runs exactly ``max_sweeps`` sweeps of
    the ICP alternation, and says so."""
    scene, body, forces = _scene()
    result = register(scene, [forces], WEIGHTS[:2], tol=1e-300, max_sweeps=2)
    assert result.sweeps == [2, 2] and not result.converged


def test_a_resumed_registration_ends_where_an_uninterrupted_one_does(tmp_path):
    scene, body, forces = _scene()
    full = register(scene, [forces], WEIGHTS, tol=1e-7)
    u_full = body.u.x.array.copy()
    scene, body, forces = _scene()
    checkpoint = tmp_path / "registration.pkl"
    register(scene, [forces], WEIGHTS[:2], tol=1e-7, checkpoint=checkpoint)
    scene, body, forces = _scene()  # a new process: a fresh scene
    resumed = register(scene, [forces], WEIGHTS, tol=1e-7, checkpoint=checkpoint)
    assert resumed.weights == full.weights
    np.testing.assert_allclose(resumed.mean_distance, full.mean_distance, rtol=1e-12)
    np.testing.assert_allclose(body.u.x.array, u_full, rtol=0, atol=1e-12 * np.abs(u_full).max())
    with pytest.raises(InputError, match="checkpoint"):
        register(scene, [forces], [5.0, 50.0], checkpoint=checkpoint)


def test_bad_schedules_are_refused():
    scene, body, forces = _scene()
    with pytest.raises(InputError, match="increasing"):
        register(scene, [forces], [100.0, 10.0])
    other = RegistrationForces(forces.skin, forces.target, 1.0, name="not added")
    with pytest.raises(InputError, match="not in the scene"):
        register(scene, [other], WEIGHTS)


class _Jumpy:
    """The scene, but its static solve fails when the weight rose more than 3.5-fold
    since the last solve that succeeded, or, before any succeeded, is over ``first`` (a
    stand-in for a stage too far)."""

    def __init__(self, scene, forces, first=np.inf):
        self.scene, self.forces, self.last, self.first = scene, forces, None, first

    def __getattr__(self, name):
        return getattr(self.scene, name)

    def solve_static(self, **options):
        w = self.forces.weight
        if w > (self.first if self.last is None else 3.5 * self.last):
            raise StepFailed(f"weight {w:g} after {self.last}")
        self.last = w
        return self.scene.solve_static(**options)


def test_a_stage_that_fails_is_preceded_by_an_intermediate_weight():
    """From 10 to 1000 in one stage fails; the loop runs 100 (the geometric mean) first,
    which fails too, then 31.6, 100, 316 and 1000."""
    scene, body, forces = _scene()
    result = register(_Jumpy(scene, forces), [forces], [10.0, 1000.0], tol=1e-9)
    np.testing.assert_allclose(result.weights, [10.0, 10**1.5, 100.0, 10**2.5, 1000.0])
    assert np.all(np.diff(result.mean_distance) < 0)


def test_a_first_stage_that_fails_starts_from_a_tenth_of_its_weight():
    """The first weight, 100, fails before any stage succeeded: the continuation starts
    from a tenth of it, so 31.6 (the geometric mean of 10 and 100) runs first, then 100."""
    scene, body, forces = _scene()
    result = register(_Jumpy(scene, forces, first=50.0), [forces], [100.0], tol=1e-9)
    np.testing.assert_allclose(result.weights, [10**1.5, 100.0])
