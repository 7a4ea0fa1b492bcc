"""The foot scene (artifem.models.foot.model) at its coarse level: tissue, 11 rigid bone
groups carrying the tissue nodes on their surfaces, the joints as contacts with a
cartilage layer, the tibia on a vertical guide loaded with half the body weight, and the
foot standing on a floor with friction."""

import numpy as np
import pytest

from artifem.models.foot import bones as fb
from artifem.models.foot.model import HALF_WEIGHT, JOINTS, build_foot

G = 9.81


@pytest.fixture(scope="module")
def standing(foot_cache):
    """The foot after the load's ramp (0.1 s) and 0.2 s of settling, 5 ms steps."""
    foot = build_foot(0, cache=foot_cache)
    y0 = foot.bones["tibia"].position[1]
    for _ in range(60):
        foot.scene.step(0.005)
    return foot, y0


def test_the_scene_has_every_bone_group_and_joint(standing):
    foot, _ = standing
    assert list(foot.bones) == list(fb.GROUPS)
    assert {tuple(c.name.removesuffix(" joint").split("-")) for c in foot.joints} == set(JOINTS)
    assert all(b.mass > 0 for b in foot.bones.values())


def test_standing_the_floor_carries_the_load_and_the_weight(standing):
    """At rest, the floor's normal force is the load on the tibia plus the weight of the
    tissue and the bones (the tibia guide is vertical and frictionless)."""
    foot, y0 = standing
    weight = G * (foot.tissue.total_mass() + sum(b.mass for b in foot.bones.values()))
    floor = foot.scene.contact_forces(foot.floor)
    assert floor.normal.sum() == pytest.approx(HALF_WEIGHT + weight, rel=1e-4)
    assert foot.bones["tibia"].position[1] < y0            # the heel pad is compressed
    u = foot.tissue.u.x.array.reshape(-1, 3)
    x = foot.tissue.V.tabulate_dof_coordinates() + u
    assert x[:, 1].min() > foot.floor.offset - foot.floor.tolerance - 1e-12
    assert np.isfinite(u).all()
