"""Rigid-lift columns: a reduced body whose boundary nodes ride on a rigid body.

A reduced body cannot have some of its nodes *be* slaves of a bone the way a
full body's nodes are (a node's displacement is a row of U q, not a
coordinate), so the bone's motion is put into the basis instead. The nodes
J carried by a rigid body with pose (p, R) sit at x_j = p + R r_j,
r_j = R_0^T (X_j - p_0) fixed; their displacement

    d_j = (p - p_0) + (R - R_0) r_j = Phi_j g,     g = [p - p_0; vec(R - R_0)],
    Phi_j = [1, r_j1 1, r_j2 1, r_j3 1]            (3 x 12, vec column-major)

is *linear* in the 12 pose numbers g, exactly, at any rotation. The lift
columns L = E Phi (n_dofs x 12) extend Phi to the whole body by the linear
static response (Craig & Bampton 1968's constraint modes): on the free dofs
f,

    K_ff L_f = -K_fJ Phi_J,     L_J = Phi_J,     L = 0 on the fixed dofs,

K the body's tangent at its current state. Nodes held by other rigid bodies are held at
rest too (L = 0 there: ``held``), so that with several carriers each one's columns move
its own nodes only, and the lift of one bone leaves the other bones' nodes where their
own lifts put them. A basis [U, L] whose other
columns U vanish on J then reproduces the carried nodes exactly, and g is a
function of the bone's pose: in a Scene the 12 lift coordinates are
slaves of the body (``LiftAttachment``), with g' = G_g u,

    G_g = [[1, 0], [0, -[R_1]x], [0, -[R_2]x], [0, -[R_3]x]]     (12 x 6),

R_k the columns of R and u = [v; w] the body's twist; U q carries the rest
of the deformation (e.g. POD of snapshots with L g subtracted).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse import linalg as splinalg

from artifem.errors import InputError
from artifem.fem_body import FemBody

__all__ = ["RigidLift", "rigid_lift"]


@dataclass(frozen=True)
class RigidLift:
    """The 12 lift columns of nodes carried by a rigid body (module docstring).

    Attributes:
        nodes: input (mesh file) indices of the carried nodes.
        dofs: their local blocked dofs.
        position, rotation: p_0, R_0, the body's pose the lift was made at.
        offsets: r_j = R_0^T (X_j - p_0) (k, 3).
        columns: L (n_dofs x 12), block-interleaved like ``body.u.x.array``.
    """

    nodes: np.ndarray
    dofs: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    offsets: np.ndarray
    columns: np.ndarray

    def coordinates(self, position, rotation) -> np.ndarray:
        """g = [p - p_0; vec(R - R_0)] (column-major vec) for the pose (p, R)."""
        dR = np.asarray(rotation, dtype=float) - self.rotation
        return np.concatenate([np.asarray(position, dtype=float) - self.position, dR.T.ravel()])

    @staticmethod
    def jacobian(rotation) -> np.ndarray:
        """G_g (12 x 6): g' = G_g [v; w] (module docstring)."""
        G = np.zeros((12, 6))
        G[:3, :3] = np.eye(3)
        for k in range(3):
            c = rotation[:, k]
            G[3 + 3 * k : 6 + 3 * k, 3:] = -np.array(
                [[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]]
            )
        return G

    def node_map(self) -> np.ndarray:
        """Phi (3 k x 12): the carried nodes' displacements d = Phi g."""
        k = len(self.offsets)
        Phi = np.zeros((k, 3, 12))
        Phi[:, :, :3] = np.eye(3)
        for c in range(3):
            Phi[:, :, 3 + 3 * c : 6 + 3 * c] = self.offsets[:, c, None, None] * np.eye(3)
        return Phi.reshape(3 * k, 12)


def rigid_lift(body: FemBody, nodes, position, rotation, held=()) -> RigidLift:
    """The lift columns of ``nodes`` (input indices) carried by a rigid body at pose
    (``position``, ``rotation``), from ``body``'s tangent at its current state; ``held``:
    input indices of nodes other rigid bodies carry (kept at rest, L = 0 there).

    Raises InputError for nodes that are fixed in ``body`` or also held (a node is
    fixed, carried by one body, or free) and for a pose that is not a rotation.
    """
    if body.mesh.comm.size != 1:
        raise NotImplementedError("rigid_lift: serial only")
    p0 = np.asarray(position, dtype=float).reshape(3)
    R0 = np.asarray(rotation, dtype=float).reshape(3, 3)
    if not np.allclose(R0.T @ R0, np.eye(3), atol=1e-9) or np.linalg.det(R0) <= 0:
        raise InputError("rigid_lift: rotation is not a proper rotation matrix")
    nodes = body._check_nodes(np.asarray(nodes), "rigid_lift")
    dofs = body.local_dofs(nodes).astype(np.int64)
    fixed = np.intersect1d(dofs, body.fixed_dofs)
    if fixed.size:
        raise InputError(
            f"rigid_lift: {fixed.size} of the carried nodes are fixed in "
            f"{body.name!r}; a node is either fixed or carried"
        )
    held = (
        body.local_dofs(body._check_nodes(np.asarray(held, dtype=np.int64), "rigid_lift")).astype(
            np.int64
        )
        if len(held)
        else np.zeros(0, dtype=np.int64)
    )
    both = np.intersect1d(dofs, held)
    if both.size:
        raise InputError(
            f"rigid_lift: {both.size} of the carried nodes of {body.name!r} are "
            "also held by another rigid body; a node rides on one body"
        )
    n = body.V.dofmap.index_map.size_local + body.V.dofmap.index_map.num_ghosts
    X = body.V.tabulate_dof_coordinates()[dofs]
    offsets = (X - p0) @ R0
    lift = RigidLift(nodes, dofs, p0, R0, offsets, np.zeros((3 * n, 12)))
    J = (3 * dofs[:, None] + np.arange(3)).ravel()
    fixed_rows = (3 * np.concatenate([body.fixed_dofs, held])[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(3 * n), np.concatenate([J, fixed_rows]))
    body.assemble(tangent=True)
    indptr, indices, data = body.K.getValuesCSR()
    K = sparse.csr_matrix((data, indices, indptr), shape=body.K.getSize())
    Phi = lift.node_map()
    L = lift.columns
    L[J] = Phi
    L[free] = splinalg.splu(K[free][:, free].tocsc()).solve(-(K[free][:, J] @ Phi))
    return lift
