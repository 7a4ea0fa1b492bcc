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

from artifem.fem_body import FemBody
from artifem.multibody.point_attachments import FemPointWeights, shape_function_weights

__all__ = ["FemFrame", "polar_rotation"]


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _axial(W: np.ndarray) -> np.ndarray:
    """a with W = [a]x, for a skew-symmetric W."""
    return np.array([W[2, 1], W[0, 2], W[1, 0]])


def polar_rotation(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, S) with A = R S, R a rotation and S symmetric (from the SVD; det R = +1).

    Raises ValueError for a singular or inverted A (det A <= 0): no frame there.
    """
    if not np.linalg.det(A) > 0:
        raise ValueError(f"polar_rotation: det A = {np.linalg.det(A):.3g} <= 0 (inverted or "
                         f"collapsed support): the frame's rotation is undefined")
    U, s, Vt = np.linalg.svd(A)
    R = U @ Vt
    S = Vt.T @ np.diag(s) @ Vt
    return R, S


class FemFrame:
    """A frame on a full FEM body: origin at a point, rotation by polar decomposition.

    Args:
        body: the FEM body.
        point: the frame's origin at rest.
        method: ``"polar"`` (the element's deformation gradient at the point) or
            ``"procrustes"`` (a fit over ``support`` nodes, input indices, with
            optional ``support_weights``; the origin then uses the containing
            element's shape functions as well).
    """

    def __init__(self, body: FemBody, point, *, method: str = "polar", support=None,
                 support_weights=None, snap: bool = False):
        if method not in ("polar", "procrustes"):
            raise ValueError(f"FemFrame: method must be 'polar' or 'procrustes', got {method!r}")
        self.body, self.method = body, method
        self.origin: FemPointWeights = shape_function_weights(body, point, snap=snap)
        x = body.V.tabulate_dof_coordinates()
        if method == "polar":
            self.dofs = self.origin.dofs
            self.c = self._gradients(self.origin.rest_position)
        else:
            if support is None or len(support) < 3:
                raise ValueError("FemFrame: a Procrustes frame needs at least 3 support nodes")
            nodes = np.asarray(support, dtype=np.int64)
            self.dofs = body.local_dofs(nodes).astype(np.int64)
            if self.dofs.size != nodes.size:
                raise ValueError(f"FemFrame: support nodes {nodes.tolist()[:10]} are not all "
                                 f"nodes of FEM body {body.name!r}")
            m = np.ones(nodes.size) if support_weights is None else \
                np.asarray(support_weights, dtype=float)
            X = x[self.dofs]
            centroid = m @ X / m.sum()
            self.c = m[:, None] * (X - centroid)
            if np.linalg.matrix_rank(X.T @ self.c) < 3:
                raise ValueError(f"FemFrame: support nodes {nodes.tolist()[:10]} are collinear "
                                 f"or coplanar-degenerate: no rotation can be fitted")
        # Rest rotation: identity for polar; the rest fit's rotation for Procrustes.
        self.A_rest = x[self.dofs].T @ self.c
        self.R_rest, _ = polar_rotation(self.A_rest)

    def _gradients(self, X: np.ndarray) -> np.ndarray:
        """grad N_j(X) of the element containing the origin, (k, 3)."""
        msh = self.body.mesh
        cell = self.origin.cell
        nodes = msh.geometry.x[msh.geometry.dofmaps[0][cell]]
        ref = msh.geometry.cmaps[0].pull_back(X.reshape(1, 3), nodes)
        element = basix.create_element(basix.ElementFamily.P,
                                       getattr(basix.CellType, self.body.cell_name), 1)
        dN = element.tabulate(1, ref)[1:4, 0, :, 0]                      # (3, k) d/dxi
        J = nodes.T @ dN.T                                               # dx/dxi
        return dN.T @ np.linalg.inv(J)                                   # (k, 3) dN/dX

    # ---- state ----------------------------------------------------------------------------

    def _nodal(self, array) -> np.ndarray:
        return array.reshape(-1, 3)[self.dofs]

    def matrix(self) -> np.ndarray:
        """A = sum_j x_j c_j^T at the current nodal positions."""
        x = self.body.V.tabulate_dof_coordinates()[self.dofs] + self._nodal(self.body.u.x.array)
        return x.T @ self.c

    def position(self) -> np.ndarray:
        u = self.body.u.x.array.reshape(-1, 3)[self.origin.dofs]
        return self.origin.rest_position + self.origin.weights @ u

    def rotation(self) -> np.ndarray:
        """R = polar(A) R_rest^T: the identity at rest, the body's rotation under rigid motion."""
        R, _ = polar_rotation(self.matrix())
        return R @ self.R_rest.T

    def angular_velocity_jacobian(self) -> np.ndarray:
        """G_w (3 x 3k) with w = G_w v over the support dofs (module docstring)."""
        R, S = polar_rotation(self.matrix())
        inv = np.linalg.inv(np.trace(S) * np.eye(3) - S)
        k = self.dofs.size
        G = np.zeros((3, 3 * k))
        for j in range(k):
            for a in range(3):              # velocity component a of node j
                Adot = np.zeros((3, 3))
                Adot[a] = self.c[j]
                W = R.T @ Adot - Adot.T @ R
                G[:, 3 * j + a] = R @ inv @ _axial(W)
        return G

    def angular_velocity(self) -> np.ndarray:
        return self.angular_velocity_jacobian() @ self._nodal(self.body.v.x.array).ravel()

    def master_wrench(self, force, torque) -> tuple[np.ndarray, np.ndarray]:
        """(origin dofs, forces) and (support dofs, forces): G_x^T f and G_w^T tau, (k, 3) each."""
        f = np.outer(self.origin.weights, np.asarray(force, dtype=float))
        t = (self.angular_velocity_jacobian().T @ np.asarray(torque, dtype=float)).reshape(-1, 3)
        return (self.origin.dofs, f), (self.dofs, t)
