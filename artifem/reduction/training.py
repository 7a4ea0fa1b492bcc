"""Training a reduced model from full runs (Lloyd et al. 2019, section 2.2).

The pipeline, each stage an artifact cached on disk by a hash of its inputs:

1. snapshots: the full model driven by training excitations (the paper: each
   muscle alone), recording nodal displacements u_s and the excitations a_s
   every few steps (:func:`record_snapshots`);
2. a basis: mass-weighted POD of the snapshots
   (:func:`~artifem.reduction.bases.pod_basis`);
3. trained integration points: the snapshots projected on the basis,
   q_s = U^T M u_s, give the training matrix of the reduced internal force

       G[(s, :), p] = V_p D_p^T vec(P(F_p(q_s); a_s)),   b = G 1,

   one column per quadrature point of the full model
   (:func:`force_training_matrix`), fitted by greedy ECSW / NNLS
   (:func:`~artifem.reduction.cubature.trained_points`).

:class:`ArtifactCache` stores each stage as an ``.npz`` file written
atomically, so an interrupted training run resumes at the first stage (or
training run) that is not on disk.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.optimize import nnls
from tqdm import tqdm

from artifem.errors import InputError
from artifem.fem_body import FemBody
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from artifem.scene import Scene, simulate

__all__ = [
    "ArtifactCache",
    "Snapshots",
    "record_snapshots",
    "project",
    "force_training_matrix",
    "pressure_weights",
]

#: Bump when a change in the code changes what a cached artifact would hold.
CACHE_VERSION = 2


def _jsonable(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


class ArtifactCache:
    """npz artifacts in ``root``, named ``<kind>-<hash of the inputs>.npz``."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    @staticmethod
    def key(kind: str, **inputs) -> str:
        """A file-name-safe key: the kind and a hash of the JSON of the inputs."""
        text = json.dumps(_jsonable({"version": CACHE_VERSION, **inputs}), sort_keys=True)
        return f"{kind}-{hashlib.sha256(text.encode()).hexdigest()[:16]}"

    def path(self, key: str) -> Path:
        return self.root / f"{key}.npz"

    def load(self, key: str) -> dict[str, np.ndarray] | None:
        path = self.path(key)
        if not path.exists():
            return None
        with np.load(path) as data:
            return {name: data[name] for name in data.files}

    def save(self, key: str, arrays: dict[str, np.ndarray]) -> None:
        """Write atomically: a killed run never leaves a truncated artifact."""
        fd, tmp = tempfile.mkstemp(dir=self.root, suffix=".npz.tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **arrays)
            os.replace(tmp, self.path(key))
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def get(self, key: str, compute: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
        """The artifact ``key``, computed and saved if it is not on disk."""
        found = self.load(key)
        if found is None:
            found = {name: np.asarray(value) for name, value in compute().items()}
            self.save(key, found)
        return found


@dataclass
class Snapshots:
    """Displacements (S, ndofs) and muscle excitations (S, muscles) of training states, the
    pressures (S, n_p) of a body with the hard incompressibility (else None), and the pose
    coordinates g (S, 12 k) of the k rigid bodies that carry nodes of it
    (:mod:`artifem.reduction.rigid_lift`; None without any): one snapshot per row, the
    convention of every function in artifem.reduction."""

    displacements: np.ndarray
    excitations: np.ndarray
    pressures: np.ndarray | None = None
    poses: np.ndarray | None = None

    def __post_init__(self):
        u, a = np.asarray(self.displacements), np.asarray(self.excitations)
        if u.ndim != 2 or a.ndim != 2 or u.shape[0] != a.shape[0]:
            raise InputError(
                f"Snapshots: displacements (n_snapshots, dofs) and excitations "
                f"(n_snapshots, muscles) need one row per snapshot, got shapes "
                f"{u.shape} and {a.shape}"
            )
        if self.pressures is not None and (
            np.ndim(self.pressures) != 2 or np.shape(self.pressures)[0] != u.shape[0]
        ):
            raise InputError(
                f"Snapshots: pressures (n_snapshots, pressure dofs) need one row "
                f"per snapshot, got shape {np.shape(self.pressures)} for "
                f"{u.shape[0]} snapshots"
            )

    @staticmethod
    def concatenate(parts: list[Snapshots]) -> Snapshots:
        def joined(name):
            if any(getattr(p, name) is None for p in parts):
                return None
            return np.concatenate([getattr(p, name) for p in parts])

        return Snapshots(
            joined("displacements"), joined("excitations"), joined("pressures"), joined("poses")
        )

    def as_arrays(self) -> dict[str, np.ndarray]:
        arrays = {"displacements": self.displacements, "excitations": self.excitations}
        for name in ("pressures", "poses"):
            if getattr(self, name) is not None:
                arrays[name] = getattr(self, name)
        return arrays

    @staticmethod
    def from_arrays(arrays: dict[str, np.ndarray]) -> Snapshots:
        """The inverse of :meth:`as_arrays` (a cached artifact)."""
        return Snapshots(
            arrays["displacements"],
            arrays["excitations"],
            arrays.get("pressures"),
            arrays.get("poses"),
        )


def record_snapshots(
    scene: Scene,
    body: FemBody,
    *,
    duration: float,
    dt: float,
    every: int,
    label: str = "training",
    progress: bool = True,
    carriers=(),
) -> Snapshots:
    """Step ``scene`` for ``duration`` and keep (u, excitations) of ``body`` every ``every``
    steps, its pressures p when it has the hard incompressibility, and the pose coordinates
    g of each (RigidLift, rigid body) of ``carriers``."""
    steps = int(round(duration / dt))
    if steps < 1 or every < 1:
        raise InputError(
            f"record_snapshots: need duration >= dt and every >= 1, got "
            f"duration={duration}, dt={dt}, every={every}"
        )
    n = 3 * body.V.dofmap.index_map.size_local
    record = {
        "u": lambda s: body.u.x.array[:n].copy(),
        "a": lambda s: [float(m.excitation.value) for m in body.muscles.values()],
    }
    vc = body.volume_constraint
    if vc is not None:
        record["p"] = lambda s: vc.p.x.array[: vc.n_owned].copy()
    for k, (lift, bone) in enumerate(carriers):
        record[f"g{k}"] = lambda s, lift=lift, bone=bone: lift.coordinates(
            bone.position, bone.rotation
        )
    run = simulate(scene, duration, dt, progress=progress, label=label, record=record, leave=False)
    u, a = run.records["u"][every::every], run.records["a"][every::every]
    p = None if vc is None else run.records["p"][every::every]
    g = (
        np.hstack([run.records[f"g{k}"][every::every] for k in range(len(carriers))])
        if carriers
        else None
    )
    return Snapshots(u, a.reshape(len(u), len(body.muscles)), p, g)


def project(U: np.ndarray, mass, displacements: np.ndarray) -> np.ndarray:
    """Reduced coordinates q_s = U^T M u_s of displacement rows (S, ndofs) -> (S, r).

    ``mass`` is the lumped diagonal (M-orthonormal U makes this the M-orthogonal
    projection) or a callable x -> M x.
    """
    displacements = np.asarray(displacements)
    if displacements.ndim != 2 or displacements.shape[1] != U.shape[0]:
        raise InputError(
            f"project: displacements must be rows (n_snapshots, dofs = "
            f"{U.shape[0]}) for a basis of shape {U.shape}, got shape "
            f"{displacements.shape}"
        )
    if callable(mass):
        return np.array([U.T @ mass(u) for u in displacements])
    return displacements @ (np.asarray(mass)[:, None] * U)


def force_training_matrix(
    full: FemBody, U: np.ndarray, q: np.ndarray, excitations: np.ndarray, *, progress: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """(G, b) of ECSW: each quadrature point's reduced internal force at each training state.

    Rows are (snapshot, reduced coordinate), columns the points of
    ``quadrature_points(full)``; b = G 1 is the full quadrature. Muscle
    excitations are set per snapshot and restored afterwards. A state whose
    projection inverts an element somewhere (possible for a basis that does
    not contain the snapshot, e.g. linear modes under large strain) has no
    finite force and is left out with a warning.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    excitations = np.atleast_2d(np.asarray(excitations, dtype=float))
    muscles = list(full.muscles.values())
    if excitations.shape != (q.shape[0], len(muscles)):
        raise InputError(
            f"force_training_matrix: excitations must have shape "
            f"({q.shape[0]}, {len(muscles)}), got {excitations.shape}"
        )
    # the material's forces only: a hard body's pressures are multipliers, not a cubature's
    everything = ReducedFemBody(
        full, U, all_points(full), hold_volume=False, name=f"{full.name}_training"
    )
    r = everything.r
    saved = [float(m.excitation.value) for m in muscles]
    G = np.empty((q.shape[0] * r, everything.m))
    kept = np.zeros(q.shape[0], dtype=bool)
    try:
        for s in tqdm(
            range(q.shape[0]), desc="training forces", unit="snapshot", disable=not progress
        ):
            for m, value in zip(muscles, excitations[s]):
                m.excitation.value = value
            everything.set_q(q[s])
            if np.min(everything.det_F()) > 0:
                G[s * r : (s + 1) * r] = everything.point_forces().T
                kept[s] = np.all(np.isfinite(G[s * r : (s + 1) * r]))
    finally:
        for m, value in zip(muscles, saved):
            m.excitation.value = value
    if not kept.any():
        raise InputError(
            "force_training_matrix: every training state inverts an element "
            "once projected on the basis"
        )
    if not kept.all():
        warnings.warn(
            f"force_training_matrix: {np.count_nonzero(~kept)} of {kept.size} "
            f"training states invert an element once projected on the basis; "
            f"left out",
            stacklevel=2,
        )
    G = G[np.repeat(kept, r)]
    return G, G.sum(axis=1)


def pressure_weights(
    full: FemBody, U: np.ndarray, points, pressure_basis: np.ndarray, q: np.ndarray
) -> tuple[np.ndarray, float]:
    """Cubature weights of a reduced body's volume constraint at its points, fitted to the
    constraint's Jacobian on training states (the constraint's own ECSW):

        min_{w >= 0} sum_s || sum_p w_p V_p pi_p dJ_p^T D_p - C_full(q_s) ||^2,

    C_full = dc/dq with every quadrature point (the exact Pi^T G U). The energy's weights are
    fitted to forces; the volume, a sum of J - 1 that is zero on incompressible training
    states, is not what they integrate, and its Jacobian is what the step holds
    (c + h C v = 0). Returns (weights (m,), relative residual). ``q``: reduced training
    states, one per row.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    exact = ReducedFemBody(
        full,
        U,
        all_points(full),
        pressure_basis=pressure_basis,
        name=f"{full.name}_pressure_training",
    )
    some = ReducedFemBody(
        full, U, points, pressure_basis=pressure_basis, name=f"{full.name}_pressure_points"
    )
    rows, target = [], []
    for state in q:
        exact.set_q(state)
        some.set_q(state)
        if min(exact.det_F().min(), some.det_F().min()) <= 0:
            continue
        target.append(exact.volume_constraint.jacobian().reshape(-1))
        per_point = some.volume_constraint.point_jacobians()
        rows.append(per_point.reshape(per_point.shape[0], -1).T)
    if not rows:
        raise InputError(
            "pressure_weights: every training state inverts an element once projected on the basis"
        )
    A, b = np.vstack(rows), np.concatenate(target)
    w_at, residual = nnls(A, b, maxiter=50 * A.shape[1])
    weights = np.zeros(some.m)
    weights[some.volume_constraint.at] = w_at
    return weights, float(residual / max(np.linalg.norm(b), np.finfo(float).tiny))
