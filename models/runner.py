"""The one runner of every model: ``artifem simulate NAME``.

A model module builds scenes and nothing else; it declares what the runner needs in
one :class:`Model`:

    MODEL = Model(
        name="beam", summary="muscle-driven cantilever beam", build=build,
        cases={"curl": "the top muscle ramped to full excitation"},
        levels={0: "12 x 3 x 3 hexahedra", 1: "24 x 6 x 6 hexahedra"},
        dt=0.01, duration=1.0, default_level=1,
    )
    add_arguments, run = command(MODEL)

``build(case, level, integrator, **options)`` returns a :class:`Built`: the Scene with its
inputs installed (excitation schedules, loads) and what to record, render and report.
The runner parses the same options for every model (``--case``, ``--level``,
``--integrator``, ``--dt``, ``--duration``, ``--out``, ``--no-vtx``, ``--no-progress``;
the model's own in a group of their own), builds each case, steps it with
:func:`artifem.scene.simulate` and writes, per case,

    DIR/<case>/<body>.bp     every FEM body's displacement (VTX, ParaView)
    DIR/<case>/<model>.png   the scene at rest, half-way and at the end
    DIR/<case>/simulate.json nodes, steps, ms per step (median), min det F, step halvings,
                             and the model's own figures

(``<case>`` is the run's name instead when the model gives one, e.g. the stem of a
schedule file that replaces the case's input)

and, with ``--case all``, ``DIR/cases.png``: every case at its end, side by side.
Comparisons between variants of a model (full against reduced, 4 against 24 support
nodes, embedding against a conforming mesh) are studies (``artifem study NAME``).
"""

from __future__ import annotations

import argparse
import json
import platform
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path


from artifem.arguments import positive_float
from artifem.errors import InputError
from artifem.scene import INTEGRATORS, Run, Scene

__all__ = ["Built", "Model", "command"]


@dataclass
class Built:
    """A scene built by a model, ready to run, and what the runner does with it.

    Attributes:
        scene: the Scene, its inputs (schedules, loads, controllers) installed.
        record: name -> ``f(scene)``, recorded at the start and after every step.
        figures: ``figures(run) -> dict``: the model's own figures for simulate.json
            (the recorded series are in ``run.records``).
        render: ``render(png, run, shown)`` draws the picture from ``run.snapshots`` at the
            ``shown`` times; None: every FEM body coloured by its displacement.
        facts: what the model says about itself once (alignment, sizes, data source).
        name: what the run is called (its output folder, the progress bar); None: the case
            (a model whose options replace the case's input, e.g. a schedule file, names it).
    """

    scene: Scene
    record: dict[str, Callable] = field(default_factory=dict)
    figures: Callable[[Run], dict] | None = None
    render: Callable[[Path, Run, tuple], object] | None = None
    facts: dict = field(default_factory=dict)
    name: str | None = None


@dataclass(frozen=True)
class Model:
    """What ``artifem simulate NAME`` needs of a model (module docstring).

    ``levels`` are mesh resolutions, smallest first (level ``min(levels)`` is the one the
    test suite builds); ``options`` adds the model's own arguments to its group; the
    runner passes each one to ``build`` by its ``dest``.
    """

    name: str
    summary: str
    build: Callable[..., Built]
    cases: Mapping[str, str]
    levels: Mapping[int, str]
    dt: float
    duration: float
    default_case: str | None = None
    default_level: int | None = None
    integrator: str = "semi-implicit"
    camera: str = "iso"
    options: Callable[[argparse._ArgumentGroup], None] | None = None

    def __post_init__(self):
        if not self.cases or not self.levels:
            raise InputError(f"model {self.name!r}: it needs at least one case and one level")
        if self.integrator not in INTEGRATORS:
            raise InputError(f"model {self.name!r}: unknown integrator {self.integrator!r}")

    @property
    def case(self) -> str:
        return self.default_case or next(iter(self.cases))

    @property
    def level(self) -> int:
        return min(self.levels) if self.default_level is None else self.default_level

    def option_names(self) -> list[str]:
        """The ``dest`` of each of the model's own options."""
        if self.options is None:
            return []
        group = argparse.ArgumentParser(add_help=False).add_argument_group()
        self.options(group)
        return [action.dest for action in group._group_actions]


def add_model_arguments(parser: argparse.ArgumentParser, model: Model) -> None:
    """The runner's options (the same for every model), then the model's own."""
    run = parser.add_argument_group("run")
    run.add_argument("--out", required=True, type=Path, help="output directory")
    run.add_argument(
        "--case",
        default=model.case,
        choices=list(model.cases) + (["all"] if len(model.cases) > 1 else []),
        help="; ".join(f"{k}: {v}" for k, v in model.cases.items())
        + (" (default: %(default)s)" if len(model.cases) > 1 else ""),
    )
    run.add_argument(
        "--level",
        type=int,
        default=model.level,
        choices=sorted(model.levels),
        help="mesh level: "
        + "; ".join(f"{k}: {v}" for k, v in sorted(model.levels.items()))
        + " (default: %(default)s)",
    )
    run.add_argument(
        "--integrator",
        default=model.integrator,
        choices=sorted(INTEGRATORS),
        help="default: %(default)s",
    )
    run.add_argument("--dt", type=positive_float, default=model.dt, help="s (%(default)s)")
    run.add_argument(
        "--duration", type=positive_float, default=model.duration, help="s (%(default)s)"
    )
    run.add_argument("--no-vtx", action="store_true", help="write no ParaView series")
    run.add_argument("--no-progress", action="store_true", help="show no progress bar")
    if model.options is not None:
        model.options(parser.add_argument_group(f"{model.name}"))


