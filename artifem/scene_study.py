"""The train/test study of any scene's reduced model.

    artifem study scene MODULE:FUNCTION --out DIR [--training-runs 10] [--each-alone LEVEL]
                        [--r 20] [--points 300] [--held-out 5] [--held-out-seed 1000] ...
    mpiexec -n N artifem study scene MODULE:FUNCTION --out DIR ...

``FUNCTION()`` (importable from ``MODULE``) returns the model: a
:class:`~artifem.reduction.reductor.ReducibleScene` (how to build the full scene, which FEM
body to reduce, its exciters, load inputs and motions). E.g.
``artifem.models.styloglossus.model:reducible``, ``artifem.models.jaw_tongue.reduced:reducible``,
or a function of the user's own module on the Python path.

1. Training (cached in ``--cache``, default DIR/cache; resumable): ``--training-runs`` random
   schedules over every input of the model, exciters and loads
   (:func:`~artifem.reduction.schedules.random_schedules`, seed ``--training-seed``), plus,
   with ``--each-alone LEVEL``, each input alone ramped to LEVEL over 0.5 s (the seed
   paper's design). Under ``mpiexec -n N`` the runs are shared over the N ranks
   (:mod:`artifem.reduction.distributed`), then rank 0 runs the rest of the study in a
   fresh serial process, from the cache (``--train-only``: stop after the training).
   DIR/training.json says what the training did.
2. The train/test split (:func:`~artifem.reduction.generalization.generalization_study`):
   the reduced model (``--basis``, ``--r``, ``--points``, ``--sampling``) on the training
   schedules, the model's motions and ``--held-out`` random schedules of a seed the
   training never saw, each against the full model, the hierarchical estimate beside the
   error: DIR/generalization.json, .md, .png and generalization_worst.png (a render of the
   worst held-out moment); with ``--error-sources``, where the error comes from (the basis'
   best approximation, the reduced model with every point).

With ``--point-pool N`` the trained points are first enriched greedily, with no full run
(:func:`~artifem.reduction.enrichment.greedy_points`): N random schedules of seed
``--point-seed`` (neither the training's nor the held-out seed), at most ``--point-rounds``
rounds, each adding the states the worst candidate's reduced run visits to the points'
training, until the cubature residual there is at most ``--point-tol``: DIR/points.json.
"""

from __future__ import annotations

import argparse
import importlib
import json
import time
from pathlib import Path

from mpi4py import MPI

from artifem.arguments import (
    fraction,
    nonnegative_float,
    nonnegative_int,
    positive_float,
    positive_int,
)
from artifem.errors import InputError
from artifem.reduction.distributed import continue_alone, record_training
from artifem.reduction.enrichment import greedy_points
from artifem.reduction.generalization import generalization_study
from artifem.reduction.reductor import BASES, Basis, Points, ReducibleScene, Reductor, Training
from artifem.reduction.schedules import each_alone, random_schedules

__all__ = ["load_model", "study_training", "add_arguments", "run"]

#: s, the ramp of the each-alone training schedules (the seed paper's 0.5 s)
RAMP = 0.5


def load_model(spec: str) -> ReducibleScene:
    """The model ``MODULE:FUNCTION()`` returns (a clear error naming the spec otherwise)."""
    module, sep, name = spec.partition(":")
    if not sep or not module or not name:
        raise InputError(f"study scene: give the model as MODULE:FUNCTION, got {spec!r}")
    try:
        factory = getattr(importlib.import_module(module), name)
    except ImportError as exc:
        raise InputError(f"study scene: cannot import {module!r} ({exc})") from None
    except AttributeError:
        raise InputError(f"study scene: module {module!r} has no {name!r}") from None
    model = factory()
    if not isinstance(model, ReducibleScene):
        raise InputError(
            f"study scene: {spec}() returned a {type(model).__name__}, not a "
            "ReducibleScene (artifem.reduction.reductor)"
        )
    return model


def study_training(
    model: ReducibleScene,
    *,
    runs: int,
    seed: int,
    each_alone_level: float,
    duration: float,
    dt: float,
    snapshot_every: int,
) -> Training:
    """``runs`` random schedules of ``seed`` over the model's inputs, plus each input alone
    at ``each_alone_level`` (0: none)."""
    names = model.input_names(model.fem_body(model.build()))
    if not names:
        raise InputError(
            f"study scene: model {model.name!r} has no inputs (exciters or loads) to train on"
        )
    schedules = dict(random_schedules(names, runs, seed=seed, duration=duration)) if runs else {}
    if each_alone_level:
        schedules.update(each_alone(names, each_alone_level, RAMP))
    if not schedules:
        raise InputError(
            "study scene: no training runs: give --training-runs N or --each-alone LEVEL"
        )
    return Training(schedules, duration, dt, snapshot_every)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "model",
        metavar="MODULE:FUNCTION",
        help="a function returning the ReducibleScene to study, e.g. "
        "artifem.models.styloglossus.model:reducible",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument(
        "--cache", type=Path, default=None, help="training cache directory (default OUT/cache)"
    )
    parser.add_argument(
        "--training-runs",
        type=nonnegative_int,
        default=10,
        help="random training schedules over every input (default 10)",
    )
    parser.add_argument("--training-seed", type=int, default=0)
    parser.add_argument(
        "--each-alone",
        type=fraction,
        default=None,
        metavar="LEVEL",
        help="also train on each input alone ramped to LEVEL over 0.5 s",
    )
    parser.add_argument(
        "--duration",
        type=positive_float,
        default=1.0,
        help="seconds of every run, training and test (default 1)",
    )
    parser.add_argument("--dt", type=positive_float, default=0.01)
    parser.add_argument("--snapshot-every", type=positive_int, default=5)
    parser.add_argument("--basis", choices=BASES, default="pod")
    parser.add_argument("--r", type=positive_int, default=20, help="basis size")
    parser.add_argument("--points", type=positive_int, default=300, help="integration points")
    parser.add_argument("--sampling", choices=("trained", "random", "all"), default="trained")
    parser.add_argument(
        "--held-out", type=nonnegative_int, default=5, help="held-out random schedules (default 5)"
    )
    parser.add_argument(
        "--held-out-seed",
        type=int,
        default=1000,
        help="their seed (must differ from --training-seed)",
    )
    parser.add_argument(
        "--error-sources",
        action="store_true",
        help="also report where the error comes from: the full runs' "
        "projection on the basis and the reduced model with every "
        "integration point (one O(n)-per-step run each)",
    )
    parser.add_argument(
        "--point-pool",
        type=nonnegative_int,
        default=0,
        help="enrich the trained points greedily over N random schedules "
        "(no full run; default 0: no enrichment)",
    )
    parser.add_argument(
        "--point-rounds",
        type=nonnegative_int,
        default=3,
        help="rounds of the points' enrichment (default 3)",
    )
    parser.add_argument(
        "--point-tol",
        type=nonnegative_float,
        default=0.0,
        help="stop when the cubature residual on every pool run is at most "
        "this (default 0: the rounds)",
    )
    parser.add_argument(
        "--point-seed",
        type=int,
        default=2000,
        help="seed of the enrichment's pool (must differ from the training and held-out seeds)",
    )
    parser.add_argument(
        "--train-only",
        action="store_true",
        help="run the training (shared over the ranks under mpiexec), write "
        "OUT/training.json and stop",
    )


