"""The reductor: a scene in, the same scene with a reduced body in place of a full one out.

In the spirit of pyMOR's reductors, the inputs are the full model, its training inputs and
the reduction options; the output is a model of the same kind:

    reduced = reduce(model, training, basis=Basis("pod", 20), points=Points(300),
                     cache="cache/")
    scene = reduced.scene()          # model.build(), with the reduced body in place

``model`` (:class:`ReducibleScene`) says how to build the full scene, which FEM body to
reduce and how inputs (exciters) drive it. The stages (:class:`Reductor`), each an
artifact of :class:`~artifem.reduction.training.ArtifactCache` keyed by its inputs, so an
interrupted reduction resumes at the first one not on disk:

1. snapshots: the full scene driven by each training schedule, the body's nodal
   displacements u_s, its excitations a_s (and pressures p_s of a hard body) every few
   steps, and the pose coordinates g_c,s of each rigid body c that carries nodes of it;
2. a basis W = [U, L_1, ..., L_k]: U from the snapshots (mass-weighted POD of
   u_s - sum_c L_c g_c,s, which vanishes on carried nodes) or the body's linear modes
   (linear, extended by linear maps, modal derivatives); L_c the 12 rigid-lift columns
   of carrier c (:mod:`artifem.reduction.rigid_lift`);
3. integration points: trained (ECSW: NNLS on the reduced forces of W at the training
   states q_s = [U^T M (u_s - sum L g); g_s]) or random;
4. for a body with the hard incompressibility, its reduced pressure space (the constant
   and POD modes of the training pressures) and the constraint's cubature weights.

The training runs may be shared over the ranks of an MPI communicator
(:meth:`Reductor.train`, :mod:`artifem.reduction.distributed`): ``mpiexec -n N`` runs N of
them at a time, each rank on its own serial model, and the cache holds the results.

Couplings: a coupling of the scene that names the body must be able to follow it onto the
reduced body: it offers ``onto_reduced(reduced, lift)``, its replacement. One whose nodes
of the body ride on a rigid body also offers ``carried_nodes(body) -> (nodes, rigid body)``
(:class:`~artifem.multibody.attachments.NodeAttachment`: the basis gets their lift
columns, and ``lift`` is theirs); one through points or frames of the body keeps their
weights (:class:`~artifem.multibody.point_paths.PointPath`,
:class:`~artifem.multibody.attachments.FrameAttachment`; lift None); an FEM body embedded
in it keeps its own dofs' dynamics and follows the reduced body on the same weights,
x_s = W (X + u_bar + U q) + c, v_s = (W U) q', f_q = (W U)^T f_s
(:class:`~artifem.multibody.attachments.EmbeddedFemAttachment`; lift None). A coupling
may also say why it cannot follow this body, ``refusal(body) -> str | None`` (an
embedded attachment whose *slave* is the body: only its master can be reduced). Any
other, and any refused, is an error naming it, before any training.

Inputs: schedules drive the model's exciters (muscles of the body) and its load inputs
(``ReducibleScene.loads``: gravity, surface load levels, path muscles; found by name, so
they drive the reduced scene too): load cases in the training. A reduced body reads its
full body's excitations and loads.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mpi4py import MPI

from artifem.errors import InputError, UnknownNameError
from artifem.excitation import ExcitationSchedule
from artifem.fem_body import FemBody
from artifem.reduction.bases import (
    body_mass,
    extended_modes,
    linear_modes,
    modal_derivative_basis,
    pod_basis,
)
from artifem.reduction.cubature import IntegrationPoints, random_points, trained_points_path
from artifem.reduction.distributed import compute_shared
from artifem.reduction.quadrature_points import quadrature_points
from artifem.reduction.reduced_body import ReducedFemBody, all_points
from artifem.reduction.reduced_volume_constraint import pressure_basis
from artifem.reduction.rigid_lift import RigidLift, rigid_lift
from artifem.reduction.training import (
    ArtifactCache,
    Snapshots,
    force_training_matrix,
    pressure_weights,
    project,
    record_snapshots,
)
from artifem.scene import Scene
from artifem.scene import inputs as scene_inputs

__all__ = [
    "ReducibleScene",
    "Training",
    "Basis",
    "Points",
    "Reductor",
    "ReducedModel",
    "reduce",
    "BASES",
]

#: The bases a reductor builds.
BASES = ("pod", "linear", "extended", "modal-derivatives")


@dataclass(frozen=True)
class ReducibleScene:
    """What a reductor needs of a model.

    Attributes:
        name: the model's name (in progress bars and errors).
        build: a callable returning the full scene at rest, freshly built.
        body: the name of the FEM body of that scene to reduce.
        key: JSON-able inputs that identify the model (its configuration): the cache key
            of every stage starts from it.
        exciters: input name -> the muscles of the body it drives (default: each muscle
            is its own input).
        motions: the model's named test inputs (schedules over the exciters and loads).
        loads: input name -> a scene input (:mod:`artifem.scene.inputs`: gravity, a surface
            load's level, a path muscle's excitation) that schedules may drive beside the
            exciters: training on load cases. Part of every cache key.
    """

    name: str
    build: Callable[[], Scene]
    body: str
    key: Mapping
    exciters: Mapping[str, Sequence[str]] | None = None
    motions: Mapping[str, ExcitationSchedule] = field(default_factory=dict)
    loads: Mapping[str, scene_inputs.SceneInput] = field(default_factory=dict)

    def identity(self) -> dict:
        """What identifies the model's runs in a cache key: its key, body and load inputs."""
        loads = {"loads": scene_inputs.describe(self.loads)} if self.loads else {}
        return {"model": self.key, "body": self.body, **loads}

    def fem_body(self, scene: Scene) -> FemBody:
        """The body to reduce in ``scene`` (a clear error when it has none of that name)."""
        for body in scene.fem_bodies:
            if body.name == self.body:
                return body
        raise UnknownNameError(
            f"model {self.name!r}: its scene has no FEM body named "
            f"{self.body!r}; it has {[b.name for b in scene.fem_bodies]}"
        )

    def inputs(self, body: FemBody) -> dict[str, list[str]]:
        """Exciter name -> the muscles of ``body`` it drives."""
        if self.exciters is None:
            return {name: [name] for name in body.muscles}
        return {e: list(m) for e, m in self.exciters.items()}

    def input_names(self, body: FemBody) -> list[str]:
        """Every name a schedule of the model may drive: the exciters, then the loads."""
        exciters = self.inputs(body)
        both = sorted(set(exciters) & set(self.loads))
        if both:
            raise InputError(f"model {self.name!r}: {both} name both an exciter and a load")
        return [*exciters, *self.loads]

    def check_schedule(self, body: FemBody, schedule: ExcitationSchedule, what: str) -> None:
        """A clear error when ``schedule`` names an input the model does not have."""
        names = self.input_names(body)
        unknown = sorted(set(schedule.values) - set(names))
        if unknown:
            raise UnknownNameError(
                f"{what} of model {self.name!r} names unknown inputs "
                f"{unknown}; the inputs are {names}"
            )

    def muscle_schedule(self, body: FemBody, schedule: ExcitationSchedule) -> ExcitationSchedule:
        """The exciters of a schedule over the model's inputs expanded to the muscles they
        drive (its loads left out)."""
        self.check_schedule(body, schedule, "a schedule")
        inputs = self.inputs(body)
        return ExcitationSchedule(
            schedule.times,
            {
                muscle: values
                for e, values in schedule.values.items()
                if e in inputs
                for muscle in inputs[e]
            },
        )

    def drive(self, scene: Scene, schedule: ExcitationSchedule) -> Callable:
        """Add a controller applying ``schedule`` to the body's muscles and the scene's
        load inputs (returned, so that it can be removed); a reduced body reads the same
        excitations and loads."""
        body = self.fem_body_or_full(scene)
        muscles = self.muscle_schedule(body, schedule).controller(body)
        loads = scene_inputs.controller(
            ExcitationSchedule(
                schedule.times,
                {name: v for name, v in schedule.values.items() if name in self.loads},
            ),
            self.loads,
        )

        def control(system, t0: float, t1: float) -> None:
            muscles(system, t0, t1)
            loads(system, t0, t1)

        scene.add_controller(control)
        return control

    def fem_body_or_full(self, scene: Scene) -> FemBody:
        """The body to reduce, or the full body of the reduced body that replaced it."""
        for reduced in scene.reduced_bodies:
            if reduced.name == self.body:
                return reduced.full
        return self.fem_body(scene)


