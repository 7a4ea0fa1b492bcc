"""The second derivative of a contact pair's signed distance: how its rows turn.

A pair of :mod:`artifem.multibody.mesh_contact` meets two affine features (a vertex and a
triangle, a vertex and an edge or a vertex of the other surface's closest point, two
edges) at their closest points, whose difference is a fixed combination of the pair's
points X_j (j = 1..4):

    d = sum_j w_j X_j = s e,     the w_j summing to zero, |e| = 1, s the signed distance,

the w_j affine in the closest points' parameters gamma along the features' spans
z_i = sum_j C_ij X_j (i = 1..m, m <= 2: none for two vertices, the edge for a vertex and
an edge, the triangle's two sides or the two edges), stationary where Z^T d = 0. Its
gradient is w_j e on X_j (the rows' coefficients: the stationarity leaves gamma out), and
its Hessian, the rows' turning stiffness lambda d^2 s / dX^2 that Newton needs where a
contact carries a load, is

    d^2 s / dX_j dX = e (dw_j / dX) + w_j de / dX,
    dgamma = -T^-1 (s dZ^T e + Z^T d_delta),        T = Z^T Z,  d_delta = sum_j w_j dX_j,
    de = P_perp d_delta / s - Z T^-1 dZ^T e,        P_perp = I - e e^T - Z T^-1 Z^T,

(differentiate Z^T d = 0 and e = d / s). P_perp is zero where Z and e span space (a
vertex over a face, two edges: no 1 / s there, so it holds through s = 0); it is the
curvature 1 / s of the distance to an edge or a vertex otherwise; the result is
symmetrized (its asymmetry is round-off). Checked against finite differences of the
gradient in tests/test_contact_mesh.py.
"""

from __future__ import annotations

import numpy as np

__all__ = ["distance_hessians"]


def distance_hessians(
    X: np.ndarray, w: np.ndarray, C: np.ndarray, spans: np.ndarray, e: np.ndarray, s: np.ndarray
) -> np.ndarray:
    """(k, 12, 12) the Hessians d^2 s / dX^2 of k pairs (module docstring) over their
    points' coordinates (point j's x, y, z at 3 j .. 3 j + 2).

    Args:
        X: (k, 4, 3) the pairs' points (world).
        w: (k, 4) the closest points' weights, d = sum_j w_j X_j = s e.
        C: (k, 2, 4) the spans' coefficients, z_i = sum_j C_ij X_j.
        spans: (k,) how many of the two spans each pair has (0, 1 or 2).
        e: (k, 3) the unit normals; s: (k,) the signed distances.
    """
    k = len(s)
    if not k:
        return np.zeros((0, 12, 12))
    on = np.arange(2)[None, :] < spans[:, None]  # (k, 2)
    C = np.where(on[:, :, None], C, 0.0)
    Z = np.einsum("kij,kja->kai", C, X)  # (k, 3, 2)
    T = np.einsum("kai,kaj->kij", Z, Z) + np.where(on, 0.0, 1.0)[:, :, None] * np.eye(2)
    Tinv = np.linalg.inv(T)
    eye = np.eye(3)
    # d_delta = D dX (k, 3, 12): w_j on point j's own coordinate; dZ^T e = ZE dX (k, 2, 12)
    D = np.einsum("kj,ab->kajb", w, eye).reshape(k, 3, 12)
    ZE = np.einsum("kij,kb->kijb", C, e).reshape(k, 2, 12)
    dgamma = -np.einsum(
        "kij,kjn->kin", Tinv, s[:, None, None] * ZE + np.einsum("kai,kan->kin", Z, D)
    )
    ZT = np.einsum("kai,kij->kaj", Z, Tinv)
    de = -np.einsum("kai,kin->kan", ZT, ZE)
    curved = spans < 2  # P_perp is zero when the spans and e fill space
    if np.any(curved):
        c = np.flatnonzero(curved)
        P = eye - np.einsum("ka,kb->kab", e[c], e[c]) - np.einsum("kai,kbi->kab", ZT[c], Z[c])
        de[c] += np.einsum("kab,kbn->kan", P, D[c]) / s[c, None, None]
    dw = np.einsum("kij,kin->kjn", C, dgamma)  # (k, 4, 12)
    H = np.einsum("ka,kjn->kjan", e, dw) + np.einsum("kj,kan->kjan", w, de)
    H = H.reshape(k, 12, 12)
    return 0.5 * (H + H.transpose(0, 2, 1))
