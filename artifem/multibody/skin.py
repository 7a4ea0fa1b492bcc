"""Skin meshes over several masters (Lloyd et al. 2019, section 4.1, eq. 8), serial.

Each vertex v of a skin follows the masters i = 1..M it is attached to,

    q_v = q_v0 + sum_i w_vi f_i(q_m, q_m0, q_v0),          sum_i w_vi = 1,

with three kinds of master:

- a rigid body (:class:`RigidMaster`, built from a RigidBody or a Frame on one):
  its motion since the skin was built is the rigid map T_i x = Rd_i x + t_i,
  Rd_i = R R_0^T, t_i = p - Rd_i p_0 (p, R: the COM pose now; p_0, R_0: when
  the skin was built, the *rest* pose). A Frame on a body moves with the body,
  so its map is the body's; the frame only supplies the reference point for
  the weights. Velocity dofs: the body's twist u = [v; w] (world, about the COM).
- a full FEM body (:class:`FemMaster`): f_i = sum_j N_j(X_v) u_j, the
  displacement interpolated with the embedding weights (shape functions) of the
  vertex's rest position X_v (:func:`shape_function_weights`); a vertex outside
  the mesh is snapped to the closest point of the nearest element and the
  snapping distance kept (``FemMaster.distance``). Dofs: the owned nodal
  velocities (block-interleaved, like ``body.v.x.array[:3 n]``).
- a reduced FEM body (:class:`ReducedMaster`): the same weights on
  u = u_bar + U q, so f_i = sum_j N_j (u_bar_j + U_j q); dofs: qdot (r).

Weights (``weighting``), per vertex over the masters, then normalized to sum 1:

- ``"inverse_square"`` (ArtiSynth's default): w_i ~ 1 / d_i^2. A master at
  distance d_i <= ``zero_distance`` takes all the weight (shared equally
  among such masters).
- ``"gaussian"``: w_i ~ exp(-d_i^2 / (2 sigma^2)) (a vertex with all weights
  under-flowing falls back to inverse-square).

Distances: to a rigid master's reference points (default: its COM, or the
frame's origin for a Frame; any points given in body coordinates, e.g. the
vertices of the body's surface or samples of a bone's axis, and the distance is
to the nearest of them - to points, not to the triangles between them); to a FEM
master: the distance from the vertex's rest position to the mesh (0 inside).
``max_masters`` keeps the k largest weights of each vertex (renormalized);
``weights=`` (n, M) overrides all of this (rows renormalized).

Blending of the rigid masters (``blending``); the FEM masters always add
linearly. With W_R = sum of the vertex's rigid weights and a_i = w_i / W_R:

- ``"linear"`` (LBS): sum_i w_i (T_i X_v - X_v). Velocity
  x_v' = sum_i w_i (v_i + w_i x r_i), r_i = T_i X_v - p_i, so the 3 x 6 block of G
  on master i is w_i [1, -[r_i]x]: exact.
- ``"dual_quaternion"`` (DQS, Kavan et al. 2008): W_R (T_b X_v - X_v), with T_b
  the rigid map of the normalized blend b = sum_i a_i s_i qhat_i of the unit
  dual quaternions qhat_i = q_i + eps (1/2)(0, t_i) q_i (q_i the rotation of
  Rd_i), s_i = sign(q_i . q_pivot) aligning them to the hemisphere of the
  vertex's heaviest rigid master (the pivot). With b = b_0 + eps b_e and X = (0, X_v):

      T_b X_v = vec(b_0 X b_0^* + 2 b_e b_0^*) / |b_0|^2

  (rotation by b_0 / |b_0| plus Kavan's translation 2 vec(b_e b_0^*) / |b_0|^2).
  G is the *exact* derivative of this rational function (no linearization
  error, no finite differences): with q_i' = (1/2)(0, w_i) q_i and
  t_i' = v_i - [t_i - p_i]x w_i,

      d b_0 = sum a_i s_i (1/2) R(q_i) E w_i,
      d b_e = sum a_i s_i [(1/2) R(q_i) E t_i' + (1/4) L((0, t_i)) R(q_i) E w_i],
      d N   = L(b_0 X) C d b_0 + R(X b_0^*) d b_0 + 2 R(b_0^*) d b_e + 2 L(b_e) C d b_0,
      d x   = vec(d N) / |b_0|^2 - vec(N) 2 (b_0 . d b_0) / |b_0|^4,

  L(p) q = p q, R(q) p = p q, C conjugation, E: R^3 -> pure quaternions. The
  hemisphere signs are piecewise constant: G is exact except exactly at a sign
  switch (q_i . q_pivot = 0), where the blend itself is discontinuous.

Both blendings reproduce a common rigid motion of all the rigid masters exactly.

Loads: vertex forces f_v (n, 3) go back to the masters by virtual work,
f_m = G^T f (:meth:`SkinMesh.master_forces`): a wrench [f; r x f] about the COM
per rigid master, nodal forces per FEM master, U^T-projected forces per reduced
master. A pressure p on the faces (:meth:`SkinMesh.pressure_forces`) gives each
face the force p * area * n (n along (x_1 - x_0) x (x_2 - x_0), i.e. outward for
an outward-oriented surface, so p > 0 inflates), a third to each of its vertices.
:class:`SkinPressure` makes that pressure a load element of a Scene
(``master_loads(t)``: f_m = G^T f_v per master, explicit in the step).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial.transform import Rotation

from artifem.errors import InputError
from artifem.embedding.embedded_mesh import locate_points
from artifem.fem_body import FemBody
from artifem.multibody.point_attachments import FemPointWeights
from artifem.multibody.rigid_body import Frame, RigidBody, cross, skew, skews
from artifem.reduction.reduced_body import ReducedFemBody

_LEVI_CIVITA = np.zeros((3, 3, 3))
_LEVI_CIVITA[0, 1, 2] = _LEVI_CIVITA[1, 2, 0] = _LEVI_CIVITA[2, 0, 1] = 1.0
_LEVI_CIVITA[0, 2, 1] = _LEVI_CIVITA[2, 1, 0] = _LEVI_CIVITA[1, 0, 2] = -1.0

__all__ = [
    "RigidMaster",
    "FemMaster",
    "ReducedMaster",
    "SkinMesh",
    "SkinPressure",
    "skin_weights",
    "embedding_weights",
]

WEIGHTINGS = ("inverse_square", "gaussian")
BLENDINGS = ("linear", "dual_quaternion")


# ---- quaternions (w, x, y, z) ------------------------------------------------------------


def _quat_left(p: np.ndarray) -> np.ndarray:
    """L(p) (..., 4, 4) with p q = L(p) q."""
    w, x, y, z = np.moveaxis(p, -1, 0)
    return np.stack(
        [
            np.stack([w, -x, -y, -z], -1),
            np.stack([x, w, -z, y], -1),
            np.stack([y, z, w, -x], -1),
            np.stack([z, -y, x, w], -1),
        ],
        -2,
    )


def _quat_right(q: np.ndarray) -> np.ndarray:
    """R(q) (..., 4, 4) with p q = R(q) p."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([w, -x, -y, -z], -1),
            np.stack([x, w, z, -y], -1),
            np.stack([y, -z, w, x], -1),
            np.stack([z, y, -x, w], -1),
        ],
        -2,
    )