@dataclass(frozen=True)
class Training:
    """The full runs a reductor learns from: each schedule (over the model's inputs) for
    ``duration`` in steps of ``dt``, a snapshot every ``snapshot_every`` steps."""

    schedules: Mapping[str, ExcitationSchedule]
    duration: float
    dt: float
    snapshot_every: int = 5

    def __post_init__(self):
        if not self.schedules:
            raise InputError("Training: give at least one schedule")
        if not (np.isfinite(self.dt) and 0 < self.dt <= self.duration):
            raise InputError(
                f"Training: need 0 < dt <= duration, got dt={self.dt}, duration={self.duration}"
            )
        if int(self.snapshot_every) != self.snapshot_every or self.snapshot_every < 1:
            raise InputError(
                f"Training: snapshot_every must be a positive integer, got {self.snapshot_every!r}"
            )


@dataclass(frozen=True)
class Basis:
    """A basis: ``"pod"`` of the training snapshots (``size`` vectors), or from ``size``
    linear modes, ``"linear"`` (those modes), ``"extended"`` (each mode under the 9 linear
    maps, von Tycowicz et al. 2013) or ``"modal-derivatives"`` (Barbic & James 2005)."""

    kind: str = "pod"
    size: int = 20

    def __post_init__(self):
        if self.kind not in BASES:
            raise InputError(f"Basis: unknown kind {self.kind!r}; choose one of {BASES}")
        if int(self.size) != self.size or self.size < 1:
            raise InputError(f"Basis: size must be a positive integer, got {self.size!r}")