def build(model: Model, case: str | None = None, level: int | None = None, **options) -> Built:
    """``model``'s scene for ``case`` at ``level`` (the defaults when None): what the
    runner runs, and what the test suite builds at the smallest level."""
    case = model.case if case is None else case
    if case not in model.cases:
        raise InputError(f"model {model.name!r}: unknown case {case!r}; it has {list(model.cases)}")
    level = model.level if level is None else level
    options.setdefault("integrator", model.integrator)
    return model.build(case=case, level=level, **options)


def run_model(model: Model, args: argparse.Namespace) -> int:
    """Build, run, render and report each case of ``args`` (module docstring)."""
    from artifem.render import render_bodies
    from artifem.scene import simulate

    cases = list(model.cases) if args.case == "all" else [args.case]
    options = {name: getattr(args, name) for name in model.option_names()}
    shown = (0.0, 0.5 * args.duration, args.duration)
    final = {}
    for case in cases:
        built = build(model, case, args.level, integrator=args.integrator, **options)
        name = built.name or case
        out = Path(args.out) / name
        scene = built.scene
        if scene.comm.rank == 0:
            out.mkdir(parents=True, exist_ok=True)
        run = simulate(
            scene,
            args.duration,
            args.dt,
            record=built.record,
            keep=shown,
            vtx=None if args.no_vtx else out,
            progress=not args.no_progress,
            label=f"{model.name} {name}",
        )
        png = out / f"{model.name}.png"
        if built.render is not None:
            built.render(png, run, shown)
        else:
            _render_fem_bodies(png, scene, run, shown, model.camera)
        final[name] = (scene, run.snapshots[shown[-1]])
        figures = _figures(model, case, args, scene, run)
        figures.update(built.facts)
        if built.figures is not None:
            figures.update(built.figures(run))
        if scene.comm.rank == 0:
            (out / "simulate.json").write_text(json.dumps(figures, indent=2))
            print(
                f"{model.name} {name} (level {args.level}, {figures['nodes']} nodes): "
                f"{figures['steps']} steps, {figures['ms_per_step']:.1f} ms/step, min det F "
                f"{figures['min_det_F']:.3f}, {figures['halvings']} halvings; results in {out}/",
                flush=True,
            )
    if len(final) > 1:
        bodies = [
            (body.mesh, snapshot[body.name])
            for scene, snapshot in final.values()
            for body in scene.fem_bodies
        ]
        names = [case for case, (scene, _) in final.items() for _ in scene.fem_bodies]
        render_bodies(
            Path(args.out) / "cases.png",
            bodies,
            scalars="displacement",
            scalar_name="displacement (m)",
            titles=names,
            camera=model.camera,
            window_size=(500 * len(bodies), 500),
        )
    return 0


def command(model: Model):
    """``(add_arguments, run)`` of ``artifem simulate NAME`` for ``model`` (the CLI's
    interface of a command module)."""

    def add_arguments(parser: argparse.ArgumentParser) -> None:
        add_model_arguments(parser, model)

    def run(args: argparse.Namespace) -> int:
        return run_model(model, args)

    return add_arguments, run


def _render_fem_bodies(png: Path, scene: Scene, run: Run, shown: tuple, camera: str) -> None:
    """Every FEM body at each ``shown`` time, side by side, coloured by its displacement."""
    from artifem.render import render_bodies

    panels = [
        ((body.mesh, run.snapshots[t][body.name]), f"{body.name}, t = {t:g} s")
        for t in shown
        if t in run.snapshots
        for body in scene.fem_bodies
    ]
    if panels:
        render_bodies(
            png,
            [body for body, _ in panels],
            scalars="displacement",
            scalar_name="displacement (m)",
            titles=[title for _, title in panels],
            camera=camera,
            show_rest=True,
            window_size=(600 * len(panels), 600),
        )


def _figures(model: Model, case: str, args, scene: Scene, run: Run) -> dict:
    fem = scene.fem_bodies
    return {
        "model": model.name,
        "case": case,
        "level": args.level,
        "nodes": int(sum(b.mesh.geometry.index_map().size_global for b in fem)),
        "elements": int(sum(b.mesh.topology.index_map(3).size_global for b in fem)),
        "reduced_coordinates": int(sum(b.r for b in scene.reduced_bodies)),
        "rigid_bodies": len(scene.rigid_bodies),
        "ranks": scene.comm.size,
        "integrator": args.integrator,
        "dt": args.dt,
        "duration": args.duration,
        "steps": int(run.step_ms.size),
        "ms_per_step": run.ms_per_step,
        "min_det_F": run.min_det_F,
        "halvings": run.halvings,
        "fallbacks": run.fallbacks,
        "machine": platform.processor() or platform.machine(),
        "units": {"ms_per_step": "median wall ms"},
    }
