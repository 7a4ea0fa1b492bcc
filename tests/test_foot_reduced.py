"""The reduced foot (artifem.models.foot.reduced) at the coarse level: the paper's
configuration (6 POD vectors, 100 random points) trained on three body weights, run
against the full foot on the held-out weight, bones, ligaments and contacts included."""

from dataclasses import replace

import numpy as np
import pytest

from artifem.models.foot import reduced as fr
from artifem.models.foot.model import foot_case
from artifem.models.foot.render import plot_reduced_comparison
from artifem.errors import UnknownNameError
from artifem.scene.inputs import LoadLevel
from outputs import assert_picture


def test_the_load_level_scales_the_tibia_load(foot_cache):
    foot = foot_case("standing", 0, cache=foot_cache)
    LoadLevel("tibia load").apply(foot.scene, 0.5)
    ((_, wrench),) = foot.load.master_loads(1.0)
    assert wrench[1] == pytest.approx(-0.5 * foot.load.force)
    with pytest.raises(UnknownNameError, match="0 load elements"):
        LoadLevel("no such load").check(foot.scene)


@pytest.fixture(scope="module")
def training_cache(tmp_path_factory):
    """The reduced foot's training runs, shared by this module's tests."""
    return tmp_path_factory.mktemp("foot_reduced")


def test_reduced_standing_foot_follows_the_full_one_on_a_held_out_weight(
    foot_cache, training_cache, tmp_path
):
    """0.1 s runs (the load's ramp), both configurations against one full run: the reduced
    tissue has the 6 POD vectors and the 11 bone groups' 12 lift columns each. On 100
    random points (the paper's) its largest mean node error on the held-out 90 kg is
    1.88 mm of the tissue's 20.0 mm (measured, the same on every machine tried; asserted
    within 1.25 x, the issue-32 margin: docs/foot/reduced_configs_level0.json is for the
    script's longer run); on 100 trained (ECSW) points, where many more friction rows under
    the sole than reduced coordinates make the bounds' fixed point circle (the sliding rows
    are then held at mu lambda_n of the same solve), it turns on round-off: 0.29, 0.33
    and 0.37 mm on three machines or BLAS kernels, asserted within 1.25 x the largest,
    inside the issue's 1 mm. The per-step error and ms are the figures' series, and they
    plot."""
    configs = {name: replace(config, level=0, duration=0.1) for name, config in fr.CONFIGS.items()}
    results = fr.compare("standing", configs, training_cache, progress=False, mesh_cache=foot_cache)
    paper, trained = results["paper"], results["trained"]
    assert paper["pod_vectors"] == 6 and paper["lift_columns"] == 11 * 12
    assert paper["points"] == 100 and trained["points"] <= 100
    assert paper["training"]["snapshots"] == 3 * 10
    assert paper["max_displacement_mm"] == pytest.approx(20.01979011073167, rel=1e-6)  # full
    assert paper["max_mean_node_error_mm"] < 1.25 * 1.8786986785914968
    assert trained["max_mean_node_error_mm"] < 1.25 * 0.36959971065735525
    steps = round(0.1 / paper["config"]["dt"])
    for r in (paper, trained):  # the per-step series the figures summarize
        assert len(r["mean_node_error_mm"]) == len(r["reduced_ms"]) == len(r["full_ms"]) == steps
        assert max(r["mean_node_error_mm"]) == pytest.approx(r["max_mean_node_error_mm"], abs=1e-4)
        assert np.median(r["reduced_ms"]) == pytest.approx(r["reduced_ms_per_step"], abs=0.05)
        assert np.mean(r["full_ms"]) == pytest.approx(r["full_ms_mean"], abs=0.05)
    png = plot_reduced_comparison(tmp_path / "reduced.png", results, paper["config"]["dt"], "test")
    assert_picture(png)
