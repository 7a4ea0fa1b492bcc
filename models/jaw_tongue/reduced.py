"""The jaw-tongue's reduced tongue: the scene as the reductor sees it, its training and its
basis (u = U q + L g, the jaw's lift columns L; :mod:`artifem.models.jaw_tongue.study` has
the comparison with the full scene).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

from mpi4py import MPI

from artifem.models.jaw_tongue import model as jt
from artifem.models.tongue.model import MOTIONS, RAMP_TIME, Tongue, load_tongue_data
from artifem.reduction.reductor import (
    Basis,
    Points,
    ReducedModel,
    ReducibleScene,
    Training,
    reduce,
)
from artifem.reduction.schedules import each_alone
from artifem.scene.inputs import PathExcitation

__all__ = [
    "ReducedJawTongueConfig",
    "build_reduced_scene",
    "quick_config",
    "reducible",
    "train",
]


@dataclass(frozen=True)
class ReducedJawTongueConfig:
    r: int = 20  # POD vectors (plus the 12 lift columns)
    points: int = 300  # trained integration points
    training_excitation: float = 0.6
    training_duration: float = 0.6
    snapshot_every: int = 2
    force_snapshots: int = 150
    cubature_tol: float = 1e-3
    dt: float = 0.01
    jaw: jt.JawTongueConfig = field(default_factory=jt.JawTongueConfig)


def quick_config() -> ReducedJawTongueConfig:
    """A small training for tests and smoke runs (``--quick``): 0.15 s training runs
    (every step a snapshot), r = 12 POD vectors, 150 trained points."""
    return ReducedJawTongueConfig(
        r=12, points=150, training_duration=0.15, snapshot_every=1, force_snapshots=60
    )


def reducible(config: ReducedJawTongueConfig = ReducedJawTongueConfig()) -> ReducibleScene:
    """The jaw-tongue scene as the reductor sees it: its tongue reduced, driven by the
    tongue's exciters and by the jaw opener's excitation, a load input (``opener``: the
    jaw's motion as a load case; a schedule that does not name it leaves the opener on its
    own ramp); each build a serial scene (``MPI.COMM_SELF``), so that training runs may be
    shared over ranks."""
    exciters = load_tongue_data(config.jaw.tongue.level).exciters
    loads = {"opener": PathExcitation("opener")} if config.jaw.opener_force > 0 else {}
    return ReducibleScene(
        "jaw-tongue",
        lambda: jt.build_scene(config.jaw, comm=MPI.COMM_SELF).scene,
        "tongue",
        {"jaw": asdict(config.jaw), "dt": config.dt},
        exciters=exciters,
        motions={m: Tongue.motion(m) for m in MOTIONS},
        loads=loads,
    )


def training(config: ReducedJawTongueConfig) -> Training:
    """Each exciter alone, ramped to ``training_excitation`` over the paper's 0.5 s."""
    exciters = sorted(load_tongue_data(config.jaw.tongue.level).exciters)
    return Training(
        each_alone(exciters, config.training_excitation, RAMP_TIME),
        config.training_duration,
        config.dt,
        config.snapshot_every,
    )


def specification(config: ReducedJawTongueConfig) -> tuple[Basis, Points]:
    """The reduced tongue's basis (POD, the jaw's lift columns added) and trained points."""
    return Basis("pod", config.r), Points(
        config.points, tol=config.cubature_tol, growth=0.0, training_states=config.force_snapshots
    )


def train(config: ReducedJawTongueConfig, cache: Path) -> ReducedModel:
    """The reduced tongue (module docstring) from :func:`artifem.reduction.reductor.reduce`,
    cached under ``cache``."""
    basis, points = specification(config)
    return reduce(reducible(config), training(config), basis=basis, points=points, cache=cache)


def build_reduced_scene(model: ReducedModel, config: ReducedJawTongueConfig) -> jt.JawTongueScene:
    return jt.build_scene(config.jaw, reduce=model)
