"""Every model through the one runner (artifem.models.runner): each ``artifem simulate``
command is a model's card, every model builds at its smallest level and takes a step, and
``--help`` has the same shape for all."""

import argparse
import importlib

import numpy as np
import pytest

from artifem.cli import COMMANDS
from artifem.models import runner
from artifem.scene import Scene

SIMULATE = sorted(path[1] for path in COMMANDS if path[0] == "simulate")


def card(name: str) -> runner.Model:
    return importlib.import_module(COMMANDS[("simulate", name)][0]).MODEL


def test_every_simulate_command_is_a_model_card_run_by_the_runner():
    for name in SIMULATE:
        module = importlib.import_module(COMMANDS[("simulate", name)][0])
        model = module.MODEL
        assert isinstance(model, runner.Model) and model.name == name
        assert model.case in model.cases and model.level in model.levels
        parser = argparse.ArgumentParser()
        module.add_arguments(parser)
        args = parser.parse_args(["--out", "o"])
        assert (args.case, args.level, args.dt, args.duration) == (
            model.case,
            model.level,
            model.dt,
            model.duration,
        )


def test_simulate_help_has_the_same_shape_for_every_model():
    """The runner's group of options, identical for all, then the model's own group."""

    def groups(name):
        parser = argparse.ArgumentParser()
        importlib.import_module(COMMANDS[("simulate", name)][0]).add_arguments(parser)
        return {
            g.title: [a.option_strings[0] for a in g._group_actions]
            for g in parser._action_groups
            if g._group_actions
        }

    shapes = {name: groups(name) for name in SIMULATE}
    for name, shape in shapes.items():
        assert shape["run"] == [
            "--out",
            "--case",
            "--level",
            "--integrator",
            "--dt",
            "--duration",
            "--no-vtx",
            "--no-progress",
        ], name
        assert set(shape) <= {"options", "run", name}, name  # -h, the runner's, the model's


@pytest.mark.parametrize("name", SIMULATE)
def test_every_model_builds_at_its_smallest_level_and_steps(name):
    model = card(name)
    built = runner.build(model, level=min(model.levels))
    scene = built.scene
    assert isinstance(scene, Scene) and scene.bodies
    for f in built.record.values():
        assert np.all(np.isfinite(np.asarray(f(scene), dtype=float)))
    scene.step(model.dt)
    assert np.isfinite(scene.min_det_F) and scene.min_det_F > 0


def test_an_unknown_case_is_refused_before_any_work():
    from artifem.errors import InputError

    with pytest.raises(InputError, match="unknown case 'yawn'"):
        runner.build(card("beam"), "yawn")