@dataclass(frozen=True)
class Points:
    """Integration points: ``count`` of them, ``"trained"`` (greedy NNLS to tolerance
    ``tol`` on ``training_states`` evenly spaced snapshots, ``growth``: points added per
    NNLS solve as a fraction of those selected) or ``"random"`` (seed ``seed``); or
    ``"all"`` of them at weight 1 (the full quadrature: a reference, O(n) per step)."""

    count: int = 300
    sampling: str = "trained"
    tol: float = 1e-4
    growth: float = 0.1
    training_states: int = 66
    seed: int = 0

    def __post_init__(self):
        if self.sampling not in ("trained", "random", "all"):
            raise InputError(
                f"Points: sampling must be 'trained', 'random' or 'all', got {self.sampling!r}"
            )
        for name in ("count", "training_states"):
            value = getattr(self, name)
            if int(value) != value or value < 1:
                raise InputError(f"Points: {name} must be a positive integer, got {value!r}")


@dataclass(frozen=True)
class Carrier:
    """Nodes of the reduced body carried by a rigid body, and their lift columns."""

    body: str
    lift: RigidLift


@dataclass
class ReducedModel:
    """What a reductor returns: the model, and the parts that put its reduced body in any
    freshly built scene of it.

    Attributes:
        basis: W = [U, L_1, ..., L_k] (ndofs x r).
        carriers: the rigid bodies whose lift columns end W, in that order.
        points: the integration points.
        pressure_basis, pressure_weights: the reduced pressure space and the constraint's
            cubature weights (a body with the hard incompressibility), else None.
        training: what the training took: snapshots, runs, seconds of computation per
            stage (also of stages loaded from the cache: the cost that bought them).
    """

    model: ReducibleScene
    basis: np.ndarray
    carriers: list[Carrier]
    points: IntegrationPoints
    pressure_basis: np.ndarray | None = None
    pressure_weights: np.ndarray | None = None
    training: dict = field(default_factory=dict)

    @property
    def r(self) -> int:
        return self.basis.shape[1]

    def body(self, full: FemBody) -> ReducedFemBody:
        """The reduced body of ``full`` (named as ``full``, which it replaces)."""
        return ReducedFemBody(
            full,
            self.basis,
            self.points,
            pressure_basis=self.pressure_basis,
            pressure_weights=self.pressure_weights,
            name=full.name,
        )

    def put_in(self, scene: Scene) -> tuple[ReducedFemBody, dict]:
        """Replace the model's full body in ``scene`` (built by the model, at rest) by its
        reduced body, and the couplings naming it by theirs. Returns (the reduced body,
        {name of a replaced coupling: its replacement})."""
        full = self.model.fem_body(scene)
        couplings = _couplings_of(scene, full, self.model.name)
        lifts = {(c.body, tuple(np.sort(c.lift.nodes))): c.lift for c in self.carriers}
        reduced = self.body(full)
        replaced = {}
        for coupling in couplings:
            nodes, carrier = _carried(coupling, full)
            lift = None if carrier is None else lifts.get((carrier.name, tuple(np.sort(nodes))))
            if carrier is not None and lift is None:
                raise InputError(
                    f"model {self.model.name!r}: coupling {coupling.name!r} "
                    f"carries nodes of {full.name!r} on {carrier.name!r} that "
                    "the reduced basis was not trained with"
                )
            replaced[coupling.name] = coupling.onto_reduced(reduced, lift)
        scene.remove(full, *couplings)
        scene.add(reduced, *replaced.values())
        return reduced, replaced

    def scene(self) -> Scene:
        """A freshly built scene of the model with the reduced body in place."""
        scene = self.model.build()
        self.put_in(scene)
        return scene


