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
def test_every_model_builds_at_its_smallest_level_and_replays_from_its_saved_state(name):
    """Each model moves from a saved state, and restoring that state replays the same
    steps (the state is complete: bodies, muscles, joints, time): every body's state and
    every recorded series agree to the iterative solvers' tolerance, not bitwise (a warm
    start is not part of the state)."""
    model = card(name)
    built = runner.build(model, level=min(model.levels))
    scene = built.scene
    assert isinstance(scene, Scene) and scene.bodies

    def snapshot():
        states = {
            f"{body.name} state {k}": np.asarray(a, dtype=float).ravel()
            for body in scene.bodies
            for k, a in enumerate(body.state())
        }
        return states | {k: np.asarray(f(scene), dtype=float) for k, f in built.record.items()}

    scene.step(model.dt)
    saved, t, start = scene.save_state(), scene.t, snapshot()
    first = []
    for _ in range(2):
        scene.step(model.dt)
        first.append(snapshot())
    assert np.isfinite(scene.min_det_F) and scene.min_det_F > 0
    assert any(not np.array_equal(first[-1][k], start[k]) for k in start), "nothing moved"
    scene.restore_state(saved)
    assert scene.t == t
    for expected in first:
        scene.step(model.dt)
        got = snapshot()
        for key, value in expected.items():
            assert np.all(np.isfinite(value)), (name, key)
            scale = max(float(np.max(np.abs(value), initial=0.0)), 1e-12)
            np.testing.assert_allclose(got[key], value, rtol=0, atol=1e-6 * scale, err_msg=key)


def test_an_unknown_case_is_refused_before_any_work():
    from artifem.errors import InputError

    with pytest.raises(InputError, match="unknown case 'yawn'"):
        runner.build(card("beam"), "yawn")
