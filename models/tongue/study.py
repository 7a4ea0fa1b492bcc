"""The tongue speed-versus-error study of reduced models (Lloyd et al. 2019, section 2.3).

    artifem study tongue --out DIR [--level 0|1] [--points 600 300 200] [--pod-r 20] [--quick]
                         [--incompressibility hard|penalty] [--random-training N]
                         [--held-out N] [--held-out-seed S] [--error-sources] [--train-only]
                         [--galerkin-gap]
                         [--greedy-pool N --greedy-runs N --greedy-tol MM]
    mpiexec -n N artifem study tongue ...   the training shared over N ranks, the rest on one

The tongue holds its element volumes (the hard incompressibility, its default) and the
reduced bodies hold them in a reduced pressure space; ``--incompressibility penalty``
studies the element penalty instead.

On one tongue (each rank builds its own, on MPI.COMM_SELF):

1. training (cached in DIR/cache, resumable): the full model driven by each
   exciter alone (ramp to ``training_excitation`` over 0.5 s, hold), nodal
   displacements and excitations recorded every ``snapshot_every`` steps; under
   ``mpiexec -n N`` the runs are shared over the N ranks, then rank 0 runs the rest of
   the study in a fresh serial process, from the same cache
   (:mod:`artifem.reduction.distributed`); DIR/training.json
   says what the training did (ranks, runs computed by each, wall and compute seconds);
   with ``--greedy-pool N`` the training then grows greedily (on one process) from a pool
   of N random schedules, the worst estimated first (:mod:`artifem.reduction.enrichment`),
   until ``--greedy-runs`` runs are added or every estimate is below ``--greedy-tol`` mm
   (DIR/greedy.json: each iteration's estimates); ``--train-only`` stops here (under
   mpiexec: before the greedy part);
2. bases: *extended modal* (6 linear modes x 9 linear maps = 54 vectors, von
   Tycowicz et al. 2013) and *trained* (mass-weighted POD of the snapshots, r = 20);
   optionally (``--bases``) *modal derivatives* (6 modes and their 21 derivatives,
   Barbic & James 2005);
3. integration points: m = 600, 300, 200 quadrature points, *trained* (ECSW
   on the snapshots' reduced forces, one greedy path per basis) or *random*
   (uniform per quadrature rule, volume kept);
4. the full model runs each speech motion (1 s, dt = 10 ms), then every
   reduced configuration runs it in a Scene with the same integrator and
   the same excitation controller; the error at a step is the mean over the
   nodes of |x_reduced - x_full|.

5. the train/test split (:mod:`artifem.reduction.generalization`, ``--held-out N``,
   default 5): the trained POD model with the renders' points on the training schedules,
   the motions and N random multi-exciter schedules drawn with a seed the training never
   saw, its error beside a hierarchical estimate (no full run); ``--error-sources`` adds
   where the error comes from (the basis' best approximation, the model with every point).
   ``--random-training N`` adds N random multi-exciter schedules to the training (seed
   ``training_seed``). ``--galerkin-gap`` runs, instead of the study, the diagnosis of
   :mod:`artifem.reduction.galerkin_gap` on the held-out schedules (OUT/galerkin_gap.json).

Results: DIR/study.json, DIR/series.npz, DIR/frames/*.npz (full and reduced
displacements at the time of largest error), DIR/generalization.json (.md, .png, series),
then the report stage (:mod:`artifem.models.tongue.report`): report.md and PNGs.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from mpi4py import MPI
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from artifem.arguments import nonnegative_int, positive_float, positive_int
from artifem.errors import InputError
from artifem.models.tongue.model import (
    DT,
    DURATION,
    HARD,
    MOTIONS,
    PENALTY,
    RAMP_TIME,
    Tongue,
    TongueConfig,
    load_tongue_data,
)
from artifem.reduction.cubature import IntegrationPoints
from artifem.reduction.distributed import continue_alone, record_training
from artifem.reduction.quadrature_points import quadrature_points
from artifem.reduction.reduced_body import ReducedFemBody
from artifem.reduction.enrichment import greedy_training
from artifem.reduction.galerkin_gap import galerkin_gap, write_markdown
from artifem.reduction.generalization import generalization_study, held_out_schedules
from artifem.reduction.reductor import Basis, Points, ReducibleScene, Reductor, Training
from artifem.reduction.schedules import each_alone, random_schedules
from artifem.scene import Scene, simulate

TARGETS = {"ms_per_step": 1.0, "speedup": 100.0, "max_error_mm": 1.0}
#: ``--galerkin-gap``: every input constant for this long (s) makes an instant held
GAP_HOLD = 0.1
#: Bases the study can build (the paper's two, and linear modes with modal derivatives).
BASES = ("extended-modal", "trained-pod", "modal-derivatives")


@dataclass(frozen=True)
class StudyConfig:
    """What the study runs (defaults: the paper's experiment)."""

    level: int = 0
    bases: tuple[str, ...] = ("extended-modal", "trained-pod")
    linear_modes: int = 6  # extended: 9 x 6 = 54 vectors
    pod_r: int = 20
    points: tuple[int, ...] = (600, 300, 200)
    samplings: tuple[str, ...] = ("trained", "random")
    motions: tuple[str, ...] = tuple(MOTIONS)
    training_excitation: float = 0.6
    training_duration: float = 0.7
    #: random multi-exciter training schedules added to the exciters alone
    #: (:func:`~artifem.reduction.schedules.random_schedules`, seed ``training_seed``)
    random_training: int = 0
    training_seed: int = 1
    #: held-out random schedules (seed ``held_out_seed``) for the train/test split
    #: (:mod:`artifem.reduction.generalization`), run on the trained POD basis with the
    #: points of the renders; 0: none
    held_out: int = 5
    held_out_seed: int = 1000
    #: the split also says where the error comes from (the basis' best approximation, the
    #: reduced model with every point: ``generalization_study(sources=True)``)
    error_sources: bool = False
    #: greedy training (:mod:`artifem.reduction.enrichment`): a pool of ``greedy_pool``
    #: random schedules (seed ``greedy_seed``) from which at most ``greedy_runs`` are added
    #: to the training, worst estimate first, until the estimate is <= ``greedy_tol`` mm
    greedy_pool: int = 0
    greedy_runs: int = 0
    greedy_tol: float = 0.0
    greedy_seed: int = 2
    snapshot_every: int = 5
    #: Training states used for the cubature fit (evenly spaced among all snapshots).
    force_snapshots: int = 66
    cubature_tol: float = 1e-4
    #: Points added per NNLS solve, as a fraction of those selected (see trained_points).
    cubature_growth: float = 0.1
    seed: int = 0
    dt: float = DT
    duration: float = DURATION
    #: "hard" (:data:`HARD`, TongueConfig's default: the full model holds every element's
    #: volume; the reduced bodies hold ``pressure_modes`` pressure modes, the constant one
    #: and POD modes of the training pressures, with cubature weights fitted to the
    #: constraint's Jacobian on the training states) or "penalty" (:data:`PENALTY`)
    incompressibility: str = "hard"
    pressure_modes: int = 4

    def __post_init__(self):
        if self.incompressibility not in ("penalty", "hard"):
            raise InputError(
                f"incompressibility must be 'penalty' or 'hard', got {self.incompressibility!r}"
            )
        if (
            self.incompressibility == "hard"
            and "trained-pod" in self.bases
            and not 1 <= self.pressure_modes < self.pod_r
        ):
            raise InputError(
                f"pressure_modes ({self.pressure_modes}) must be in [1, pod_r = {self.pod_r})"
            )
        unknown = set(self.bases) - set(BASES)
        if unknown:
            raise InputError(f"unknown bases {sorted(unknown)}; use {', '.join(BASES)}")
        unknown = set(self.samplings) - {"trained", "random"}
        if unknown:
            raise InputError(f"unknown samplings {sorted(unknown)}; use trained, random")
        unknown = set(self.motions) - set(MOTIONS)
        if unknown:
            raise InputError(f"unknown motions {sorted(unknown)}; choose from {sorted(MOTIONS)}")
        if not self.points or min(self.points) < 1:
            raise InputError(f"points must be positive counts, got {self.points}")
        if self.held_out and self.random_training and self.held_out_seed == self.training_seed:
            raise InputError(
                f"held_out_seed ({self.held_out_seed}) must differ from "
                f"training_seed: held-out schedules are inputs the training "
                "never saw"
            )
        if self.greedy_pool:
            seeds = {
                "held_out_seed": self.held_out_seed if self.held_out else None,
                "training_seed": self.training_seed if self.random_training else None,
            }
            for name, seed in seeds.items():
                if seed == self.greedy_seed:
                    raise InputError(
                        f"greedy_seed ({self.greedy_seed}) must differ from "
                        f"{name}: the pools must not share schedules"
                    )
            if self.greedy_runs < 1 and self.greedy_tol <= 0:
                raise InputError(
                    "a greedy training needs greedy_runs >= 1 or greedy_tol > 0 (where to stop)"
                )
        if not 0.0 < self.training_excitation <= 1.0:
            raise InputError(
                f"training_excitation must be in (0, 1], got {self.training_excitation}"
            )


def reducible(config: TongueConfig, data=None) -> ReducibleScene:
    """The tongue as the reductor sees it: its scene, driven by its exciters (bilateral
    muscles drive both bundles), with the seed paper's motions."""
    data = data or load_tongue_data(config.level)
    return ReducibleScene(
        "tongue",
        lambda: Tongue(config, MPI.COMM_SELF, data).scene,
        "tongue",
        {"tongue": asdict(config)},
        exciters=data.exciters,
        motions={m: Tongue.motion(m) for m in MOTIONS},
    )


def reducible_at(level: int = 0, incompressibility: str = "hard") -> ReducibleScene:
    """The tongue at ``level`` with its default settings, the hard incompressibility or
    (``"penalty"``) the element penalty (:func:`reducible`; ``artifem study robustness
    tongue``, ``tongue-level1``, ``tongue-penalty``)."""
    return reducible(
        TongueConfig(
            level=level, incompressibility={"hard": HARD, "penalty": PENALTY}[incompressibility]
        )
    )


class TongueStudy:
    """Runs the study (see the module docstring); each stage is a method."""

    def __init__(
        self,
        config: StudyConfig,
        out: Path,
        cache: Path | None = None,
        comm: MPI.Comm = MPI.COMM_SELF,
    ):
        self.config, self.out = config, Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        hard = config.incompressibility == "hard"
        tongue_config = TongueConfig(
            level=config.level, incompressibility=HARD if hard else PENALTY
        )
        self.tongue = Tongue(tongue_config, MPI.COMM_SELF)
        self.body = self.tongue.body
        self.body.compile()
        self.volume0 = self.body.volume()
        self.table = quadrature_points(self.body)
        schedules = each_alone(self.tongue.exciters, config.training_excitation, RAMP_TIME)
        if config.random_training:
            schedules.update(
                random_schedules(
                    self.tongue.exciters,
                    config.random_training,
                    seed=config.training_seed,
                    duration=config.training_duration,
                )
            )
        training = Training(schedules, config.training_duration, config.dt, config.snapshot_every)
        #: the training stages (snapshots, bases, points, pressure space), cached
        self.reductor = Reductor(
            reducible(tongue_config, self.tongue.data),
            training,
            cache or self.out / "cache",
            pressure_modes=config.pressure_modes,
            comm=comm,
        )
        n = self.body.V.dofmap.index_map.size_local
        node_of_dof = np.empty(n, dtype=np.int64)
        for node, dof in self.body._input_node_to_dof().items():
            if dof < n:
                node_of_dof[dof] = node
        self.node_of_dof = node_of_dof

    # ---- training (the reductor's stages) ----------------------------------------------

    def train(self) -> dict | None:
        """The training runs not in the cache, shared over the ranks (collective); rank 0
        writes OUT/training.json and returns it (other ranks: None)."""
        done = self.reductor.train()
        if self.reductor.comm.rank != 0:
            return None
        snapshots, _, _ = self.reductor.snapshots()
        done.update(
            runs=len(self.reductor.training.schedules),
            snapshots=int(snapshots.displacements.shape[0]),
            compute_seconds=self.reductor.seconds["snapshots"],
            level=self.config.level,
            incompressibility=self.config.incompressibility,
            random_training=self.config.random_training,
            training_duration=self.config.training_duration,
        )
        record_training(
            self.out / "training.json",
            done,
            ("runs", "level", "incompressibility", "random_training", "training_duration"),
        )
        if self.config.greedy_pool and self.reductor.comm.size == 1:
            self.greedy()  # on one process (under mpiexec: its continuation)
        return done

    def greedy(self) -> dict:
        """Greedy training from the study's training over a pool of random schedules
        (:func:`~artifem.reduction.enrichment.greedy_training`, the trained POD basis and
        the renders' points); the study then uses the enriched training. Writes
        OUT/greedy.json (the estimates of every iteration, the schedules added)."""
        c, reductor = self.config, self.reductor
        pool = random_schedules(
            self.tongue.exciters,
            c.greedy_pool,
            seed=c.greedy_seed,
            duration=c.training_duration,
            prefix="greedy",
        )
        tic = time.perf_counter()
        result = greedy_training(
            reductor.model,
            reductor.training,
            pool,
            cache=reductor.cache.root,
            basis=Basis("pod", c.pod_r),
            points=self._render_points(),
            tol=c.greedy_tol,
            max_runs=len(reductor.training.schedules) + c.greedy_runs if c.greedy_runs else None,
            pressure_modes=c.pressure_modes,
        )
        self.reductor = result.reductor
        summary = {
            **result.summary(),
            "pool": c.greedy_pool,
            "seed": c.greedy_seed,
            "tol_mm": c.greedy_tol,
            "max_added": c.greedy_runs,
            "wall_seconds": time.perf_counter() - tic,
        }
        (self.out / "greedy.json").write_text(json.dumps(summary, indent=1))
        return summary

    def _render_points(self) -> Points:
        c = self.config
        return Points(
            self._frame_m(),
            tol=c.cubature_tol,
            growth=c.cubature_growth,
            training_states=c.force_snapshots,
        )

    def basis(self, name: str) -> tuple[np.ndarray, str]:
        """(U, cache key) of a basis of the study."""
        c = self.config
        spec = {
            "trained-pod": Basis("pod", c.pod_r),
            "extended-modal": Basis("extended", c.linear_modes),
            "modal-derivatives": Basis("modal-derivatives", c.linear_modes),
        }[name]
        return self.reductor.basis(spec)

    def point_sets(self, U, basis_key) -> dict[tuple[int, str], IntegrationPoints]:
        """{(m, sampling): points} of every count and sampling of the study (trained: one
        greedy path, each m cached)."""
        c, sets = self.config, {}
        for sampling in c.samplings:
            spec = Points(
                sampling=sampling,
                tol=c.cubature_tol,
                growth=c.cubature_growth,
                training_states=c.force_snapshots,
                seed=c.seed,
            )
            for m, pts in self.reductor.points(U, basis_key, spec, counts=c.points).items():
                sets[(m, sampling)] = pts
        return sets

    def volume_changes(self, displacements: np.ndarray) -> np.ndarray:
        """V(t) / V0 - 1 of the full mesh at each displacement row (O(n) each: after a run,
        outside its timing)."""
        n = displacements.shape[1]
        u = self.body.u.x.array
        saved = u[:n].copy()
        V0 = self.volume0
        changes = np.full(displacements.shape[0], np.nan)
        for k, row in enumerate(displacements):
            if np.all(np.isfinite(row)):
                u[:n] = row
                self.body.u.x.scatter_forward()
                changes[k] = self.body.volume() / V0 - 1.0
        u[:n] = saved
        self.body.u.x.scatter_forward()
        return changes

    # ---- runs ---------------------------------------------------------------

    def _controller(self, motion: str):
        return self.tongue.bundle_schedule(Tongue.motion(motion)).controller(self.body)

    def full_run(self, motion: str) -> dict:
        """The full model through a motion: displacements at every step and step times."""
        c = self.config
        self.tongue.reset()
        self.tongue.drive(Tongue.motion(motion))
        n = 3 * self.body.V.dofmap.index_map.size_local
        run = simulate(
            self.tongue.scene,
            c.duration,
            c.dt,
            label=f"full {motion}",
            record={"u": lambda s: self.body.u.x.array[:n].copy()},
        )
        return {
            "u": run.records["u"],
            "ms_per_step": run.ms_per_step,
            "volume_change": self.volume_changes(run.records["u"]),
        }

    def reduced_run(self, reduced: ReducedFemBody, motion: str, full: dict, run_id: str) -> dict:
        """A reduced configuration through a motion, its error against the full run."""
        c = self.config
        self.tongue.reset()
        reduced.set_state(tuple(np.zeros_like(part) for part in reduced.state()))
        scene = Scene(gravity=(0.0, 0.0, 0.0), integrator=self.tongue.config.integrator)
        scene.add(reduced)
        scene.add_controller(self._controller(motion))
        steps = full["u"].shape[0] - 1
        # r x r and m x 9 x 9 algebra: BLAS threads only add synchronization.
        with threadpool_limits(limits=1, user_api="blas"):
            run = simulate(
                scene,
                steps * c.dt,
                c.dt,
                record={"q": lambda s: reduced.q.copy()},
                on_failure="stop",
                label=run_id,
                leave=False,
            )
        q = np.full((steps + 1, reduced.r), np.nan)
        q[: len(run.records["q"])] = run.records["q"]
        ms = run.step_ms.tolist()
        failure = None if run.failure is None else str(run.failure)
        u_red = q @ reduced.U.T + reduced.u_bar  # (steps + 1, ndofs)
        node_error = 1e3 * np.linalg.norm((u_red - full["u"]).reshape(steps + 1, -1, 3), axis=2)
        mean_error = node_error.mean(axis=1)
        worst = int(np.nanargmax(mean_error)) if np.any(np.isfinite(mean_error)) else 0
        return {
            "q": q,
            "ms": ms,
            "failure": failure,
            "mean_error": mean_error,
            "max_node_error": float(np.nanmax(node_error)) if ms else float("nan"),
            "worst_step": worst,
            "u_worst": u_red[worst],
            "volume_change": self.volume_changes(u_red),
        }

    # ---- the study ------------------------------------------------------------

    def run(self) -> Path:
        c = self.config
        snapshots, _, snapshot_keys = self.reductor.snapshots()
        bases = {name: self.basis(name) for name in c.bases}
        pressures = self.reductor.pressure_space()
        point_sets = {
            (name, m, sampling): pts
            for name, (U, key) in bases.items()
            for (m, sampling), pts in self.point_sets(U, key).items()
        }
        full = {motion: self.full_run(motion) for motion in c.motions}
        steps = int(round(c.duration / c.dt))
        times = np.arange(steps + 1) * c.dt
        runs, series = [], {"times": times}
        frames = self.out / "frames"
        frames.mkdir(exist_ok=True)
        for (name, m, sampling), pts in tqdm(
            point_sets.items(), desc="reduced configurations", unit="config"
        ):
            U, basis_key = bases[name]
            weights = (
                None
                if pressures is None
                else self.reductor.constraint_weights(
                    U, basis_key, pts, pressures, c.force_snapshots
                )
            )
            reduced = ReducedFemBody(
                self.body,
                U,
                pts,
                pressure_basis=pressures,
                pressure_weights=weights,
                name=f"{name}_{m}_{sampling}",
            )
            for motion in c.motions:
                run_id = f"{name}_r{U.shape[1]}_m{m}_{sampling}_{motion}"
                result = self.reduced_run(reduced, motion, full[motion], run_id)
                series[f"error/{run_id}"] = result["mean_error"]
                runs.append(
                    self._summary(
                        run_id, name, U.shape[1], m, sampling, motion, pts, result, full[motion]
                    )
                )
                if name == "trained-pod" and sampling == "trained" and m == self._frame_m():
                    self._write_frame(frames / f"{run_id}.npz", full[motion], result, times)
        study = {
            "model": {
                "name": "tongue",
                "level": c.level,
                "nodes": int(self.node_of_dof.size),
                "elements": int(self.tongue.data.mesh.cells.shape[0]),
                "dofs": int(3 * self.node_of_dof.size),
                "quadrature_points": int(self.table.size),
            },
            "dt": c.dt,
            "duration": c.duration,
            "full": {
                "ms_per_step": float(np.median([f["ms_per_step"] for f in full.values()])),
                "ms_per_step_by_motion": {k: f["ms_per_step"] for k, f in full.items()},
                "max_volume_change_by_motion": {
                    k: float(np.nanmax(np.abs(f["volume_change"]))) for k, f in full.items()
                },
            },
            "incompressibility": c.incompressibility,
            "training": {
                "snapshots": int(snapshots.displacements.shape[0]),
                "runs": len(snapshot_keys),
                "random_schedules": c.random_training,
                "training_excitation": c.training_excitation,
                "force_snapshots": c.force_snapshots,
                "cubature_tol": c.cubature_tol,
                "trained_residual": {
                    f"{b}_m{m}": pts.residual
                    for (b, m, s), pts in point_sets.items()
                    if s == "trained"
                },
            },
            "config": asdict(c),
            "runs": runs,
            "targets": TARGETS,
        }
        if c.held_out and "trained-pod" in c.bases:
            generalization_study(
                self.reductor,
                self.out,
                basis=Basis("pod", c.pod_r),
                points=self._render_points(),
                held_out=c.held_out,
                seed=c.held_out_seed,
                duration=c.duration,
                dt=c.dt,
                sources=c.error_sources,
            )
        (self.out / "study.json").write_text(json.dumps(study, indent=1))
        np.savez(self.out / "series.npz", **series)
        from artifem.models.tongue.report import write_report

        return write_report(self.out)

    def galerkin_gap(self) -> Path:
        """Why the trained POD model (the renders' points) is off on the held-out schedules
        (:mod:`artifem.reduction.galerkin_gap`): OUT/galerkin_gap.json and .md."""
        c = self.config
        reduced = self.reductor.reduce(Basis("pod", c.pod_r), self._render_points())
        schedules = held_out_schedules(
            self.reductor.model,
            sorted(self.reductor.model.input_names(self.body)),
            self.reductor.training,
            c.held_out,
            c.held_out_seed,
            c.duration,
        )
        figures = {
            "level": c.level,
            "incompressibility": c.incompressibility,
            "r": reduced.r,
            "points": int(reduced.points.m),
            "random_training": c.random_training,
            "held_out_seed": c.held_out_seed,
            "hold": GAP_HOLD,
            "runs": galerkin_gap(
                reduced,
                schedules,
                c.duration,
                c.dt,
                self.reductor.cache,
                hold=GAP_HOLD,
                training=self.reductor.snapshots()[0],
            ),
        }
        (self.out / "galerkin_gap.json").write_text(json.dumps(figures, indent=1))
        (self.out / "galerkin_gap.md").write_text(
            f"# The Galerkin gap: tongue level {c.level}, {c.incompressibility}, r = "
            f"{reduced.r}, {reduced.points.m} points\n\nMean node distances (mm) at the held "
            f"instant of largest error of each held-out run (artifem.reduction.galerkin_gap)."
            f"\n\n" + write_markdown(figures["runs"])
        )
        return self.out / "galerkin_gap.json"

    def _frame_m(self) -> int:
        """The point count shown in renders: 300 as in the paper's Fig. 5, else the middle one."""
        points = sorted(self.config.points)
        return 300 if 300 in points else points[len(points) // 2]

    def _summary(self, run_id, basis, r, m, sampling, motion, pts, result, full) -> dict:
        ms = float(np.median(result["ms"])) if result["ms"] else float("nan")
        summary = {
            "id": run_id,
            "basis": basis,
            "r": int(r),
            "points": int(m),
            "points_used": int(pts.m),
            "sampling": sampling,
            "motion": motion,
            "ms_per_step": ms,
            "mean_error_mm": float(np.nanmean(result["mean_error"])),
            "max_error_mm": float(np.nanmax(result["mean_error"])),
            "max_node_error_mm": result["max_node_error"],
            "speedup": full["ms_per_step"] / ms,
            "time_of_max_error": float(result["worst_step"] * self.config.dt),
            "max_volume_change": float(np.nanmax(np.abs(result["volume_change"]))),
            "full_max_volume_change": float(np.nanmax(np.abs(full["volume_change"]))),
            "failed": result["failure"] is not None,
        }
        if result["failure"] is not None:
            summary["error"] = result["failure"]
        return summary

    def _write_frame(self, path: Path, full: dict, result: dict, times) -> None:
        """Rest nodes, hexahedra and both displacements (input node order) at the worst step."""
        k = result["worst_step"]
        mesh = self.tongue.data.mesh
        n = mesh.points.shape[0]
        u_full = np.zeros((n, 3))
        u_red = np.zeros((n, 3))
        u_full[self.node_of_dof] = full["u"][k].reshape(-1, 3)
        u_red[self.node_of_dof] = result["u_worst"].reshape(-1, 3)
        np.savez(
            path,
            points=mesh.points,
            cells=mesh.cells,
            u_full=u_full,
            u_reduced=u_red,
            time=float(times[k]),
        )


def quick_config(level: int = 0) -> StudyConfig:
    """A small study for tests and smoke runs: one motion, short, few points."""
    return StudyConfig(
        level=level,
        points=(120, 60),
        motions=("protrusion",),
        duration=0.3,
        training_duration=0.3,
        snapshot_every=10,
        force_snapshots=20,
        pod_r=8,
        linear_modes=2,
        pressure_modes=3,
        held_out=0,
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument(
        "--level",
        type=int,
        choices=(0, 1),
        default=0,
        help="tongue fidelity: 0 as shipped, 1 split 2x2x2",
    )
    parser.add_argument(
        "--points",
        type=positive_int,
        nargs="+",
        default=None,
        help="integration point counts (default 600 300 200)",
    )
    parser.add_argument(
        "--pod-r",
        type=positive_int,
        default=None,
        help="vectors of the trained POD basis (default 20)",
    )
    parser.add_argument("--motions", nargs="+", choices=sorted(MOTIONS), default=None)
    parser.add_argument(
        "--bases",
        nargs="+",
        choices=BASES,
        default=None,
        help="bases to compare (default: extended-modal trained-pod)",
    )
    parser.add_argument(
        "--cache", type=Path, default=None, help="training cache directory (default OUT/cache)"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a small smoke-test study (one motion, 0.3 s, few points)",
    )
    parser.add_argument(
        "--incompressibility",
        choices=("hard", "penalty"),
        default="hard",
        help="the hard constraint (the default: reduced bodies hold "
        "--pressure-modes POD modes of the training pressures), or the "
        "element penalty 100 C10",
    )
    parser.add_argument(
        "--random-training",
        type=nonnegative_int,
        default=None,
        help="random multi-exciter training schedules added to the exciters alone (default 0)",
    )
    parser.add_argument(
        "--training-duration",
        type=positive_float,
        default=None,
        help="seconds of each training run (default 0.7; --quick: 0.3)",
    )
    parser.add_argument(
        "--held-out",
        type=nonnegative_int,
        default=None,
        help="held-out random schedules the trained POD model is tested on (default 5; --quick: 0)",
    )
    parser.add_argument(
        "--held-out-seed",
        type=int,
        default=None,
        help="their seed (default 1000; must differ from the training's)",
    )
    parser.add_argument(
        "--error-sources",
        action="store_true",
        default=None,
        help="the split also reports where the error comes from: the full "
        "runs' projection on the basis and the reduced model with every "
        "integration point (one O(n)-per-step run each)",
    )
    parser.add_argument(
        "--greedy-pool",
        type=nonnegative_int,
        default=None,
        help="greedy training: a pool of N random schedules (seed "
        "--greedy-seed) from which the worst estimated are added to the "
        "training (default 0: none)",
    )
    parser.add_argument(
        "--greedy-runs",
        type=nonnegative_int,
        default=None,
        help="greedy training: at most N runs added",
    )
    parser.add_argument(
        "--greedy-tol",
        type=positive_float,
        default=None,
        help="greedy training: stop when every estimate is below MM",
    )
    parser.add_argument("--greedy-seed", type=int, default=None, help="the pool's seed (default 2)")
    parser.add_argument(
        "--train-only",
        action="store_true",
        help="run the training (shared over the ranks under mpiexec), write "
        "OUT/training.json and stop",
    )
    parser.add_argument(
        "--galerkin-gap",
        action="store_true",
        help="after the training, only diagnose the trained POD model's "
        "error on the held-out schedules at their held instants (best "
        "approximation, static and energy projections, oracle "
        "Petrov-Galerkin, the residual's parts): OUT/galerkin_gap.json",
    )
    parser.add_argument(
        "--pressure-modes",
        type=positive_int,
        default=None,
        help="reduced pressure modes with --incompressibility hard: the constant "
        "and POD modes of the training pressures (default 4)",
    )


def run(args: argparse.Namespace) -> int:
    config = quick_config(args.level) if args.quick else StudyConfig(level=args.level)
    names = (
        "pod_r",
        "random_training",
        "training_duration",
        "held_out",
        "held_out_seed",
        "error_sources",
        "greedy_pool",
        "greedy_runs",
        "greedy_tol",
        "greedy_seed",
    )
    config = replace(
        config, **{name: getattr(args, name) for name in names if getattr(args, name) is not None}
    )
    if args.points:
        config = replace(config, points=tuple(args.points))
    if args.motions:
        config = replace(config, motions=tuple(args.motions))
    if args.bases:
        config = replace(config, bases=tuple(args.bases))
    config = replace(config, incompressibility=args.incompressibility)
    if args.pressure_modes:
        config = replace(config, pressure_modes=args.pressure_modes)
    comm = MPI.COMM_WORLD
    study = TongueStudy(config, args.out, args.cache, comm=comm)
    done = study.train()
    if comm.rank == 0:
        print(
            f"training: {done['missing']} of {done['runs']} runs computed on "
            f"{done['ranks']} rank(s) in {done['wall_seconds']:.1f} s: "
            f"{args.out / 'training.json'}"
        )
    if args.train_only:
        return 0
    if comm.size > 1:  # the rest on one process: artifem.reduction.distributed
        return continue_alone(args._argv, comm)
    if args.galerkin_gap:
        print(f"Galerkin gap: {study.galerkin_gap()}")
        return 0
    print(f"report: {study.run()}")
    return 0