def _couplings_of(scene: Scene, body, model: str) -> list:
    """The scene's couplings that name ``body``; each must follow it onto a reduced body
    (module docstring), else a clear error before any training."""
    found = scene.couplings_of(body)
    for item in found:
        if not callable(getattr(item, "onto_reduced", None)):
            raise InputError(
                f"model {model!r}: {type(item).__name__} {getattr(item, 'name', '')!r} "
                f"couples {body.name!r}, and the reductor cannot carry it onto a reduced "
                "body (those that can: NodeAttachment, PointPath, FrameAttachment, "
                "EmbeddedFemAttachment with the body as its master, PlaneContact, "
                "MeshContact)"
            )
        refusal = getattr(item, "refusal", None)
        reason = refusal(body) if callable(refusal) else None
        if reason is not None:
            raise InputError(f"model {model!r}: {reason}")
    return found


def _carried(coupling, body) -> tuple:
    """(nodes of ``body``, the rigid body carrying them) of a coupling, else (None, None)."""
    carried = getattr(coupling, "carried_nodes", None)
    found = carried(body) if callable(carried) else None
    return found if found is not None else (None, None)


class Reductor:
    """The stages of a reduction (module docstring), each cached in ``cache``.

    Builds the model once at construction, at rest: its body, mass, quadrature points and
    the lift columns of the rigid bodies that carry nodes of it. ``comm``: the ranks
    :meth:`train` shares the training runs over (each builds its own serial model; the
    other stages are computed where they are called).
    """

    def __init__(
        self,
        model: ReducibleScene,
        training: Training,
        cache: str | Path,
        *,
        pressure_modes: int = 4,
        progress: bool = True,
        comm: MPI.Comm = MPI.COMM_SELF,
    ):
        self.model, self.training, self.progress, self.comm = model, training, progress, comm
        self.scene = model.build()
        self.body = model.fem_body(self.scene)
        if self.body.mesh.comm.size != 1:
            raise InputError(
                f"model {model.name!r}: its body {self.body.name!r} is distributed "
                f"over {self.body.mesh.comm.size} ranks; a reductor needs a serial "
                "model on each rank (build its mesh on MPI.COMM_SELF)"
            )
        inputs = model.inputs(self.body)
        for name, schedule in training.schedules.items():
            model.check_schedule(self.body, schedule, f"training schedule {name!r}")
        for load in model.loads.values():
            load.check(self.scene)
        missing = sorted({m for ms in inputs.values() for m in ms} - set(self.body.muscles))
        if missing:
            raise UnknownNameError(
                f"model {model.name!r}: its inputs drive muscles {missing} "
                f"that {self.body.name!r} does not define"
            )
        couplings = _couplings_of(self.scene, self.body, model.name)
        self.body.compile()
        self.mass = body_mass(self.body)
        self.table = quadrature_points(self.body)
        carried = [
            (nodes, carrier)
            for nodes, carrier in (_carried(coupling, self.body) for coupling in couplings)
            if carrier is not None
        ]
        self.carriers = []
        for i, (nodes, carrier) in enumerate(carried):
            # the lift holds the other carriers' nodes at rest (rigid_lift)
            others = [np.asarray(n) for k, (n, _) in enumerate(carried) if k != i]
            held = np.concatenate(others) if others else np.zeros(0, dtype=np.int64)
            self.carriers.append(
                Carrier(
                    carrier.name,
                    rigid_lift(self.body, nodes, carrier.position, carrier.rotation, held=held),
                )
            )
        hard = self.body.volume_constraint is not None
        if hard and pressure_modes < 1:
            raise InputError(f"pressure_modes must be >= 1, got {pressure_modes}")
        self.pressure_modes = pressure_modes if hard else 0
        self.cache = ArtifactCache(cache)  # created once the input is known good
        self.seconds: dict[str, float] = {}
        self._runs = None  # (each training run's Snapshots, seconds), loaded once
        self._snapshots = None

    # ---- stage 1: snapshots -------------------------------------------------------------

    def _timed(self, key: str, compute: Callable[[], dict]) -> tuple[dict, float]:
        """``cache.get``, the artifact holding the seconds it took to compute: (it, them)."""

        def timed():
            tic = time.perf_counter()
            arrays = compute()
            return {**arrays, "seconds": np.array(time.perf_counter() - tic)}

        data = self.cache.get(key, timed)
        return data, float(data.get("seconds", 0.0))

    def _cached(self, stage: str, key: str, compute: Callable[[], dict]) -> dict:
        """:meth:`_timed`, its seconds added to ``stage``'s."""
        data, seconds = self._timed(key, compute)
        self.seconds[stage] = self.seconds.get(stage, 0.0) + seconds
        return data

    def _run(self, name: str, schedule: ExcitationSchedule) -> dict[str, np.ndarray]:
        """One training run in a freshly built scene (:func:`record_snapshots`)."""
        t = self.training
        scene = self.model.build()
        body = self.model.fem_body(scene)
        self.model.drive(scene, schedule)
        bones = [next(b for b in scene.rigid_bodies if b.name == c.body) for c in self.carriers]
        on = f" (rank {self.comm.rank + 1}/{self.comm.size})" if self.comm.size > 1 else ""
        return record_snapshots(
            scene,
            body,
            duration=t.duration,
            dt=t.dt,
            every=t.snapshot_every,
            label=f"training {name}{on}",
            progress=self.progress,
            carriers=[(c.lift, bone) for c, bone in zip(self.carriers, bones)],
        ).as_arrays()

    def snapshot_keys(self) -> list[str]:
        t = self.training
        return [
            self.cache.key(
                "reductor-snapshots",
                **self.model.identity(),
                times=s.times,
                values=s.values,
                duration=t.duration,
                dt=t.dt,
                every=t.snapshot_every,
            )
            for s in t.schedules.values()
        ]

    def train(self) -> dict:
        """Compute the training runs not in the cache, shared over the ranks of ``comm``
        (collective: every rank calls it; :func:`compute_shared`). Returns what it did:
        ranks, runs computed, the names each rank computed, wall seconds."""
        jobs = [
            (name, key, lambda n=name, s=schedule, k=key: self._timed(k, lambda: self._run(n, s)))
            for key, (name, schedule) in zip(self.snapshot_keys(), self.training.schedules.items())
        ]
        return compute_shared(jobs, self.cache, self.comm)

    def snapshots(self) -> tuple[Snapshots, np.ndarray, list[str]]:
        """(snapshots of u - sum L g, the pose coordinates g (S, 12 k), their cache keys)."""
        if self._snapshots is None:
            self._snapshots = self._all_snapshots()
        self.seconds["snapshots"] = self._runs[1]
        return self._snapshots

    def _training_runs(self) -> list[Snapshots]:
        """Each training run's snapshots, computed (here, on this rank alone) or loaded
        from the cache, once."""
        if self._runs is None:
            runs, seconds = [], 0.0
            for key, (name, schedule) in zip(self.snapshot_keys(), self.training.schedules.items()):
                data, spent = self._timed(key, lambda n=name, s=schedule: self._run(n, s))
                seconds += spent
                runs.append(Snapshots.from_arrays(data))
            self._runs = (runs, seconds)
        return self._runs[0]

    def training_run(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(the steps of its snapshots, the body's displacements there) of the training run
        ``name``: the full model's answer on a training schedule, without another run."""
        names = list(self.training.schedules)
        if name not in names:
            raise UnknownNameError(f"no training schedule {name!r}; they are {names}")
        u = self._training_runs()[names.index(name)].displacements
        return self.training.snapshot_every * np.arange(1, len(u) + 1), u

    def _all_snapshots(self) -> tuple[Snapshots, np.ndarray, list[str]]:
        found = Snapshots.concatenate(self._training_runs())
        u = found.displacements
        g = found.poses if found.poses is not None else np.zeros((len(u), 0))
        L = self.lift_columns()
        if L.shape[1]:
            u = u - g @ L.T
            rows = self._carried_rows()
            off = float(np.abs(u[:, rows]).max(initial=0.0))
            if off > 1e-9 * max(float(np.abs(u).max()), float(np.abs(g @ L.T).max())):
                raise InputError(
                    f"model {self.model.name!r}: the carried nodes of "
                    f"{self.body.name!r} left their rigid bodies by up to "
                    f"{off:.3g} in training; the lift cannot carry them"
                )
            u[:, rows] = 0.0  # round-off of u - Phi g
        return Snapshots(u, found.excitations, found.pressures), g, self.snapshot_keys()

    def lift_columns(self) -> np.ndarray:
        n = 3 * self.body.V.dofmap.index_map.size_local
        return (
            np.hstack([c.lift.columns[:n] for c in self.carriers])
            if self.carriers
            else np.zeros((n, 0))
        )

    # ---- stage 2: the basis -------------------------------------------------------------

    def basis(self, spec: Basis) -> tuple[np.ndarray, str]:
        """(W = [U, L_1, ..., L_k], its cache key)."""
        if spec.kind == "pod":
            snapshots, _, keys = self.snapshots()
            key = self.cache.key("reductor-basis-pod", snapshots=keys, r=spec.size)
            U = self._cached(
                "basis",
                key,
                lambda: {
                    "U": pod_basis(snapshots.displacements, self._uncarried_mass(), r=spec.size)[0]
                },
            )["U"]
        else:
            if self.carriers:
                raise InputError(
                    f"model {self.model.name!r}: a {spec.kind!r} basis does not "
                    f"vanish on the nodes {[c.body for c in self.carriers]} "
                    "carry; use the 'pod' basis"
                )
            key = self.cache.key(
                f"reductor-basis-{spec.kind}",
                model=self.model.key,
                body=self.model.body,
                modes=spec.size,
            )

            def compute():
                if spec.kind == "modal-derivatives":
                    return {"U": modal_derivative_basis(self.body, spec.size)}
                modes, _ = linear_modes(self.body, spec.size)
                if spec.kind == "linear":
                    return {"U": modes}
                return {"U": extended_modes(modes, self.mass, fixed_dofs=self.body.fixed_dofs)}

            U = self._cached("basis", key, compute)["U"]
        return np.hstack([U, self.lift_columns()]), key

    def _carried_rows(self) -> np.ndarray:
        return (
            np.concatenate(
                [(3 * c.lift.dofs[:, None] + np.arange(3)).ravel() for c in self.carriers]
            )
            if self.carriers
            else np.zeros(0, dtype=np.int64)
        )

    def _uncarried_mass(self):
        """The mass with the carried rows zeroed: POD vectors then vanish there exactly,
        also those of round-off singular values (a POD size beyond the snapshots' rank)."""
        if not self.carriers:
            return self.mass
        keep = np.ones(3 * self.body.V.dofmap.index_map.size_local)
        keep[self._carried_rows()] = 0.0
        if callable(self.mass):
            return lambda x: keep * self.mass(keep * x)
        return keep * self.mass

    def training_states(
        self, W: np.ndarray, count: int, extra: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(q, excitations) of ``count`` snapshots evenly spaced over the training: the
        reduced coordinates [U^T M (u - L g); g] of the basis W = [U, L]; then the states
        ``extra`` (q, excitations) of W, e.g. states reduced runs visited
        (:func:`artifem.reduction.enrichment.greedy_points`)."""
        snapshots, g, _ = self.snapshots()
        S = snapshots.displacements.shape[0]
        rows = np.unique(np.linspace(0, S - 1, min(S, count)).round().astype(int))
        U = W[:, : W.shape[1] - g.shape[1]]
        q = np.hstack([project(U, self.mass, snapshots.displacements[rows]), g[rows]])
        a = snapshots.excitations[rows]
        if extra is None:
            return q, a
        q_x, a_x = (np.atleast_2d(np.asarray(x, dtype=float)) for x in extra)
        if q_x.shape[1] != W.shape[1] or a_x.shape != (q_x.shape[0], a.shape[1]):
            raise InputError(
                f"model {self.model.name!r}: extra training states must be "
                f"(k, {W.shape[1]}) coordinates and (k, {a.shape[1]}) "
                f"excitations, got {q_x.shape} and {a_x.shape}"
            )
        return np.vstack([q, q_x]), np.vstack([a, a_x])

    # ---- stage 3: the integration points ------------------------------------------------

    def points(
        self,
        W: np.ndarray,
        basis_key: str,
        spec: Points,
        counts: Sequence[int] | None = None,
        extra: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> dict[int, IntegrationPoints]:
        """{m: points} for m in ``counts`` (default ``spec.count``): trained ones from one
        greedy path (each m cached), on the training states and ``extra`` ones
        (:meth:`training_states`), or random ones."""
        counts = sorted({int(m) for m in (counts or [spec.count])})
        if spec.sampling == "all":
            return {m: all_points(self.body) for m in counts}
        if spec.sampling == "random":
            return {
                m: random_points(self.table.volume, m, rng=spec.seed, groups=self.table.degree)
                for m in counts
            }
        keys = {
            m: self.cache.key(
                "reductor-points",
                basis=basis_key,
                m=m,
                tol=spec.tol,
                growth=spec.growth,
                states=spec.training_states,
                snapshots=self.snapshot_keys(),
                **({} if extra is None else {"extra": list(extra)}),
            )
            for m in counts
        }
        cached = {m: self.cache.load(k) for m, k in keys.items()}
        if any(v is None for v in cached.values()):
            tic = time.perf_counter()
            q, a = self.training_states(W, spec.training_states, extra)
            G, b = force_training_matrix(self.body, W, q, a, progress=self.progress)
            path = trained_points_path(
                G, b, sizes=counts, tol=spec.tol, growth=spec.growth, progress=self.progress
            )
            del G
            seconds = (time.perf_counter() - tic) / len(counts)
            for m, pts in path.items():
                cached[m] = {
                    "indices": pts.indices,
                    "weights": pts.weights,
                    "residual": np.array(pts.residual),
                    "seconds": np.array(seconds),
                }
                self.cache.save(keys[m], cached[m])
        self.seconds["points"] = self.seconds.get("points", 0.0) + sum(
            float(d.get("seconds", 0.0)) for d in cached.values()
        )
        return {
            m: IntegrationPoints(d["indices"], d["weights"], "trained", float(d["residual"]))
            for m, d in cached.items()
        }

    # ---- stage 4: the pressure space of a hard body -------------------------------------

    def pressure_space(self) -> np.ndarray | None:
        """The constant pressure and ``pressure_modes - 1`` POD modes of the training
        pressures (a body with the hard incompressibility), else None."""
        if self.pressure_modes == 0:
            return None
        snapshots, _, _ = self.snapshots()
        return pressure_basis(
            snapshots.pressures, self.body.volume_constraint.volume, self.pressure_modes
        )

    def constraint_weights(
        self, W: np.ndarray, basis_key: str, pts: IntegrationPoints, Pi: np.ndarray, states: int
    ) -> np.ndarray:
        """The volume constraint's cubature weights at ``pts`` (training.pressure_weights on
        ``states`` training states), cached."""
        key = self.cache.key(
            "reductor-pressure-weights",
            basis=basis_key,
            indices=pts.indices,
            weights=pts.weights,
            modes=self.pressure_modes,
            states=states,
            snapshots=self.snapshot_keys(),
        )

        def fit():
            q, _ = self.training_states(W, states)
            weights, residual = pressure_weights(self.body, W, pts, Pi, q)
            return {"weights": weights, "residual": np.array(residual)}

        return self._cached("pressure weights", key, fit)["weights"]

    # ---- all of them --------------------------------------------------------------------

    def reduce(
        self,
        basis: Basis = Basis(),
        points: Points = Points(),
        extra_states: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> ReducedModel:
        """The reduced model of ``basis`` and ``points`` (trained points also on
        ``extra_states``, :meth:`training_states`)."""
        self.seconds = {}
        W, key = self.basis(basis)
        pts = self.points(W, key, points, extra=extra_states)[points.count]
        Pi = self.pressure_space()
        weights = (
            None if Pi is None else self.constraint_weights(W, key, pts, Pi, points.training_states)
        )
        trained = "snapshots" in self.seconds  # this model used the training
        return ReducedModel(
            self.model,
            W,
            list(self.carriers),
            pts,
            Pi,
            weights,
            training={
                "runs": len(self.training.schedules) if trained else 0,
                "snapshots": int(self._snapshots[0].displacements.shape[0]) if trained else 0,
                "basis": {
                    "kind": basis.kind,
                    "size": basis.size,
                    "lift_columns": 12 * len(self.carriers),
                    "r": int(W.shape[1]),
                },
                "points": {
                    "count": int(pts.m),
                    "sampling": points.sampling,
                    "residual": pts.residual,
                    "extra_states": 0
                    if extra_states is None
                    else int(np.atleast_2d(extra_states[0]).shape[0]),
                },
                "seconds": dict(self.seconds),
            },
        )


def reduce(
    model: ReducibleScene,
    training: Training,
    *,
    basis: Basis = Basis(),
    points: Points = Points(),
    cache: str | Path,
    pressure_modes: int = 4,
    progress: bool = True,
) -> ReducedModel:
    """The reduced model of ``model`` trained by ``training`` (module docstring)."""
    return Reductor(
        model, training, cache, pressure_modes=pressure_modes, progress=progress
    ).reduce(basis, points)
