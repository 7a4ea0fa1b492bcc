"""Force elements: springs, muscles and loads acting on rigid bodies as wrenches.

A force element gives the scene, at the end of each step (backward Euler reads
forces at t + h), the wrenches [force; torque about the COM] (world) it applies
to the bodies, and optionally their pose and velocity Jacobians so that the
element is implicit in the step (A = M - h D - h^2 K).
"""

from __future__ import annotations

from typing import Iterable, Protocol, Sequence, runtime_checkable

import numpy as np

from artifem.multibody.rigid_body import Frame, RigidBody, skew

__all__ = ["ForceElement", "JacobianBlock", "point_force_wrenches"]

#: (body_i, body_j, K_ij, D_ij): the 6 x 6 derivatives of the wrench on body i with
#: respect to body j's pose (K = df_i/dq_j) and velocity (D = df_i/du_j); either may be None.
JacobianBlock = tuple[RigidBody, RigidBody, "np.ndarray | None", "np.ndarray | None"]


@runtime_checkable
class ForceElement(Protocol):
    """What a force effector (spring, muscle, load) gives the step of a scene.

    ``wrenches(t)`` returns (body, wrench) pairs: the world wrench
    [force; torque about the body's COM] on each body it acts on, at the
    current poses and velocities and at time t (the end of the step, when
    backward Euler evaluates the forces: excitations are read at t). A point
    force f at a frame's origin is ``frame.wrench(f)``.

    Optional methods, used when present:

    - ``jacobians(t) -> Iterable[JacobianBlock]``: K_ij = df_i/dq_j and
      D_ij = df_i/du_j (stiffness and damping; the step uses -h D - h^2 K).
      Without it the element is explicit in the step. For a point force f(x)
      on points carried by frames, :func:`point_force_wrenches` builds both
      the wrenches and these blocks from the point forces and their Jacobians.
    - ``potential_energy() -> float``: its stored energy, for energy checks.
    """

    def wrenches(self, t: float) -> Iterable[tuple[RigidBody, np.ndarray]]: ...


def point_force_wrenches(
    frames: Sequence[Frame], forces, stiffness=None, damping=None
) -> tuple[list[tuple[RigidBody, np.ndarray]], list[JacobianBlock]]:
    """Map forces on points carried by frames to body wrenches and ForceElement Jacobians.

    Point i is the origin x_i of ``frames[i]`` (on body b_i; world frames carry
    nothing), with x_i' = G_i u_i, G_i = [1, -[r_i]x]. For forces f_i (n x 3) with
    K = df/dx and D = df/dv (3n x 3n, optional), virtual work gives

        wrench_b = sum_{i on b} G_i^T f_i,
        K_bc = sum_{i on b, j on c} G_i^T (K_ij G_j + D_ij [0, -[w_j]x [r_j]x])
               + delta_bc sum_{i on b} [0, 0; 0, [f_i]x [r_i]x],
        D_bc = sum_{i on b, j on c} G_i^T D_ij G_j,

    the second K term because v_j = v + w x r_j turns with the body, the third
    because the lever r_i does (``Frame.wrench_stiffness``).
    """
    n = len(frames)
    forces = np.asarray(forces, dtype=float).reshape(n, 3)
    wrenches: dict[int, list] = {}
    for frame, f in zip(frames, forces):
        if frame.body is not None:
            wrenches.setdefault(id(frame.body), [frame.body, np.zeros(6)])[1] += frame.wrench(f)
    blocks: dict[tuple[int, int], list] = {}

    def block(bi, bj):
        return blocks.setdefault((id(bi), id(bj)), [bi, bj, np.zeros((6, 6)), np.zeros((6, 6))])

    for frame, f in zip(frames, forces):
        if frame.body is not None:
            block(frame.body, frame.body)[2] += frame.wrench_stiffness(f)
    K = None if stiffness is None else np.asarray(stiffness, dtype=float).reshape(3 * n, 3 * n)
    D = None if damping is None else np.asarray(damping, dtype=float).reshape(3 * n, 3 * n)
    for i, fi in enumerate(frames):
        for j, fj in enumerate(frames):
            if fi.body is None or fj.body is None:
                continue
            entry = block(fi.body, fj.body)
            Gi, Gj = fi.jacobian(), fj.jacobian()
            if K is not None:
                entry[2] += Gi.T @ K[3 * i : 3 * i + 3, 3 * j : 3 * j + 3] @ Gj
            if D is not None:
                Dij = D[3 * i : 3 * i + 3, 3 * j : 3 * j + 3]
                entry[3] += Gi.T @ Dij @ Gj
                entry[2][:, 3:] -= Gi.T @ Dij @ skew(fj.body.angular_velocity) @ skew(fj.lever())
    return ([tuple(w) for w in wrenches.values()], [tuple(b) for b in blocks.values()])
