"""Registration forces: a model surface pulled toward a target surface by closest points.

A :class:`~artifem.multibody.skin.SkinMesh` with faces carries the model surface (a bone
mesh embedded in a voxel FEM grid, on a deformable or rigid body, or over several of
them); a :class:`~artifem.registration.rigid.TriangleSurface` is the target. With x_i the
model's vertices, c_i their closest points on the target, y_j the target's vertices and
p_j = sum_k b_jk x_k their closest points on the model (triangle of vertices k,
barycentric coordinates b_jk), the energy

    E = w/2 sum_i |x_i - c_i|^2 + w/2 sum_j |y_j - p_j|^2

pulls both ways: the model to the target, and the target's parts the model has no
vertex near (thin features, a partial target) to the model. A pair whose closest point
lies on the border of an open surface (an edge of one triangle) is dropped (Turk and
Levoy 1994): the model's parts a partial target does not cover find their closest
points on the target's border and would otherwise be pulled onto it. Optional landmarks add
w_l/2 sum_l |x_v(l) - y_l|^2 (a model vertex to a given target point each). Its forces
on the model's vertices are exact (-dE/dx, the closest points' own motion drops out:
they minimize the distances), f_i = w (c_i - x_i) and f_k = sum_j w b_jk (y_j - p_j),
and reach the masters by virtual work, G^T f (a load element of the scene). Their
stiffness df/dx is exact while each closest point stays on its feature: the first
term's -w P_i with P_i the
projector off the feature c_i lies on (n n^T on a triangle's interior, I - e e^T on an
edge of direction e, I at a vertex); the second's from the envelope theorem on the
distance to the model's feature (:func:`_value_hessian`: the triangle's turning and the
closest point's sliding included).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from artifem.errors import InputError
from artifem.multibody.skin import SkinMesh
from artifem.registration.rigid import TriangleSurface

__all__ = ["RegistrationForces"]

#: barycentric coordinates at or below this are zero: the closest point is on an edge or
#: at a vertex of its triangle
ON_FEATURE = 1e-10


def _projectors(
    surface: TriangleSurface, triangles: np.ndarray, barycentric: np.ndarray
) -> np.ndarray:
    """(k, 3, 3) projectors off the feature each point (``barycentric`` coordinates in its
    ``triangles``) lies on: n n^T inside, I - e e^T on an edge, I at a vertex."""
    corners = surface.vertices[surface.triangles[triangles]]
    zero = barycentric <= ON_FEATURE
    count = zero.sum(axis=1)
    P = np.broadcast_to(np.eye(3), (len(triangles), 3, 3)).copy()  # vertices
    inside = count == 0
    if inside.any():
        n = np.cross(
            corners[inside, 1] - corners[inside, 0], corners[inside, 2] - corners[inside, 0]
        )
        n /= np.linalg.norm(n, axis=1)[:, None]
        P[inside] = n[:, :, None] * n[:, None, :]
    edge = np.flatnonzero(count == 1)
    if edge.size:
        ends = np.argsort(zero[edge], axis=1, kind="stable")[:, :2]  # the two nonzero
        e = corners[edge, ends[:, 1]] - corners[edge, ends[:, 0]]
        e /= np.linalg.norm(e, axis=1)[:, None]
        P[edge] = np.eye(3) - e[:, :, None] * e[:, None, :]
    return P


def _value_hessian(xs: np.ndarray, b: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(q, m, m, 3, 3): the exact Hessian, by the vertices' positions, of the squared
    distance 1/2 |y - p|^2 from a point y to its closest point p = sum_a b_a x_a on a
    feature of m vertices xs (q, m, 3) (1: a vertex, 2: an edge, 3: a triangle's
    interior), r = y - p. It is the value of min_s L(x, s), L = 1/2 |y - x_0 - J s|^2
    with J = [x_a - x_0] (m - 1 columns, s the barycentric coordinates b_1..): by the
    envelope theorem, H = L_xx - L_xs (J^T J)^-1 L_sx with L_xx = (b b^T) (x) I and
    L_sx[c, a] = -(delta_{a, c+1} - delta_{a, 0}) r^T + b_a J_c^T."""
    q, m = b.shape
    H = b[:, :, None, None, None] * b[:, None, :, None, None] * np.eye(3)
    if m == 1:
        return H
    J = xs[:, 1:] - xs[:, :1]  # (q, m - 1, 3): columns
    C = np.zeros((m - 1, m))
    C[np.arange(m - 1), np.arange(1, m)] = 1.0
    C[:, 0] = -1.0
    Lsx = (
        -C[None, :, :, None] * r[:, None, None, :] + b[:, None, :, None] * J[:, :, None, :]
    )  # (q, m - 1, m, 3)
    M = np.linalg.inv(np.einsum("qca,qda->qcd", J, J))
    return H - np.einsum("qcix,qcd,qdjy->qijxy", Lsx, M, Lsx)