def _qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    return np.einsum("...ij,...j->...i", _quat_left(p), q)


_CONJ = np.diag([1.0, -1.0, -1.0, -1.0])
_E = np.vstack([np.zeros((1, 3)), np.eye(3)])  # R^3 -> pure quaternions


def _pure(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return np.concatenate([np.zeros(x.shape[:-1] + (1,)), x], axis=-1)


def _quat_of_rotation(R: np.ndarray) -> np.ndarray:
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


# ---- masters -------------------------------------------------------------------------------


class RigidMaster:
    """A rigid master: a RigidBody, or a Frame on one (see the module docstring).

    ``reference``: points in body coordinates (relative to the COM, body axes)
    the weight distances are measured to (the nearest of them); default the
    COM, or the frame's origin for a Frame. Its rest pose is recorded by
    :meth:`record_rest` (done by SkinMesh when it is built).
    """

    kind = "rigid"

    @property
    def scene_body(self):
        """The body of the scene its forces act on: the rigid body."""
        return self.body

    def __init__(self, master: RigidBody | Frame, reference=None):
        if isinstance(master, Frame):
            if master.body is None:
                raise InputError(
                    "a skin master frame must be attached to a rigid body (a "
                    "world frame does not move: leave it out)"
                )
            body, default = master.body, master.position.reshape(1, 3)
        elif isinstance(master, RigidBody):
            body, default = master, np.zeros((1, 3))
        else:
            raise TypeError(f"RigidMaster needs a RigidBody or a Frame, got {type(master)}")
        self.body = body
        self.name = body.name
        ref = default if reference is None else np.asarray(reference, dtype=float).reshape(-1, 3)
        if ref.size == 0 or not np.all(np.isfinite(ref)):
            raise InputError(f"rigid master {self.name!r}: reference points must be finite")
        self.reference = ref
        self.ndofs = 6
        self.record_rest()

    def record_rest(self) -> None:
        self.p0 = self.body.position.copy()
        self.R0 = self.body.rotation.copy()

    def distances(self, X: np.ndarray) -> np.ndarray:
        ref = self.body.to_world(self.reference)
        return np.sqrt(((X[:, None, :] - ref[None]) ** 2).sum(-1)).min(axis=1)

    def transform(self) -> tuple[np.ndarray, np.ndarray]:
        """(Rd, t): x -> Rd x + t maps rest-pose world points to current world points."""
        Rd = self.body.rotation @ self.R0.T
        return Rd, self.body.position - Rd @ self.p0

    def velocity(self) -> np.ndarray:
        return self.body.twist


def embedding_weights(
    body: FemBody, points: np.ndarray, tol: float = 1e-10
) -> list[FemPointWeights]:
    """Shape-function weights of many points on a FEM body, located at once by
    :func:`~artifem.embedding.embedded_mesh.locate_points` with ``snap=True``: the containing
    element inside; outside, the closest point of the nearest element (weights in [0, 1],
    the distance kept in the result). Serial (in parallel: the points this rank owns)."""
    loc = locate_points(body, points, snap=True, tol=tol)
    dofs = body.V.dofmap.list[loc.cells].astype(np.int64)
    x_nodes = body.V.tabulate_dof_coordinates()
    return [
        FemPointWeights(d, w, w @ x_nodes[d], float(loc.distance[i]), int(c))
        for i, c, d, w in zip(loc.indices, loc.cells, dofs, loc.weights)
    ]


class FemMaster:
    """A full FEM master: f = sum_j N_j(X_v) u_j (embedding weights, snapped outside)."""

    kind = "fem"

    @property
    def scene_body(self):
        """The body of the scene its forces act on: the FEM body."""
        return self.body

    def __init__(self, body: FemBody):
        if body.mesh.comm.size != 1:
            raise NotImplementedError("skin meshes over FEM bodies run in serial only for now")
        self.body = body
        self.name = body.name
        self.ndofs = 3 * body.V.dofmap.index_map.size_local

    def embed(self, X: np.ndarray) -> None:
        """Embedding weights of the skin's rest vertices (called by SkinMesh)."""
        self.embedding = embedding_weights(self.body, X)
        self.distance = np.array([e.distance for e in self.embedding])
        n = len(self.embedding)
        rows = np.repeat(np.arange(n), [e.dofs.size for e in self.embedding])
        cols = np.concatenate([e.dofs for e in self.embedding])
        vals = np.concatenate([e.weights for e in self.embedding])
        self.N = sparse.csr_matrix((vals, (rows, cols)), shape=(n, self.ndofs // 3))

    def distances(self, X: np.ndarray) -> np.ndarray:
        return self.distance

    def nodal_displacement(self) -> np.ndarray:
        return self.body.u.x.array[: self.ndofs].reshape(-1, 3)

    def displacement(self) -> np.ndarray:
        """sum_j N_j u_j at every vertex (n, 3)."""
        return self.N @ self.nodal_displacement()

    def velocity(self) -> np.ndarray:
        return self.body.v.x.array[: self.ndofs].copy()

    def node_jacobian(self) -> sparse.csr_matrix:
        """d(vertex displacement)/d(nodal dofs), (3n, ndofs): N kron I3."""
        return sparse.kron(self.N, sparse.identity(3), format="csr")


class ReducedMaster(FemMaster):
    """A reduced FEM master: f = sum_j N_j (u_bar_j + U_j q); dofs qdot."""

    kind = "reduced"

    @property
    def scene_body(self):
        """The body of the scene its forces act on: the reduced body (not its full body)."""
        return self.reduced

    def __init__(self, reduced: ReducedFemBody):
        self.reduced = reduced
        self.body = reduced.full
        self.name = reduced.name
        self.ndofs = reduced.r
        self._nodal = 3 * self.body.V.dofmap.index_map.size_local

    def embed(self, X: np.ndarray) -> None:
        ndofs, self.ndofs = self.ndofs, self._nodal
        try:
            super().embed(X)
        finally:
            self.ndofs = ndofs
        self.NU = sparse.kron(self.N, sparse.identity(3), format="csr") @ self.reduced.U  # (3n, r)
        self.N_bar = self.N @ self.reduced.u_bar.reshape(-1, 3)

    def nodal_displacement(self) -> np.ndarray:
        return self.reduced.nodal_displacement().reshape(-1, 3)

    def displacement(self) -> np.ndarray:
        return self.N_bar + (self.NU @ self.reduced.q).reshape(-1, 3)

    def velocity(self) -> np.ndarray:
        return self.reduced.qdot.copy()

    def node_jacobian(self) -> np.ndarray:
        return self.NU


def _as_master(m):
    if isinstance(m, (RigidMaster, FemMaster)):
        return m
    if isinstance(m, (RigidBody, Frame)):
        return RigidMaster(m)
    if isinstance(m, ReducedFemBody):
        return ReducedMaster(m)
    if isinstance(m, FemBody):
        return FemMaster(m)
    raise TypeError(
        f"a skin master must be a RigidBody, Frame, FemBody or ReducedFemBody "
        f"(or a RigidMaster / FemMaster / ReducedMaster), got {type(m)}"
    )


def skin_weights(
    distances: np.ndarray,
    *,
    weighting: str = "inverse_square",
    sigma: float | None = None,
    max_masters: int | None = None,
    zero_distance: float = 1e-12,
) -> np.ndarray:
    """Normalized weights (n, M) from vertex-to-master distances (n, M) (module docstring)."""
    d = np.asarray(distances, dtype=float)
    if d.ndim != 2 or d.shape[1] == 0 or np.any(d < 0) or not np.all(np.isfinite(d)):
        raise InputError("distances must be a finite non-negative (n, M >= 1) array")
    if weighting not in WEIGHTINGS:
        raise InputError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")

    def inverse_square(d):
        zero = d <= zero_distance
        with np.errstate(divide="ignore"):
            w = np.where(zero, 0.0, 1.0 / np.maximum(d, zero_distance) ** 2)
        hit = zero.any(axis=1)
        w[hit] = zero[hit].astype(float)
        return w

    if weighting == "gaussian":
        if sigma is None or not (np.isfinite(sigma) and sigma > 0):
            raise InputError(f"gaussian weighting needs sigma > 0, got {sigma!r}")
        w = np.exp(-0.5 * (d / sigma) ** 2)
        dead = w.sum(axis=1) == 0.0
        if dead.any():
            w[dead] = inverse_square(d[dead])
    else:
        w = inverse_square(d)
    if max_masters is not None:
        k = int(max_masters)
        if k < 1:
            raise InputError(f"max_masters must be >= 1, got {max_masters!r}")
        if k < w.shape[1]:
            drop = np.argsort(-w, axis=1, kind="stable")[:, k:]
            np.put_along_axis(w, drop, 0.0, axis=1)
    return w / w.sum(axis=1, keepdims=True)


# ---- the skin ----------------------------------------------------------------------------


class SkinMesh:
    """A skin over several masters (see the module docstring).

    Args:
        vertices: rest positions (n, 3), world coordinates at the masters' rest
            state (the current state when the skin is built).
        faces: optional triangles (m, 3) (for pressures and output).
        masters: RigidBody / Frame / FemBody / ReducedFemBody objects or their
            RigidMaster / FemMaster / ReducedMaster wrappers.
        weighting, sigma, max_masters, zero_distance: see :func:`skin_weights`.
        weights: optional (n, M) weights overriding the distance weighting
            (rows renormalized to sum 1).
        blending: ``"linear"`` or ``"dual_quaternion"`` for the rigid masters.
    """

    def __init__(
        self,
        vertices,
        faces=None,
        masters=(),
        *,
        weighting: str = "inverse_square",
        sigma: float | None = None,
        max_masters: int | None = None,
        weights=None,
        blending: str = "linear",
        zero_distance: float = 1e-12,
        name: str = "skin",
    ):
        self.name = name
        X = np.asarray(vertices, dtype=float)
        if X.ndim != 2 or X.shape[1] != 3 or X.shape[0] == 0 or not np.all(np.isfinite(X)):
            raise InputError(f"skin {name!r}: vertices must be a finite (n >= 1, 3) array")
        self.rest = X.copy()
        self.n = X.shape[0]
        if faces is not None:
            faces = np.asarray(faces)
            if (
                faces.ndim != 2
                or faces.shape[1] != 3
                or not np.issubdtype(faces.dtype, np.integer)
                or faces.min() < 0
                or faces.max() >= self.n
            ):
                raise InputError(
                    f"skin {name!r}: faces must be (m, 3) vertex indices in [0, {self.n})"
                )
        self.faces = faces
        if blending not in BLENDINGS:
            raise InputError(
                f"skin {name!r}: blending must be one of {BLENDINGS}, got {blending!r}"
            )
        self.blending = blending
        self.masters = [_as_master(m) for m in masters]
        if not self.masters:
            raise InputError(f"skin {name!r}: needs at least one master")
        for m in self.masters:
            if isinstance(m, FemMaster):
                m.embed(X)
        offsets = np.cumsum([0] + [m.ndofs for m in self.masters])
        self.slices = [slice(int(a), int(b)) for a, b in zip(offsets[:-1], offsets[1:])]
        self.ndofs = int(offsets[-1])
        if weights is None:
            D = np.stack([m.distances(X) for m in self.masters], axis=1)
            self.weights = skin_weights(
                D,
                weighting=weighting,
                sigma=sigma,
                max_masters=max_masters,
                zero_distance=zero_distance,
            )
        else:
            W = np.asarray(weights, dtype=float)
            if (
                W.shape != (self.n, len(self.masters))
                or np.any(W < 0)
                or not np.all(np.isfinite(W))
                or np.any(W.sum(axis=1) <= 0)
            ):
                raise InputError(
                    f"skin {name!r}: weights must be finite, >= 0, of shape "
                    f"({self.n}, {len(self.masters)}), each row with a "
                    f"positive sum"
                )
            self.weights = W / W.sum(axis=1, keepdims=True)
        self.rigid = [i for i, m in enumerate(self.masters) if m.kind == "rigid"]
        self.deformable = [i for i, m in enumerate(self.masters) if m.kind != "rigid"]

    # ---- positions and G ---------------------------------------------------------------

    def _rigid_part(self, jacobian: bool):
        """(displacement (n, 3), [3 x 6 blocks per rigid master (n, 3, 6)]) of the rigid
        masters under the chosen blending."""
        X = self.rest
        disp = np.zeros((self.n, 3))
        blocks = []
        if not self.rigid:
            return disp, blocks
        W = self.weights[:, self.rigid]  # (n, K)
        maps = [self.masters[i].transform() for i in self.rigid]
        if self.blending == "linear":
            for k, (Rd, t) in enumerate(maps):
                Y = X @ Rd.T + t
                disp += W[:, k, None] * (Y - X)
                if jacobian:
                    r = Y - self.masters[self.rigid[k]].body.position
                    B = np.zeros((self.n, 3, 6))
                    B[:, :, :3] = np.eye(3)
                    B[:, :, 3:] = np.einsum("ijk,nk->nij", _LEVI_CIVITA, r)  # -[r]x
                    blocks.append(W[:, k, None, None] * B)
            return disp, blocks
        # dual quaternions
        WR = W.sum(axis=1)  # (n,)
        on = WR > 0
        A = np.zeros_like(W)
        A[on] = W[on] / WR[on, None]
        Q = np.array([_quat_of_rotation(Rd) for Rd, _ in maps])  # (K, 4)
        T = np.array([_pure(t) for _, t in maps])  # (K, 4)
        Dq = 0.5 * _qmul(T, Q)  # (K, 4)
        pivot = np.argmax(A, axis=1)
        S = np.where(Q[pivot] @ Q.T >= 0.0, 1.0, -1.0)  # (n, K)
        AS = A * S
        b0, be = AS @ Q, AS @ Dq  # (n, 4)
        Xq = _pure(X)
        b0c = b0 @ _CONJ
        N = _qmul(_qmul(b0, Xq), b0c) + 2.0 * _qmul(be, b0c)
        s = (b0 * b0).sum(axis=1)
        s_safe = np.where(on, s, 1.0)
        Y = N[:, 1:] / s_safe[:, None]
        disp = np.where(on[:, None], WR[:, None] * (Y - X), 0.0)
        if not jacobian:
            return disp, blocks
        # dN = M0 db0 + Me dbe (n, 4, 4 each)
        M0 = (
            _quat_left(_qmul(b0, Xq)) @ _CONJ
            + _quat_right(_qmul(Xq, b0c))
            + 2.0 * _quat_left(be) @ _CONJ
        )
        Me = 2.0 * _quat_right(b0c)
        # dx = P dN / s - vec(N) 2 b0^T db0 / s^2 = (P M0 / s - 2 Y b0^T / s) db0 + P Me / s dbe
        P = _E.T
        J0 = (P @ M0) / s_safe[:, None, None] - 2.0 * np.einsum("ni,nj->nij", Y, b0) / s_safe[
            :, None, None
        ]
        Je = (P @ Me) / s_safe[:, None, None]  # (n, 3, 4)
        for k, i in enumerate(self.rigid):
            body = self.masters[i].body
            t = maps[k][1]
            RqE = _quat_right(Q[k]) @ _E  # (4, 3)
            db0_dw = 0.5 * RqE
            dbe_dv = 0.5 * RqE
            dbe_dw = 0.5 * RqE @ (-skew(t - body.position)) + 0.25 * _quat_left(T[k]) @ RqE
            B = np.zeros((self.n, 3, 6))
            B[:, :, :3] = Je @ dbe_dv
            B[:, :, 3:] = J0 @ db0_dw + Je @ dbe_dw
            blocks.append((WR * AS[:, k])[:, None, None] * B)
        return disp, blocks

    def positions(self) -> np.ndarray:
        """Current vertex positions q_v (n, 3), eq. 8."""
        disp, _ = self._rigid_part(jacobian=False)
        for i in self.deformable:
            disp += self.weights[:, i, None] * self.masters[i].displacement()
        return self.rest + disp

    def jacobian(self) -> sparse.csr_matrix:
        """G (3n x ndofs) at the current state: u_v = G u_m, u_m = master_velocities()."""
        _, blocks = self._rigid_part(jacobian=True)
        parts = []
        for k, i in enumerate(self.rigid):
            B = blocks[k]
            rows = np.repeat(np.arange(3 * self.n), 6)
            cols = self.slices[i].start + np.tile(np.arange(6), 3 * self.n)
            parts.append(
                sparse.csr_matrix((B.reshape(-1), (rows, cols)), shape=(3 * self.n, self.ndofs))
            )
        for i in self.deformable:
            m = self.masters[i]
            Gi = sparse.diags(np.repeat(self.weights[:, i], 3)) @ sparse.csr_matrix(
                m.node_jacobian()
            )
            Gi = sparse.csr_matrix(Gi)
            parts.append(
                sparse.hstack(
                    [
                        sparse.csr_matrix((3 * self.n, self.slices[i].start)),
                        Gi,
                        sparse.csr_matrix((3 * self.n, self.ndofs - self.slices[i].stop)),
                    ],
                    format="csr",
                )
            )
        G = parts[0]
        for p in parts[1:]:
            G = G + p
        return sparse.csr_matrix(G)

    def master_velocities(self) -> np.ndarray:
        """u_m: the masters' velocity dofs stacked (rigid twists, FEM nodal velocities, qdot)."""
        return np.concatenate([m.velocity() for m in self.masters])

    def velocities(self) -> np.ndarray:
        """u_v = G u_m (n, 3)."""
        return (self.jacobian() @ self.master_velocities()).reshape(-1, 3)

    # ---- loads -------------------------------------------------------------------------

    def master_forces(self, forces, G: sparse.csr_matrix | None = None) -> list[np.ndarray]:
        """G^T f split per master: a wrench [f; r x f] (about the COM, world) per rigid master,
        nodal forces (3 n_owned, block-interleaved) per FEM master, generalized forces (r)
        per reduced master. Without ``G`` each part is formed directly, without assembling G:
        sum_v B_vk^T f_v (the rigid master's 3 x 6 blocks), N^T (w_i f) on an FEM master's
        nodes, (N U)^T (w_i f) on a reduced master's coordinates."""
        f = np.asarray(forces, dtype=float).reshape(self.n, 3)
        if G is not None:
            fm = G.T @ f.ravel()
            return [fm[s] for s in self.slices]
        out: list = [None] * len(self.masters)
        if self.rigid:
            _, blocks = self._rigid_part(jacobian=True)
            for k, i in enumerate(self.rigid):
                out[i] = np.einsum("nij,ni->j", blocks[k], f)
        for i in self.deformable:
            m, wf = self.masters[i], self.weights[:, i, None] * f
            out[i] = m.NU.T @ wf.ravel() if isinstance(m, ReducedMaster) else (m.N.T @ wf).ravel()
        return out

    def loads(self, forces) -> list[tuple[object, np.ndarray]]:
        """Vertex forces (n, 3) as a load element's ``master_loads``: [(scene body, its part
        of G^T f)], a rigid master's wrench, an FEM master's nodal forces (the length of
        ``body.v.x.array``), a reduced master's generalized force."""
        out = []
        for m, f in zip(self.masters, self.master_forces(forces)):
            if m.kind == "rigid":
                out.append((m.body, f))
            elif m.kind == "reduced":
                out.append((m.reduced, f))
            else:
                full = np.zeros(m.body.v.x.array.size)
                full[: f.size] = f
                out.append((m.body, full))
        return out

    def load_jacobians(
        self, K_v: sparse.spmatrix
    ) -> list[tuple[object, object, sparse.csr_matrix]]:
        """The derivative df_v/dx_v (3n x 3n) of vertex forces as a load element's
        ``master_load_jacobians``: [(body_i, body_j, block of G^T (df_v/dx_v) G)]. The change
        of G itself as rigid masters turn (their levers, at fixed f_v) is left out: exact for
        FEM and reduced masters."""
        G = self.jacobian()
        K = (G.T @ K_v @ G).tocsr()
        bodies = [m.reduced if m.kind == "reduced" else m.body for m in self.masters]
        return [
            (bi, bj, K[si, sj])
            for bi, si in zip(bodies, self.slices)
            for bj, sj in zip(bodies, self.slices)
        ]

    def face_area_vectors(self, x: np.ndarray | None = None) -> np.ndarray:
        """area * n per face, (x_1 - x_0) x (x_2 - x_0) / 2, at the current positions."""
        if self.faces is None:
            raise InputError(f"skin {self.name!r} has no faces")
        x = self.positions() if x is None else x
        a, b, c = (x[self.faces[:, k]] for k in range(3))
        return 0.5 * cross(b - a, c - a)

    def pressure_stiffness(self, pressure: float) -> sparse.csr_matrix:
        """d f_v / d x_v (3n x 3n) of :meth:`pressure_forces` at the current positions: the
        follower pressure turns and stretches with the faces. With a = (e1 x e2) / 2,
        e1 = x1 - x0, e2 = x2 - x0: da/dx1 = -[e2]x / 2, da/dx2 = [e1]x / 2 and
        da/dx0 = -(da/dx1 + da/dx2); each face adds p/3 da/dx_k to its three vertices."""
        x = self.positions()
        e1 = x[self.faces[:, 1]] - x[self.faces[:, 0]]
        e2 = x[self.faces[:, 2]] - x[self.faces[:, 0]]
        d1, d2 = -0.5 * skews(e2), 0.5 * skews(e1)
        per_vertex = [-(d1 + d2), d1, d2]  # da/dx_k, (faces, 3, 3)
        rows, cols, vals = [], [], []
        r3 = np.arange(3)
        for v in range(3):  # the vertex that receives the force
            for k in range(3):  # the vertex that moves
                block = float(pressure) / 3.0 * per_vertex[k]
                rows.append(
                    (3 * self.faces[:, v, None, None] + r3[None, :, None]).repeat(3, axis=2).ravel()
                )
                cols.append(
                    (3 * self.faces[:, k, None, None] + r3[None, None, :]).repeat(3, axis=1).ravel()
                )
                vals.append(block.ravel())
        return sparse.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(3 * self.n, 3 * self.n),
        )

    def pressure_forces(self, pressure: float) -> np.ndarray:
        """Vertex forces (n, 3) of a uniform pressure: p * area * n per face, a third per vertex."""
        F = float(pressure) * self.face_area_vectors() / 3.0
        out = np.zeros((self.n, 3))
        for k in range(3):
            np.add.at(out, self.faces[:, k], F)
        return out


class SkinPressure:
    """A uniform pressure p(t) on a skin's faces as a Scene load element.

    Vertex forces f_v = sum over the vertex's faces of p A_f n_f / 3
    (:meth:`SkinMesh.pressure_forces`) go to the masters by virtual work,
    f_m = G^T f_v (:meth:`SkinMesh.master_forces`), so that f_v . u_v = f_m . u_m for
    every master velocity. ``master_loads(t)`` yields (body, array) per master:
    the rigid body and its wrench [f; tau about the COM] (world), the FEM body and
    its nodal forces (blocked, the length of ``body.v.x.array``), or the reduced body
    and its generalized force (r). The load follows the skin (a follower load) and
    enters the step explicitly (b += h f_m).

    Args:
        skin: a SkinMesh with faces, outward oriented (p > 0 pushes the faces along
            their normals).
        pressure: p in Pa, a float or a callable t -> p.
    """

    def __init__(self, skin: SkinMesh, pressure, *, name: str = "pressure"):
        if not isinstance(skin, SkinMesh):
            raise TypeError(f"SkinPressure needs a SkinMesh, got {type(skin).__name__}")
        if skin.faces is None:
            raise InputError(f"SkinPressure {name!r}: skin {skin.name!r} has no faces")
        if not callable(pressure):
            value = float(pressure)
            if not np.isfinite(value):
                raise InputError(
                    f"SkinPressure {name!r}: pressure must be finite, got {pressure!r}"
                )
        self.skin = skin
        self.pressure = pressure
        self.name = name

    @property
    def bodies(self) -> tuple:
        """The scene bodies its forces act on: the skin's masters."""
        return tuple(m.scene_body for m in self.skin.masters)

    def __repr__(self) -> str:
        return f"SkinPressure({self.name!r}, skin={self.skin.name!r})"

    def pressure_at(self, t: float) -> float:
        p = float(self.pressure(t)) if callable(self.pressure) else float(self.pressure)
        if not np.isfinite(p):
            raise InputError(f"SkinPressure {self.name!r}: pressure({t:g}) = {p}")
        return p

    def vertex_forces(self, t: float) -> np.ndarray:
        """f_v (n, 3) at the skin's current positions."""
        return self.skin.pressure_forces(self.pressure_at(t))

    def master_load_jacobians(self, t: float) -> list[tuple[object, object, sparse.csr_matrix]]:
        """[(body_i, body_j, dF_i/dx_j)]: the derivative of the masters' loads G^T f_v by the
        masters' coordinates, G^T (df_v/dx_v) G (the follower pressure's stiffness,
        :meth:`SkinMesh.pressure_stiffness`). The change of G itself as rigid masters turn
        (their levers, at fixed f_v) is left out: exact for FEM and reduced masters."""
        return self.skin.load_jacobians(self.skin.pressure_stiffness(self.pressure_at(t)))

    def master_loads(self, t: float) -> list[tuple[object, np.ndarray]]:
        """[(body, G^T f_v restricted to the body's dofs)] for every master of the skin."""
        return self.skin.loads(self.vertex_forces(t))
