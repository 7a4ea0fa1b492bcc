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
    """0.1 s runs (the load's ramp), both configurations against one full run: the reduced
    tissue has the 6 POD vectors and the 11 bone groups' 12 lift columns each. On 100
    random points (the paper's) its mean node error on the held-out 90 kg stays a small
    fraction of the tissue's largest displacement; on 100 trained (ECSW) points, where
    many more friction rows under the sole than reduced coordinates make the bounds' fixed
    point circle (the sliding rows are then held at mu lambda_n of the same solve), the
    run ends and meets the issue's 1 mm."""
    configs = {name: replace(config, level=0, duration=0.1)
               for name, config in fr.CONFIGS.items()}
    results = fr.compare("standing", configs, training_cache, progress=False,
                         mesh_cache=foot_cache)
    paper, trained = results["paper"], results["trained"]
    assert paper["pod_vectors"] == 6 and paper["lift_columns"] == 11 * 12
    assert paper["points"] == 100 and trained["points"] <= 100
    assert paper["training"]["snapshots"] == 3 * 10
    assert paper["max_mean_node_error_mm"] < 0.25 * paper["max_displacement_mm"]
    assert trained["max_mean_node_error_mm"] < 1.0