@dataclass(frozen=True)
class _Features:
    """The closest-point features at one configuration: model-to-target, each model
    vertex's closest point c_i, the projector P_i off its feature and whether the pair is
    kept; target-to-model, for m = 1, 2, 3 (the closest point at a model vertex, on an
    edge, inside a triangle) the target vertices y (q, 3) and the feature's model
    vertices (q, m)."""

    c: np.ndarray
    P: np.ndarray
    kept: np.ndarray
    pieces: tuple = ()


def _features(
    x: np.ndarray, faces: np.ndarray, target: TriangleSurface, both_ways: bool = True
) -> _Features:
    """The :class:`_Features` of the model surface (vertices ``x``, triangles ``faces``)
    toward ``target``, pairs on a border dropped (module docstring)."""
    _, c, tri = target.closest_triangles(x)
    b = target.barycentric(c, tri)
    kept = ~target.on_border(tri, b, ON_FEATURE)
    P = _projectors(target, tri, b) * kept[:, None, None]
    pieces = []
    if both_ways:
        model = TriangleSurface(x, faces)
        _, p, tj = model.closest_triangles(target.vertices)
        b = model.barycentric(p, tj)
        pick = ~model.on_border(tj, b, ON_FEATURE)
        y, b, corners = target.vertices[pick], b[pick], model.triangles[tj[pick]]
        on = b > ON_FEATURE
        for m in (1, 2, 3):
            rows = np.flatnonzero(on.sum(axis=1) == m)
            order = np.argsort(~on[rows], axis=1, kind="stable")[:, :m]
            pieces.append((y[rows], np.take_along_axis(corners[rows], order, axis=1)))
    return _Features(c, P, kept, tuple(pieces))


