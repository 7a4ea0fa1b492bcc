"""Springs and muscles on points of FEM bodies in a Scene (multibody.point_paths.PointPath).

(1) statics: a spring from a fixed world point to a point of a cantilever (shape-function
    weights, and a 24-node support): the equilibrium from Scene.solve_static equals a
    FEM-only reference loaded by the equivalent nodal loads w_j f_s, f_s the converged spring
    force taken as a dead load; both solved to Newton tolerance 1e-12 (measured: they agree
    to 1.5e-15 of the largest displacement; the bound is 1e-10);
(2) the point map G and the path force against references that do not use G: G is a
    central difference of the points' positions, the force minus one of the spring's energy
    (and its damping part c Ldot times one of the path length), G z the points' velocities;
(3) stiffness: the assembled path stiffness G^T K G (+ lever terms of rigid frames) and the
    scene's static tangent match central finite differences of the assembled forces, also for
    a spring between the beam and a free rigid body;
(4) a spring 2500x stiffer than the beam stays stable in the (implicit) step at h = 0.01 s
    and is damped out by it, towards the static equilibrium.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.fem_body import FemBody
from artifem.forms import NeoHookean
from artifem.multibody.attachments import FemPoint
from artifem.multibody.point_paths import PointPath
from artifem.scene import Scene
from artifem.multibody.muscles import AxialSpring
from artifem.multibody.point_attachments import (
    nearest_nodes,
    shape_function_weights,
    support_weights,
)
from artifem.multibody.rigid_body import Frame, RigidBody, exp_so3

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")

ANCHOR = np.array([1.1, 0.1, 0.7])
POINT = np.array([0.95, 0.1, 0.2])  # on the top face near the tip


def beam(gravity=(0.0, 0.0, 0.0), rayleigh=(0.0, 0.0)):
    msh = dmesh.create_box(
        MPI.COMM_SELF,
        [np.zeros(3), np.array([1.0, 0.2, 0.2])],
        [10, 2, 2],
        dmesh.CellType.hexahedron,
    )
    body = FemBody(
        msh,
        NeoHookean.from_young_poisson(1e5, 0.3),
        1000.0,
        rayleigh=rayleigh,
        gravity=gravity,
        name="beam",
    )
    body.fix_nodes(body.find_nodes(lambda x: x[0] < 1e-12))
    return body


def weights_of(body, kind):
    if kind == "element":
        return shape_function_weights(body, POINT)
    return support_weights(body, POINT, nearest_nodes(body, POINT, 24))


@pytest.mark.parametrize("kind", ["element", "support24"])
def test_static_equilibrium_matches_the_equivalent_nodal_load(kind):
    body = beam()
    w = weights_of(body, kind)
    path = PointPath(AxialSpring(50.0, rest_length=0.3), [ANCHOR, FemPoint(body, w)])
    scene = Scene(gravity=(0, 0, 0))
    scene.add(body, path)
    scene.solve_static(load_steps=1, rtol=1e-12)
    f_s = path.evaluate(scene.t).forces[1]
    assert np.linalg.norm(f_s) > 1.0  # really loaded
    assert np.abs(body.u.x.array).max() > 0.02  # really bent

    ref = beam()
    inverse = {d: n for n, d in ref._input_node_to_dof().items()}
    nodes = np.array([inverse[int(d)] for d in w.dofs])
    ref.add_nodal_load(nodes, w.weights[:, None] * f_s[None, :])
    reference = Scene(gravity=(0, 0, 0))
    reference.add(ref)
    reference.solve_static(rtol=1e-12)
    scale = np.abs(ref.u.x.array).max()
    assert np.abs(body.u.x.array - ref.u.x.array).max() < 1e-10 * scale


def test_point_map_is_the_derivative_of_the_positions_and_forces_the_energy_gradient():
    """Against references that do not use G (Layout.path_map, all-space):

    (a) G P dq (P the prolongation) is the change of the path's point positions under a
        master displacement dq (the beam's free dofs and the bob's pose, Layout.displace):
        a central difference of FemPoint.position() and Frame.world_position() (the FEM
        point is linear in u; the frame turns by exp_so3: O(eps^2));
    (b) at rest, the path force P^T F (Layout.path_terms) is minus the gradient of the
        spring's energy k (L - L0)^2 / 2: a central difference of the energy of the
        displaced path;
    (c) moving, G z is the points' own velocities (the FEM point's weights on v, v + w x r
        of the frame), and the force changes by the damping -c Ldot dL/dx: its work along
        dq against c Ldot times a central difference of the path length.
    (G^T f . z = f . G z, the check this replaces, holds for any matrix G.)"""
    rng = np.random.default_rng(0)
    body = beam()
    bob = RigidBody("bob", 1.0, np.diag([0.1, 0.2, 0.3]), position=(1.2, 0.1, -0.5))
    pt = FemPoint(body, weights_of(body, "support24"))
    k, rest, c = 50.0, 0.2, 3.0
    path = PointPath(
        AxialSpring(k, rest, damping=c), [ANCHOR, pt, Frame.at_world(bob, (1.1, 0.15, -0.4))]
    )
    scene = Scene(gravity=(0, 0, 0))
    scene.add(body, bob, path)
    L = scene._ready()
    body.u.x.array[:] = 0.01 * rng.standard_normal(body.u.x.array.size)
    body.u.x.array.reshape(-1, 3)[body.fixed_dofs] = 0.0
    bob.rotation = exp_so3(rng.standard_normal(3))  # the frame's lever turns with it
    idx, G_local = L.path_map(path)
    G, P = np.zeros((G_local.shape[0], L.n_all)), L.prolongation()
    G[:, idx] = G_local
    n = scene.master_count()
    assert n == body.u.x.array.size - 3 * body.fixed_dofs.size + 6
    here = L.save()

    def along(dq, what, eps=1e-6):
        """(what(q + eps dq) - what(q - eps dq)) / (2 eps)."""
        values = []
        for sign in (1.0, -1.0):
            scene.displace_masters(sign * eps * dq)
            values.append(np.asarray(what()))
            L.restore(here)
            L.place_slaves()
        return (values[0] - values[1]) / (2 * eps)

    def energy():
        return 0.5 * k * (path.length() - rest) ** 2

    F_rest = L.path_terms(scene.t, None)[0]
    directions = []
    for rigid in (1.0, 0.0):  # all masters, then the beam alone
        dq = rng.standard_normal(n)
        dq[-6:] *= rigid
        directions.append(dq)
        fd = along(dq, path.positions)
        assert np.abs(fd.ravel() - G @ (P @ dq)).max() < 1e-7 * np.abs(fd).max()
        dE = along(dq, energy)
        assert abs(dE) > 1e-3
        assert abs(-(P.T @ F_rest) @ dq - dE) < 1e-7 * abs(dE)
    # moving: G z against the points' velocities, the damping force against dL/dq
    body.v.x.array[:] = rng.standard_normal(body.v.x.array.size)
    body.v.x.array.reshape(-1, 3)[body.fixed_dofs] = 0.0
    bob.set_twist(rng.standard_normal(6))
    z, xdot = L.current_velocities(), path.velocities()
    assert np.abs(xdot[1]).max() > 0.1 and np.abs(xdot[2]).max() > 0.1
    assert np.abs(G @ z - xdot.ravel()).max() < 1e-13 * np.abs(xdot).max()

    def polyline(x):
        return np.linalg.norm(np.diff(x, axis=0), axis=1).sum()

    x, eps = path.positions(), 1e-7
    length_rate = (polyline(x + eps * xdot) - polyline(x - eps * xdot)) / (2 * eps)
    assert abs(length_rate) > 0.1
    F_moving = L.path_terms(scene.t, None)[0]
    for dq in directions:
        work = (P.T @ (F_moving - F_rest)) @ dq
        assert abs(work + c * length_rate * along(dq, path.length)) < 1e-6 * abs(work)


def test_path_stiffness_and_static_tangent_by_finite_differences():
    rng = np.random.default_rng(1)
    body = beam(gravity=(0, 0, -9.81))
    bob = RigidBody(
        "bob", 0.2, np.diag([1e-3, 2e-3, 3e-3]), position=(1.2, 0.1, -0.3), rotation=np.eye(3)
    )
    pt = FemPoint(body, weights_of(body, "element"))
    hang = PointPath(AxialSpring(80.0, 0.2), [pt, Frame.at_world(bob, (1.15, 0.12, -0.25))])
    pull = PointPath(AxialSpring(50.0, 0.3), [ANCHOR, pt])
    scene = Scene(gravity=(0, 0, -9.81))
    scene.add(body, bob, hang, pull)
    L = scene._ready()
    body.u.x.array[:] = 0.02 * rng.standard_normal(body.u.x.array.size)
    body.u.x.array.reshape(-1, 3)[body.fixed_dofs] = 0.0
    F0, K, _ = L.path_terms(scene.t, None)
    # (a) path forces on the FEM dofs, FEM displacement directions
    o = L.fem_offset[id(body)]
    du = rng.standard_normal(body.u.x.array.size)
    du.reshape(-1, 3)[body.fixed_dofs] = 0.0
    dz = np.zeros(L.n_all)
    dz[o : o + du.size] = du
    eps = 1e-6
    saved = body.u.x.array.copy()
    body.u.x.array[:] = saved + eps * du
    Fp = L.path_terms(scene.t, None)[0]
    body.u.x.array[:] = saved - eps * du
    Fm = L.path_terms(scene.t, None)[0]
    body.u.x.array[:] = saved
    fd = (Fp - Fm) / (2 * eps)
    assert np.abs(fd - K @ dz).max() < 1e-6 * np.abs(fd).max()
    # (b) the whole static tangent on the masters (FEM dofs and the bob's pose)
    Kt = scene.static_tangent().toarray()
    n = scene.master_count()
    for _ in range(3):
        dq = rng.standard_normal(n)
        dq[-6:] *= 0.1
        s = L.save()
        scene.displace_masters(eps * dq)
        Fp = scene.master_forces()
        L.restore(s)
        scene.displace_masters(-eps * dq)
        Fm = scene.master_forces()
        L.restore(s)
        L.place_slaves()
        fd = -(Fp - Fm) / (2 * eps)
        assert np.abs(fd - Kt @ dq).max() < 1e-5 * np.abs(fd).max()


def stiff_spring_scene():
    body = beam(rayleigh=(0.0, 0.0))
    pt = FemPoint(body, weights_of(body, "support24"))
    # the cantilever's tip stiffness is 3 E I / L^3 = 40 N/m; the spring is 1e5 N/m
    path = PointPath(AxialSpring(1e5, rest_length=0.45), [ANCHOR, pt])
    scene = Scene(gravity=(0, 0, 0))
    scene.add(body, path)
    return scene, body, pt


def test_stiff_spring_is_stable_in_the_implicit_step():
    """Undamped, 100 steps of 0.01 s: backward Euler never gains energy and takes the stiff
    spring's fast mode out, leaving the beam near the static equilibrium of the same scene
    (E_static = 0.1808 J). Measured after 1 s: E - E_static = 2.74e-3 of e0 - E_static
    (0.890 J left of 259.3 J), and the point 0.44981 m from the anchor against the static
    0.45005 m (2.47e-4 m); the bounds are these x 1.25."""
    scene, body, pt = stiff_spring_scene()
    e0 = scene.energy()
    for _ in range(100):
        scene.step(0.01)
        assert np.all(np.isfinite(body.u.x.array))
        assert scene.energy() <= e0 * (1 + 1e-9)  # backward Euler: no energy gain
    static, _, twin = stiff_spring_scene()
    static.solve_static()
    minimum = static.energy()
    assert (scene.energy() - minimum) < 3.4e-3 * (e0 - minimum)  # bounds the kinetic energy
    # it pulled the point to about the spring's rest length from the anchor, as statics does
    distance, rest = (np.linalg.norm(p.position() - ANCHOR) for p in (pt, twin))
    assert abs(distance - rest) < 3.1e-4, (distance, rest)
