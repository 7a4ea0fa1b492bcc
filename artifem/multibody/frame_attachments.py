"""Frames attached to deformable bodies (Lloyd et al. 2019, section 3.2).

A frame on an FEM body has its origin at an attached point
(:mod:`~artifem.multibody.point_attachments`) and its rotation from the
deformation around it. Both ways of the paper reduce to the rotation of a
3x3 matrix that is linear in the nodal positions x_j of a support,

    A = sum_j x_j c_j^T,   R = polar(A)   (A = R S, S symmetric positive definite),

- ``"polar"``: c_j = grad N_j(X_a), the shape-function gradients of the element
  containing the point, so A = F(X_a), the deformation gradient there;
- ``"procrustes"``: c_j = m_j (X_j - X_bar) over any support with weights m_j and
  weighted centroid X_bar (so sum_j c_j = 0), the rotation that best maps the
  support's rest offsets onto the current ones (Kabsch / orthogonal Procrustes).

Both give R = I at rest when rest offsets are used (A = S at rest for the
Procrustes case, F = I for polar) and recover any rigid rotation exactly.

A planar Procrustes support (e.g. the nodes of a face) has A n = 0 for its rest
normal n, so A = R S with S positive *semi*-definite of rank 2: R is then the
rotation of the Kabsch fit, U diag(1, 1, det U V^T) V^T from the SVD, unique as
long as the support is not collinear; everything below holds unchanged
(tr(S) I - S stays invertible). Such a frame cannot tell a mirrored face from a
turned one, so inversion is not detected there.

On a reduced body (u = u_bar + U q) the support's nodes are read from q and every
Jacobian below is multiplied by the support's rows of U.

Angular velocity: with A' = sum_j v_j c_j^T and w = R w_b,
R^T A' - A'^T R = [(tr(S) I - S) w_b]x, so

    w = R (tr(S) I - S)^-1 axial(R^T A' - A'^T R),

linear in the nodal velocities: w = G_w v. A frame attached to a deformable
body therefore has the 6 x 3k Jacobian [G_x; G_w], and a wrench [f; tau] on it
comes back to the nodes as G_x^T f + G_w^T tau (virtual work).
"""

from __future__ import annotations

import basix
import numpy as np

from artifem.errors import InputError
from artifem.fem_body import FemBody
from artifem.multibody.point_attachments import FemPointWeights, shape_function_weights

__all__ = ["FemFrame", "polar_rotation"]


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _axial(W: np.ndarray) -> np.ndarray:
    """a with W = [a]x, for a skew-symmetric W."""
    return np.array([W[2, 1], W[0, 2], W[1, 0]])


def collapsed(A: np.ndarray, planar: bool = False) -> bool:
    """True when :func:`polar_rotation` has no rotation for A: det A <= 0, or for a
    planar support its second singular value vanished."""
    if planar:
        s = np.linalg.svd(A, compute_uv=False)
        return not s[1] > 1e-12 * s[0]
    return not np.linalg.det(A) > 0