def _on_hull(y: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """(q, m) barycentric coordinates of the projections of ``y`` (q, 3) onto the affine
    hulls of the features xs (q, m, 3): b = [1 - sum s, s], s = (J^T J)^-1 J^T (y - x_0)."""
    if xs.shape[1] == 1:
        return np.ones((len(y), 1))
    J = xs[:, 1:] - xs[:, :1]
    s = np.linalg.solve(
        np.einsum("qca,qda->qcd", J, J), np.einsum("qca,qa->qc", J, y - xs[:, 0])[:, :, None]
    )[:, :, 0]
    return np.column_stack([1.0 - s.sum(axis=1), s])


def _evaluate(x: np.ndarray, features: _Features) -> tuple[float, np.ndarray, sparse.csr_matrix]:
    """(E / w, f / w (n, 3), df/dx / w (3n x 3n)) of the module docstring at ``x`` on the
    given features: model-to-target 1/2 (x_i - c_i)^T P_i (x_i - c_i) (the distance to
    the plane, line or point of c_i's feature: equal to 1/2 |x_i - c_i|^2 where the
    features were found), target-to-model 1/2 |y_j - p_j|^2 with p_j the projection of
    y_j onto its feature's affine hull (:func:`_value_hessian`)."""
    n = len(x)
    g = x - features.c
    f = -np.einsum("nij,nj->ni", features.P, g)
    energy = -0.5 * float(np.sum(f * g))
    rows = [np.repeat(3 * np.arange(n)[:, None] + np.arange(3), 3, axis=1)]
    cols = [np.tile(3 * np.arange(n)[:, None] + np.arange(3), (1, 3))]
    vals = [-features.P.reshape(n, 9)]
    for y, verts in features.pieces:
        if not len(y):
            continue
        xs = x[verts]
        b = _on_hull(y, xs)
        r = y - np.einsum("qm,qmx->qx", b, xs)
        energy += 0.5 * float(np.sum(r * r))
        np.add.at(f, verts.ravel(), (b[:, :, None] * r[:, None, :]).reshape(-1, 3))
        H = _value_hessian(xs, b, r)
        dofs = 3 * verts[:, :, None] + np.arange(3)  # (q, m, 3)
        rows.append(np.broadcast_to(dofs[:, :, None, :, None], H.shape).ravel())
        cols.append(np.broadcast_to(dofs[:, None, :, None, :], H.shape).ravel())
        vals.append(-H.ravel())
    K = sparse.csr_matrix(
        (
            np.concatenate([v.ravel() for v in vals]),
            (np.concatenate([r.ravel() for r in rows]), np.concatenate([q.ravel() for q in cols])),
        ),
        shape=(3 * n, 3 * n),
    )
    return energy, f, K


class _Weight:
    """A weight attribute of :class:`RegistrationForces`: finite and >= 0, checked when set
    (a schedule sets it between solves)."""

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        return self if obj is None else obj.__dict__[self.name]

    def __set__(self, obj, value) -> None:
        if not (np.isfinite(value) and value >= 0):
            raise InputError(
                f"RegistrationForces {obj.name!r}: {self.name} must be finite "
                f"and >= 0, got {value!r}"
            )
        obj.__dict__[self.name] = float(value)


class RegistrationForces:
    """The registration energy of the module docstring on ``skin`` toward ``target``, as a
    scene load element (``master_loads``, ``master_load_jacobians``, ``potential_energy``).

    Args:
        skin: the model surface: a SkinMesh with faces.
        target: the target surface (:class:`TriangleSurface`), world coordinates.
        weight: w (N/m^2: force per metre of distance, per vertex); a schedule raises it
            between solves (the attribute may be set).
        both_ways: with the target-to-model term (else the model-to-target term alone).
        landmarks: optional pairs (model vertex indices (L,), target points (L, 3)), each
            adding w_l/2 |x_v - y_l|^2 (force w_l (y_l - x_v), stiffness -w_l I).
        landmark_weight: w_l (settable like ``weight``; default ``weight``).
    """

    weight = _Weight()
    landmark_weight = _Weight()

    def __init__(
        self,
        skin: SkinMesh,
        target: TriangleSurface,
        weight: float,
        *,
        both_ways: bool = True,
        landmarks=None,
        landmark_weight: float | None = None,
        name: str = "registration",
    ):
        if not isinstance(skin, SkinMesh) or skin.faces is None:
            raise InputError(
                f"RegistrationForces {name!r}: the model surface must be a SkinMesh with faces"
            )
        if not isinstance(target, TriangleSurface):
            raise InputError(
                f"RegistrationForces {name!r}: the target must be a "
                f"TriangleSurface, got {type(target).__name__}"
            )
        self.skin, self.target, self.name = skin, target, name
        self.weight = weight
        self.both_ways = both_ways
        self._memo = self._found = self._held = None
        self.landmarks = None
        if landmarks is not None:
            vertices, points = landmarks
            vertices = np.asarray(vertices, dtype=np.int64).ravel()
            points = np.asarray(points, dtype=float).reshape(-1, 3)
            if (
                len(vertices) != len(points)
                or not len(vertices)
                or vertices.min() < 0
                or vertices.max() >= skin.n
                or not np.all(np.isfinite(points))
            ):
                raise InputError(
                    f"RegistrationForces {name!r}: landmarks must pair model "
                    f"vertex indices in [0, {skin.n}) with as many finite "
                    f"target points"
                )
            self.landmarks = (vertices, points)
        self.landmark_weight = weight if landmark_weight is None else landmark_weight

    @property
    def bodies(self) -> tuple:
        """The scene bodies its forces act on: the skin's masters."""
        return tuple(m.scene_body for m in self.skin.masters)

    def __repr__(self) -> str:
        return f"RegistrationForces({self.name!r}, skin={self.skin.name!r})"

    def features(self) -> _Features:
        """The closest-point features: the held ones (:meth:`hold`), else those at the
        skin's current positions (found once per configuration)."""
        if self._held is not None:
            return self._held
        x = self.skin.positions()
        if self._found is None or not np.array_equal(self._found[0], x):
            self._found = (x.copy(), _features(x, self.skin.faces, self.target, self.both_ways))
        return self._found[1]

    def hold(self, hold: bool) -> None:
        """Hold the features found at the current positions (True) or follow them again
        (False). Held, the energy is smooth (:func:`_evaluate`): a static solve converges
        quadratically where the closest points would switch features at every iteration,
        and the loop finds the features again between solves (ICP's alternation)."""
        self._held = None
        self._held = self.features() if hold else None

    def terms(self) -> tuple[float, np.ndarray, sparse.csr_matrix]:
        """(E / w, f / w (n, 3), df/dx / w (3n x 3n)) at the skin's current positions on
        :meth:`features` (:func:`_evaluate`; kept while the positions stay)."""
        x = self.skin.positions()
        features = self.features()
        if (
            self._memo is None
            or self._memo[1] is not features
            or not np.array_equal(self._memo[0], x)
        ):
            self._memo = (x.copy(), features, _evaluate(x, features))
        return self._memo[2]

    def distances(self) -> np.ndarray:
        """|x_i - c_i| of the model vertices whose pair to the target is kept, at the
        current positions (m)."""
        d, _, kept = self.target.closest_kept(self.skin.positions())
        return d[kept]

    def _landmark_gaps(self) -> np.ndarray | None:
        """y_l - x_v (L, 3) of the landmarks, or None."""
        if self.landmarks is None:
            return None
        vertices, points = self.landmarks
        return points - self.skin.positions()[vertices]

    def potential_energy(self, t: float) -> float:
        gaps = self._landmark_gaps()
        extra = 0.0 if gaps is None else 0.5 * self.landmark_weight * float(np.sum(gaps**2))
        return self.weight * self.terms()[0] + extra

    def vertex_forces(self) -> np.ndarray:
        """f (n, 3) on the model's vertices."""
        f = self.weight * self.terms()[1]
        gaps = self._landmark_gaps()
        if gaps is not None:
            np.add.at(f, self.landmarks[0], self.landmark_weight * gaps)
        return f

    def vertex_stiffness(self) -> sparse.csr_matrix:
        """df/dx (3n x 3n) on the model's vertices."""
        K = self.weight * self.terms()[2]
        if self.landmarks is not None:
            dofs = (3 * self.landmarks[0][:, None] + np.arange(3)).ravel()
            n = 3 * self.skin.n
            K = K - self.landmark_weight * sparse.csr_matrix(
                (np.ones(dofs.size), (dofs, dofs)), shape=(n, n)
            )
        return K

    def master_loads(self, t: float) -> list[tuple[object, np.ndarray]]:
        return self.skin.loads(self.vertex_forces())

    def master_load_jacobians(self, t: float) -> list[tuple[object, object, sparse.csr_matrix]]:
        return self.skin.load_jacobians(self.vertex_stiffness())
