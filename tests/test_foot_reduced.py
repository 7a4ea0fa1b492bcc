"""The reduced foot (artifem.models.foot.reduced) at the coarse level: the paper's
configuration (6 POD vectors, 100 random points) trained on three body weights, run
against the full foot on the held-out weight, bones, ligaments and contacts included."""

from dataclasses import replace

import numpy as np
import pytest

from artifem.models.foot import reduced as fr
from artifem.models.foot.model import foot_case
from artifem.errors import UnknownNameError
from artifem.scene.inputs import LoadLevel


def test_the_load_level_scales_the_tibia_load(foot_cache):
    foot = foot_case("standing", 0, cache=foot_cache)
    LoadLevel("tibia load").apply(foot.scene, 0.5)
    (_, wrench), = foot.load.master_loads(1.0)
    assert wrench[1] == pytest.approx(-0.5 * foot.load.force)
    with pytest.raises(UnknownNameError, match="0 load elements"):
        LoadLevel("no such load").check(foot.scene)


@pytest.fixture(scope="module")
def training_cache(tmp_path_factory):
    """The reduced foot's training runs, shared by this module's tests."""
    return tmp_path_factory.mktemp("foot_reduced")


def test_reduced_standing_foot_follows_the_full_one_on_a_held_out_weight(foot_cache,
                                                                         training_cache):
    """0.1 s runs (the load's ramp): the reduced tissue has the 6 POD vectors and the 11
    bone groups' 12 lift columns each; on the held-out 90 kg its mean node error stays a
    small fraction of the tissue's largest displacement."""
    config = replace(fr.PAPER, level=0, duration=0.1)
    result = fr.compare("standing", config, training_cache, progress=False,
                        mesh_cache=foot_cache)
    assert result["pod_vectors"] == 6 and result["lift_columns"] == 11 * 12
    assert result["points"] == 100
    assert result["training"]["snapshots"] == 3 * 10
    assert np.isfinite(result["max_mean_node_error_mm"])
    assert result["max_mean_node_error_mm"] < 0.25 * result["max_displacement_mm"]


def test_trained_points_run_under_the_soles_friction(foot_cache, training_cache):
    """6 POD vectors on 100 trained (ECSW) points: many more friction rows under the sole
    than reduced coordinates, whose bounds' fixed point circles a change of the active set
    (the sliding rows are then held at mu lambda_n of the same solve); the run ends and
    follows the full foot."""
    config = replace(fr.PAPER, level=0, duration=0.1, sampling="trained")
    result = fr.compare("standing", config, training_cache, progress=False,
                        mesh_cache=foot_cache)
    assert result["points"] <= 100
    assert result["max_mean_node_error_mm"] < 0.25 * result["max_displacement_mm"]