def polar_rotation(A: np.ndarray, planar: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(R, S) with A = R S, R a rotation and S symmetric (from the SVD; det R = +1).

    Raises ValueError for a singular or inverted A (det A <= 0): no frame there.
    ``planar``: A has rank 2 by construction (a planar support, module docstring);
    R = U diag(1, 1, det U V^T) V^T, and only a collapse to rank 1 is an error.
    """
    if collapsed(A, planar):
        raise InputError(
            f"polar_rotation: singular values {np.linalg.svd(A, compute_uv=False)}"
            f", det A = {np.linalg.det(A):.3g}: the support collapsed or "
            f"inverted; the frame's rotation is undefined"
        )
    U, s, Vt = np.linalg.svd(A)
    if planar:
        U[:, 2] *= np.linalg.det(U @ Vt)
        s[2] = 0.0
    R = U @ Vt
    S = Vt.T @ np.diag(s) @ Vt
    return R, S


class FemFrame:
    """A frame on an FEM body (full or reduced): origin at a point, rotation by polar
    decomposition.

    Args:
        body: the FEM body, a FemBody or a ReducedFemBody (u = u_bar + U q on its full
            body's dofs; the frame then reads the support's nodes from q).
        point: the frame's origin at rest. For ``"procrustes"`` it may be None: the
            origin is then the weighted centroid of the support, x_o = sum_j m_j x_j /
            sum_j m_j (a support point attachment, so forces spread over the support).
        method: ``"polar"`` (the element's deformation gradient at the point) or
            ``"procrustes"`` (a fit over ``support`` nodes, input indices, with
            optional ``support_weights`` m_j; a given point uses the containing
            element's shape functions).
    """

    def __init__(
        self,
        body,
        point=None,
        *,
        method: str = "polar",
        support=None,
        support_weights=None,
        snap: bool = False,
    ):
        if method not in ("polar", "procrustes"):
            raise InputError(f"FemFrame: method must be 'polar' or 'procrustes', got {method!r}")
        full = getattr(body, "full", body)
        if not isinstance(full, FemBody):
            raise TypeError(
                f"FemFrame: expected a FemBody or ReducedFemBody, got {type(body).__name__}"
            )
        self.body, self.full, self.method = body, full, method
        self._spec = {
            "point": point,
            "method": method,
            "support": support,
            "support_weights": support_weights,
            "snap": snap,
        }
        self.planar = False
        self.reduced = full is not body
        x = full.V.tabulate_dof_coordinates()
        if method == "polar" or point is not None:
            if point is None:
                raise InputError("FemFrame: a polar frame needs its origin point")
            self.origin: FemPointWeights = shape_function_weights(full, point, snap=snap)
        if method == "polar":
            self.dofs = self.origin.dofs
            self.c = self._gradients(self.origin.rest_position)
        else:
            if support is None or len(support) < 3:
                raise InputError("FemFrame: a Procrustes frame needs at least 3 support nodes")
            nodes = np.asarray(support, dtype=np.int64)
            self.dofs = full.local_dofs(nodes).astype(np.int64)
            if self.dofs.size != nodes.size:
                raise InputError(
                    f"FemFrame: support nodes {nodes.tolist()[:10]} are not all "
                    f"nodes of FEM body {full.name!r}"
                )
            m = (
                np.ones(nodes.size)
                if support_weights is None
                else np.asarray(support_weights, dtype=float)
            )
            if m.shape != nodes.shape or not np.all(m > 0):
                raise InputError(
                    f"FemFrame: support_weights must be {nodes.size} positive "
                    f"numbers, got {support_weights!r}"
                )
            X = x[self.dofs]
            centroid = m @ X / m.sum()
            self.c = m[:, None] * (X - centroid)
            s = np.linalg.svd(X.T @ self.c, compute_uv=False)
            if not s[1] > 1e-10 * s[0]:
                raise InputError(
                    f"FemFrame: support nodes {nodes.tolist()[:10]} are collinear: "
                    f"no rotation can be fitted"
                )
            self.planar = not s[2] > 1e-10 * s[0]
            if point is None:
                self.origin = FemPointWeights(self.dofs, m / m.sum(), centroid)
        # Rest rotation: identity for polar; the rest fit's rotation for Procrustes.
        self._X = x[self.dofs]
        self.A_rest = self._X.T @ self.c
        self.R_rest, _ = polar_rotation(self.A_rest, self.planar)

    def onto(self, reduced) -> "FemFrame":
        """This frame on ``reduced``, the reduced body of its full FEM body: the same
        origin, method and support, read from q."""
        if getattr(reduced, "full", None) is not self.full:
            raise InputError(
                f"FemFrame on {self.full.name!r}: {getattr(reduced, 'name', '')!r} "
                "is not a reduced body of it"
            )
        return FemFrame(reduced, **self._spec)

    def _gradients(self, X: np.ndarray) -> np.ndarray:
        """grad N_j(X) of the element containing the origin, (k, 3)."""
        msh = self.full.mesh
        cell = self.origin.cell
        nodes = msh.geometry.x[msh.geometry.dofmaps[0][cell]]
        ref = msh.geometry.cmaps[0].pull_back(X.reshape(1, 3), nodes)
        element = basix.create_element(
            basix.ElementFamily.P, getattr(basix.CellType, self.full.cell_name), 1
        )
        dN = element.tabulate(1, ref)[1:4, 0, :, 0]  # (3, k) d/dxi
        J = nodes.T @ dN.T  # dx/dxi
        return dN.T @ np.linalg.inv(J)  # (k, 3) dN/dX

    # ---- state ----------------------------------------------------------------------------

    def rows(self, dofs: np.ndarray) -> np.ndarray:
        """The blocked dof rows (3 per node, node-major) of ``dofs``."""
        return (3 * dofs[:, None] + np.arange(3)).ravel()

    def _nodal(self, dofs: np.ndarray, velocity: bool = False) -> np.ndarray:
        """Displacements (or velocities) of ``dofs``, (k, 3): u = u_bar + U q on a reduced body."""
        if self.reduced:
            r = self.rows(dofs)
            b = self.body
            u = b.U[r] @ b.qdot if velocity else b.u_bar[r] + b.U[r] @ b.q
            return u.reshape(-1, 3)
        array = self.body.v.x.array if velocity else self.body.u.x.array
        return array.reshape(-1, 3)[dofs]

    def matrix(self) -> np.ndarray:
        """A = sum_j x_j c_j^T at the current nodal positions."""
        return (self._X + self._nodal(self.dofs)).T @ self.c

    def position(self) -> np.ndarray:
        return self.origin.rest_position + self.origin.weights @ self._nodal(self.origin.dofs)

    def collapsed(self) -> bool:
        """True when the support (or the element at a polar frame's point) collapsed or
        inverted: no rotation is defined (:func:`collapsed`)."""
        return collapsed(self.matrix(), self.planar)

    def rotation(self) -> np.ndarray:
        """R = polar(A) R_rest^T: the identity at rest, the body's rotation under rigid motion."""
        R, _ = polar_rotation(self.matrix(), self.planar)
        return R @ self.R_rest.T

    def angular_velocity_jacobian(self) -> np.ndarray:
        """G_w (3 x 3k) with w = G_w v over the support dofs (module docstring).

        Column (j, a) is R N^-1 (c_j x R_a), N = tr(S) I - S and R_a the a-th row of R:
        for A' = e_a c_j^T, R^T A' - A'^T R = [c_j x R_a]x."""
        R, S = polar_rotation(self.matrix(), self.planar)
        N_inv = np.linalg.inv(np.trace(S) * np.eye(3) - S)
        cols = np.cross(self.c[:, None, :], R[None, :, :])  # (k, a, 3)
        return np.einsum("ij,kaj->ika", R @ N_inv, cols).reshape(3, -1)

    def angular_velocity(self) -> np.ndarray:
        return self.angular_velocity_jacobian() @ self._nodal(self.dofs, velocity=True).ravel()

    def torque_stiffness(self, torque) -> np.ndarray:
        """H = d(G_w^T tau)/dx at fixed tau (3k x 3k over the support dofs).

        G_w^T tau gives node j the force B c_j with B_a = R_a x m, m = N^-1 R^T tau.
        For dA: dw_b = N^-1 axial(R^T dA - dA^T R), dR = R [dw_b]x,
        dS = R^T dA - [dw_b]x S, dm = -N^-1 ((tr dS) I - dS) m - N^-1 [dw_b]x R^T tau,
        dB_a = dR_a x m + R_a x dm; and dA = sum_d c_kd E_ed for a move of node k along e.
        """
        tau = np.asarray(torque, dtype=float)
        R, S = polar_rotation(self.matrix(), self.planar)
        N_inv = np.linalg.inv(np.trace(S) * np.eye(3) - S)
        Rt_tau = R.T @ tau
        m = N_inv @ Rt_tau
        dB = np.zeros((3, 3, 3, 3))  # [e, d] -> dB (a, b) for dA = E_ed
        for e in range(3):
            for d in range(3):
                dA = np.zeros((3, 3))
                dA[e, d] = 1.0
                W = R.T @ dA - dA.T @ R
                dw = N_inv @ np.array([W[2, 1], W[0, 2], W[1, 0]])
                dR = R @ _skew(dw)
                dS = R.T @ dA - _skew(dw) @ S
                dm = -N_inv @ ((np.trace(dS) * np.eye(3) - dS) @ m + _skew(dw) @ Rt_tau)
                dB[e, d] = dR @ _skew(m) + R @ _skew(dm)  # rows: dR_a x m + R_a x dm
        H = np.einsum("edab,jb,kd->jake", dB, self.c, self.c)
        k = self.dofs.size
        return H.reshape(3 * k, 3 * k)

    def master_wrench(self, force, torque) -> tuple[np.ndarray, np.ndarray]:
        """(origin dofs, forces) and (support dofs, forces): G_x^T f and G_w^T tau, (k, 3) each."""
        f = np.outer(self.origin.weights, np.asarray(force, dtype=float))
        t = (self.angular_velocity_jacobian().T @ np.asarray(torque, dtype=float)).reshape(-1, 3)
        return (self.origin.dofs, f), (self.dofs, t)
