"""The foot scene (artifem.models.foot.model) at its coarse level: tissue, 11 rigid bone
groups carrying the tissue nodes on their surfaces, the joints as contacts with a
cartilage layer, ligaments, the tibialis anterior and the soleus; standing (the tibia on a
vertical guide loaded with half the body weight, the foot on a floor with friction) and
lift (the tibia fixed, the tibialis anterior lifting the hanging forefoot)."""

import numpy as np
import pytest

from scipy.spatial.transform import Rotation

from artifem.models.foot import bones as fb
from artifem.models.foot import ligaments as fl
from artifem.models.foot.model import HALF_WEIGHT, JOINTS, TibiaLoad, build_foot, foot_case
from artifem.multibody.rigid_body import RigidBody
from outputs import assert_picture

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
    names = [p.name for p in foot.ligaments]
    assert names[: len(fl.NAMED)] == list(fl.NAMED)
    assert len(names) == len(fl.NAMED) + 4 * (len(JOINTS) - 1)  # capsules but the ankle
    assert {m: len(p) for m, p in foot.muscles.items()} == {"tibialis anterior": 2, "soleus": 1}


def test_ligaments_are_taut_at_rest_and_pull_only(foot_cache):
    """Built in the neutral pose every ligament carries no force (round-off of its
    attachments' frames); it pulls when stretched and goes slack when shortened."""
    foot = build_foot(0, load=0.0, floor=False, cache=foot_cache)
    for path in foot.ligaments:
        r = path.evaluate(0.0)
        assert abs(r.tension) < 1e-9 and r.length == pytest.approx(path.element.rest_length)
        assert path.element.tension(1.1 * r.length)[0] > 0
        assert path.element.tension(0.9 * r.length)[0] == 0.0


def test_standing_the_floor_carries_the_load_and_the_weight(standing):
    """At rest, the floor's normal force is the load on the tibia plus the weight of the
    tissue and the bones (the tibia guide is vertical and frictionless). The heel pad is
    compressed by the measured amount, the joints' cartilage by the measured depth, and no
    sole node is below the floor (measured: exactly on it; the step itself allows the
    floor's tolerance, 0.1 mm, and the cartilage's thickness, 1 mm)."""
    foot, y0 = standing
    weight = G * (foot.tissue.total_mass() + sum(b.mass for b in foot.bones.values()))
    floor = foot.scene.contact_forces(foot.floor)
    assert floor.normal.sum() == pytest.approx(HALF_WEIGHT + weight, rel=1e-6)
    # deterministic, measured (two runs, same digits), rel 1e-6: the tibia's drop and the
    # deepest vertex in any joint's cartilage (metatarsals 2-5 on the toes)
    assert y0 - foot.bones["tibia"].position[1] == pytest.approx(0.017484421454536547, rel=1e-6)
    deepest = min(c._pairs().deepest[0] for c in foot.joints)
    assert deepest == pytest.approx(-0.00032220529322484967, rel=1e-6)
    u = foot.tissue.u.x.array.reshape(-1, 3)
    x = foot.tissue.V.tabulate_dof_coordinates() + u
    assert x[:, 1].min() >= foot.floor.offset - 1e-12  # measured 0.0 below the floor


def test_the_tibia_loads_potential_is_minus_its_work():
    """d(potential)/dp = -f at every time of the ramp (statics' energy merit)."""
    tibia = RigidBody("tibia", 0.1, np.eye(3) * 1e-4, position=(0.0, 0.3, 0.0))
    load = TibiaLoad(tibia, HALF_WEIGHT, ramp=0.1)
    for t in (0.0, 0.05, 0.2):
        e0 = load.potential_energy(t)
        tibia.position = tibia.position + np.array([0.0, 1e-3, 0.0])
        ((_, wrench),) = load.master_loads(t)
        assert load.potential_energy(t) - e0 == pytest.approx(-wrench[1] * 1e-3, abs=1e-12)


def test_the_foot_stands_on_the_floor_by_the_static_solve(foot_cache):
    """Scene.solve_static finds the unloaded foot's rest on the floor under its own weight
    (it failed before its active sets started from the last Newton iteration's, its merit
    counted the joints' cartilage springs and the sliding friction, and the muscles had an
    energy): the floor carries the weight of the tissue and the bones, nothing passes
    through the floor or a joint. Newton's tail is superlinear: each merit above round-off
    falls by more than 100x once within 1e-4 of the largest (the joints' contact rows turn
    under their forces in the tangent, MeshContactRows.stiffness; without it the merit fell
    by a constant 0.08 per iteration)."""
    foot = build_foot(0, load=0.0, cache=foot_cache)
    counts = foot.scene.solve_static()
    assert len(counts) == 1 and counts.failed == 0
    merit = np.array(counts.residuals[0])
    tail = [(a, b) for a, b in zip(merit, merit[1:]) if 1e-9 * merit.max() < a < 1e-4 * merit.max()]
    assert len(tail) >= 2 and all(b < 1e-2 * a for a, b in tail), merit
    weight = G * (foot.tissue.total_mass() + sum(b.mass for b in foot.bones.values()))
    floor = foot.scene.contact_forces(foot.floor)
    assert floor.normal.sum() == pytest.approx(weight, rel=1e-6)
    # the joints' cartilage rows are not in the statics' gap: this is a check of the solve
    assert all(c.constraint_failure() is None for c in foot.joints)
    u = foot.tissue.u.x.array.reshape(-1, 3)
    x = foot.tissue.V.tabulate_dof_coordinates() + u
    # the floor's rows are: converged to 1e-10 of the loads, about 1e-10 m (measured 0.0),
    # where the floor's own tolerance would allow 0.1 mm
    assert x[:, 1].min() > foot.floor.offset - 1e-9