def run(args: argparse.Namespace) -> int:
    comm = MPI.COMM_WORLD
    if args.held_out and args.held_out_seed == args.training_seed and args.training_runs:
        raise InputError(
            f"--held-out-seed {args.held_out_seed} is the training's seed: the "
            "held-out schedules would be training schedules"
        )
    if args.point_pool:
        if args.sampling != "trained":
            raise InputError(
                f"--point-pool enriches trained points; --sampling is {args.sampling!r}"
            )
        used = {
            "--training-seed": args.training_seed if args.training_runs else None,
            "--held-out-seed": args.held_out_seed if args.held_out else None,
        }
        for flag, seed in used.items():
            if seed == args.point_seed:
                raise InputError(
                    f"--point-seed {args.point_seed} is also {flag}: the pool "
                    "would hold schedules of that set"
                )
    model = load_model(args.model)
    training = study_training(
        model,
        runs=args.training_runs,
        seed=args.training_seed,
        each_alone_level=args.each_alone or 0.0,
        duration=args.duration,
        dt=args.dt,
        snapshot_every=args.snapshot_every,
    )
    out = Path(args.out)
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    reductor = Reductor(model, training, args.cache or out / "cache", comm=comm)
    done = reductor.train()
    if comm.size > 1:  # the rest on one process: artifem.reduction.distributed
        if comm.rank == 0:
            _record(out, done, args)
        return 0 if args.train_only else continue_alone(args._argv, comm)
    _record(out, done, args)
    if args.train_only:
        return 0
    basis, points = Basis(args.basis, args.r), Points(args.points, args.sampling)
    extra = _enrich_points(reductor, model, basis, points, args, out) if args.point_pool else None
    generalization_study(
        reductor,
        out,
        basis=basis,
        points=points,
        held_out=args.held_out,
        seed=args.held_out_seed,
        duration=args.duration,
        dt=args.dt,
        extra_states=extra,
        sources=args.error_sources,
    )
    print(f"report: {out / 'generalization.md'}")
    return 0


def _enrich_points(
    reductor: Reductor,
    model: ReducibleScene,
    basis: Basis,
    points: Points,
    args: argparse.Namespace,
    out: Path,
):
    """The greedy enrichment of the points (module docstring): OUT/points.json; returns the
    states it added."""
    pool = random_schedules(
        model.input_names(reductor.body),
        args.point_pool,
        seed=args.point_seed,
        duration=args.duration,
        prefix="points",
    )
    tic = time.perf_counter()
    result = greedy_points(
        reductor,
        pool,
        basis=basis,
        points=points,
        tol=args.point_tol,
        max_rounds=args.point_rounds,
        duration=args.duration,
    )
    summary = {
        **result.summary(),
        "pool": args.point_pool,
        "seed": args.point_seed,
        "tol": args.point_tol,
        "wall_seconds": time.perf_counter() - tic,
    }
    (out / "points.json").write_text(json.dumps(summary, indent=1))
    print(
        f"points: {summary['stopped']} after {summary['rounds']} round(s), "
        f"{summary['extra_states']} states added, largest residual "
        f"{result.history[0]['max_indicator']:.3g} -> "
        f"{min(e['max_indicator'] for e in result.history):.3g}"
    )
    return result.states


def _record(out: Path, done: dict, args: argparse.Namespace) -> None:
    """OUT/training.json (:func:`~artifem.reduction.distributed.record_training`)."""
    done.update(
        model=args.model,
        runs=done["jobs"],
        training_seed=args.training_seed,
        each_alone=args.each_alone,
        duration=args.duration,
        dt=args.dt,
        snapshot_every=args.snapshot_every,
    )
    record = record_training(
        out / "training.json",
        done,
        ("model", "runs", "training_seed", "each_alone", "duration", "dt", "snapshot_every"),
    )
    print(
        f"training: {done['missing']} of {done['runs']} runs computed on {done['ranks']} "
        f"rank(s) in {done['wall_seconds']:.1f} s; the record of the training: {record}"
    )
