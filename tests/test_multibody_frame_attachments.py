"""Frames on FEM bodies: exact rigid rotations, angular-velocity Jacobian, virtual work."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.multibody.frame_attachments import FemFrame, polar_rotation
from artifem.multibody.point_attachments import nearest_nodes
from reduced_beam import make_body, ndofs

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="attachments are serial for now")

ORIGIN = np.array([0.61, 0.17, 0.07])


def frames(body):
    return [
        FemFrame(body, ORIGIN),
        FemFrame(body, ORIGIN, method="procrustes", support=nearest_nodes(body, ORIGIN, 12)),
    ]


def rigid_motion(body, Q, t):
    x = body.V.tabulate_dof_coordinates()
    body.u.x.array[:] = (x @ Q.T + t - x).ravel()


def test_a_rigid_rotation_is_recovered_exactly():
    body = make_body()
    Q = Rotation.from_rotvec([0.7, -1.9, 0.4]).as_matrix()  # a large rotation
    t = np.array([0.2, -0.1, 0.3])
    for frame in frames(body):
        body.u.x.array[:] = 0.0
        np.testing.assert_allclose(frame.rotation(), np.eye(3), atol=1e-13)
        rigid_motion(body, Q, t)
        np.testing.assert_allclose(frame.rotation(), Q, atol=1e-12)
        np.testing.assert_allclose(frame.position(), Q @ ORIGIN + t, atol=1e-12)


def _spin(R1, R0, eps):
    return Rotation.from_matrix(R1 @ R0.T).as_rotvec() / eps


@pytest.mark.parametrize("which", [0, 1])
def test_angular_velocity_jacobian_matches_finite_differences(which):
    body = make_body()
    rng = np.random.default_rng(which)
    Q = Rotation.from_rotvec([0.3, 0.5, -0.2]).as_matrix()
    rigid_motion(body, Q, np.zeros(3))
    body.u.x.array[: ndofs(body)] += 0.02 * rng.standard_normal(ndofs(body))  # and deformed
    frame = frames(body)[which]
    u0 = body.u.x.array.copy()
    v = rng.standard_normal(ndofs(body))
    body.v.x.array[: ndofs(body)] = v
    w = frame.angular_velocity()
    eps = 1e-6
    R0 = frame.rotation()
    body.u.x.array[: ndofs(body)] = u0[: ndofs(body)] + eps * v
    R1 = frame.rotation()
    body.u.x.array[:] = u0
    np.testing.assert_allclose(w, _spin(R1, R0, eps), rtol=1e-4, atol=1e-6 * np.abs(w).max())


def test_a_wrench_on_the_frame_does_the_work_of_its_nodal_forces():
    body = make_body()
    rng = np.random.default_rng(3)
    body.u.x.array[: ndofs(body)] = 0.01 * rng.standard_normal(ndofs(body))
    v = rng.standard_normal(ndofs(body))
    body.v.x.array[: ndofs(body)] = v
    for frame in frames(body):
        f, tau = rng.standard_normal(3), rng.standard_normal(3)
        (od, of), (sd, sf) = frame.master_wrench(f, tau)
        nodal = np.zeros((ndofs(body) // 3, 3))
        np.add.at(nodal, od, of)
        np.add.at(nodal, sd, sf)
        va = frame.origin.weights @ v.reshape(-1, 3)[frame.origin.dofs]
        assert f @ va + tau @ frame.angular_velocity() == pytest.approx(
            nodal.ravel() @ v, rel=1e-12
        )


def test_degenerate_supports_and_inverted_elements_are_errors():
    body = make_body()
    x = body.V.tabulate_dof_coordinates()
    inverse = {d: n for n, d in body._input_node_to_dof().items()}
    line = [
        inverse[d] for d in np.flatnonzero((np.abs(x[:, 1]) < 1e-12) & (np.abs(x[:, 2]) < 1e-12))
    ]
    with pytest.raises(ValueError, match="collinear"):
        FemFrame(body, ORIGIN, method="procrustes", support=line)
    with pytest.raises(ValueError, match="method"):
        FemFrame(body, ORIGIN, method="euler")
    with pytest.raises(ValueError, match="det A"):
        polar_rotation(np.diag([1.0, 1.0, -1.0]))


@pytest.mark.parametrize("which", [0, 1])
def test_torque_stiffness_matches_finite_differences(which):
    """H = d(G_w^T tau)/dx (analytic, through the polar decomposition's derivative)."""
    body = make_body()
    rng = np.random.default_rng(10 + which)
    rigid_motion(body, Rotation.from_rotvec([0.4, -0.3, 0.9]).as_matrix(), np.zeros(3))
    body.u.x.array[: ndofs(body)] += 0.02 * rng.standard_normal(ndofs(body))
    frame = frames(body)[which]
    tau = rng.standard_normal(3)
    H = frame.torque_stiffness(tau)
    rows = frame.rows(frame.dofs)
    dx = rng.standard_normal(rows.size)
    u0 = body.u.x.array.copy()

    def nodal(eps):
        body.u.x.array[rows] = u0[rows] + eps * dx
        return frame.angular_velocity_jacobian().T @ tau

    eps = 1e-6
    fd = (nodal(eps) - nodal(-eps)) / (2 * eps)
    body.u.x.array[:] = u0
    np.testing.assert_allclose(H @ dx, fd, rtol=1e-6, atol=1e-7 * np.abs(fd).max())


def test_procrustes_frame_without_a_point_sits_at_the_support_centroid():
    body = make_body()
    support = nearest_nodes(body, ORIGIN, 12)
    frame = FemFrame(body, method="procrustes", support=support)
    x = body.V.tabulate_dof_coordinates()[frame.dofs]
    np.testing.assert_allclose(frame.position(), x.mean(axis=0), atol=1e-15)
    Q = Rotation.from_rotvec([0.2, 1.1, -0.5]).as_matrix()
    rigid_motion(body, Q, np.array([0.1, 0.0, -0.2]))
    np.testing.assert_allclose(frame.position(), Q @ x.mean(axis=0) + [0.1, 0.0, -0.2], atol=1e-13)
    with pytest.raises(ValueError, match="origin point"):
        FemFrame(body)


def test_a_collapsed_support_is_a_cut_trial_not_an_error():
    """A mirrored support (det A < 0, e.g. a Newton trial too long) has no rotation: the
    frame says it collapsed, and a scene's layout leaves the attached marker where it was
    and reports the configuration inverted (the static line search then halves the step;
    a dynamic step fails its health check) instead of raising mid-solve."""
    from artifem.multibody.attachments import FrameAttachment
    from artifem.multibody.rigid_body import RigidBody
    from artifem.scene import Scene

    body = make_body()
    frame = frames(body)[1]
    marker = RigidBody.marker("marker", position=frame.position())
    scene = Scene()
    attachment = FrameAttachment(marker, frame)
    scene.add(body, marker, attachment)
    L = scene._direct_layout("test")
    x = body.V.tabulate_dof_coordinates()
    mirror = np.diag([1.0, 1.0, -1.0])
    body.u.x.array[:] = (x @ mirror.T - x).ravel()
    assert frame.collapsed()
    L.place_slaves()
    assert L.collapsed_frames == [attachment] and L.inverted()
    np.testing.assert_allclose(marker.position, ORIGIN, atol=1e-12)
    body.u.x.array[:] = 0.0
    L.place_slaves()
    assert not frame.collapsed() and not L.collapsed_frames and not L.inverted()