def test_the_loaded_foot_stands_by_the_static_solve_with_adaptive_load_steps(foot_cache):
    """Half the body weight on the tibia, solved with ``load_steps="auto"``: it failed
    before (12 cuts at a load factor of 0.60, the merit circling 22, 37, 22, ... in
    every smaller increment: a vertex of the talus pressed through the cartilage went
    from one triangle of the tibia to its neighbour and back); the contacts now hold
    their pairs once two of Newton's steps raise the merit or hardly lower it
    (MeshContact.hold_pairs), and friction sticks to where each increment found it
    (IncrementSlip). The floor carries
    the weight and the load, and nothing passes through the floor or a joint."""
    foot = build_foot(0, load=HALF_WEIGHT, ramp=0.0, cache=foot_cache)
    counts = foot.scene.solve_static(load_steps="auto")
    assert max(counts) <= 10  # auto's cap on the increments that converged
    weight = G * (foot.tissue.total_mass() + sum(b.mass for b in foot.bones.values()))
    floor = foot.scene.contact_forces(foot.floor)
    assert floor.normal.sum() == pytest.approx(weight + HALF_WEIGHT, rel=1e-6)
    assert all(c.constraint_failure() is None for c in foot.joints)


def test_the_tibialis_anterior_lifts_the_hanging_forefoot(foot_cache):
    """The lift case (the seed paper's Fig. 7): the tibia fixed, the foot hanging, the
    tibialis anterior excited to 0.3 in 0.1 s. After 0.3 s the forefoot has risen 42.5 mm
    and the talus has turned 12.5 degrees in dorsiflexion (about +z), held by the soleus's
    passive force (79.6 N) and the posterior ligaments: the level-0 values, measured (two
    runs, same digits), rel 1e-6. (docs/foot/lift/foot.json is level 1.) The joints'
    cartilage depth is the step's own health check."""
    foot = foot_case("lift", 0, cache=foot_cache)
    m1 = foot.bones["metatarsal1"].position.copy()
    for _ in range(60):
        foot.scene.step(0.005)
    rise = foot.bones["metatarsal1"].position[1] - m1[1]
    turn = np.degrees(Rotation.from_matrix(foot.bones["talus"].rotation).as_rotvec())
    assert rise == pytest.approx(0.04252409480116398, rel=1e-6)
    assert turn[2] == pytest.approx(12.537698081805754, rel=1e-6)
    soleus = foot.muscles["soleus"][0].evaluate(foot.scene.t).tension
    assert soleus == pytest.approx(79.60087987885903, rel=1e-6)


def test_simulate_foot_and_study_foot_agree_on_the_standing_figures(tmp_path, standing):
    """``artifem simulate foot`` (the runner) and ``artifem study foot`` (timed against the
    foot's parts) run the same standing case: the same steps give the same figures, and the
    floor carries the load ramped so far plus the weight, less the momentum still
    changing."""
    import json

    from artifem.cli import main

    common = ["--level", "0", "--duration", "0.02", "--no-progress", "--no-vtx"]
    assert main(["simulate", "foot", "--out", str(tmp_path / "run"), *common]) == 0
    assert (
        main(["study", "foot", "--out", str(tmp_path / "study"), "--timing-steps", "1", *common])
        == 0
    )
    run = json.loads((tmp_path / "run" / "standing" / "simulate.json").read_text())
    study = json.loads((tmp_path / "study" / "standing" / "foot.json").read_text())
    assert (run["nodes"], run["steps"], run["rigid_bodies"]) == (study["nodes"], 4, 11)
    for key, value in study["standing"].items():
        if isinstance(value, dict):
            assert run["standing"][key] == pytest.approx(value, rel=1e-9), key
        else:
            assert np.allclose(run["standing"][key], value, rtol=1e-9), key
    assert run["min_det_F"] == pytest.approx(study["min_det_F"], rel=1e-12)
    foot, _ = standing  # the same level-0 foot: its weight
    weight = G * (foot.tissue.total_mass() + sum(b.mass for b in foot.bones.values()))
    expected = 0.2 * HALF_WEIGHT + weight  # t = 0.02 s of the 0.1 s ramp, plus the weight
    assert run["standing"]["load_plus_weight_N"] == pytest.approx(expected, rel=1e-9)
    for png in ("foot.png", "plantar_pressure.png"):
        assert_picture(tmp_path / "run" / "standing" / png)
