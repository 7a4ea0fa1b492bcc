"""Skeletal registration (artifem.registration.skeleton, .skeletal; the cases of
artifem.models.registration) at the coarse grid of the suite (12 mm cells): the three
OpenSim bones (tibia with fibula, talus, calcaneus) on their ankle and subtalar hinges.

- rigid target (the reference turned about its joints and moved): the jointed deformable
  bones recover the joint angles and come near the target within 1.25 times their measured
  errors (0.004 and 0.001 degrees; 0.5 to 2.9 micrometres), the joints held to round-off;
- synthetic non-rigid target (scaled, bent, noisy, a third of the calcaneus missing): the
  jointed bones end nearer the target than per-bone rigid ICP and than one jointless
  grid, with no element inverted;
- bad input is refused before any solve, naming the bone or joint.
"""

import json
import shutil

import numpy as np
import pytest

from artifem.errors import InputError, MeshError
from artifem.forms import NeoHookean
from artifem.models import registration as cases
from artifem.registration.skeletal import register_skeleton
from artifem.registration.skeleton import Skeleton, read_surface, write_surface
from outputs import assert_picture

CELL = 0.012
MATERIAL = NeoHookean.from_young_poisson(1e6, 0.3)


@pytest.fixture(scope="module")
def rigid_case(tmp_path_factory):
    out = tmp_path_factory.mktemp("rigid")
    ref, target = cases.write_case("rigid", out / "input")
    report = register_skeleton(
        ref,
        target,
        out,
        material=MATERIAL,
        cell_size=CELL,
        methods=("rigid", "jointed"),
        progress=lambda s: None,
    )
    return out, report


def test_the_reference_reads_back_and_poses_about_its_hinges(tmp_path):
    skeleton = cases.reference()
    skeleton.write(tmp_path)
    again = Skeleton.read(tmp_path)
    for bone, (V, T) in skeleton.bones.items():
        np.testing.assert_allclose(again.bones[bone][0], V, atol=1e-7)  # float32 in VTP
        np.testing.assert_array_equal(again.bones[bone][1], T)
    ankle = skeleton.hinge("ankle")
    posed = skeleton.posed({"ankle": 0.3})
    np.testing.assert_array_equal(posed["tibia"], skeleton.bones["tibia"][0])
    # the talus and the calcaneus turn together about the ankle axis through its centre
    R, t = ankle.rotation(0.3)
    for bone in ("talus", "calcaneus"):
        np.testing.assert_allclose(posed[bone], skeleton.bones[bone][0] @ R.T + t, atol=1e-15)
    assert np.allclose(R @ ankle.axis, ankle.axis) and np.allclose(
        R @ ankle.centre + t, ankle.centre
    )


#: the jointed registration's errors on the rigid case at 12 mm cells, measured (two runs,
#: same digits): |angle - truth| in degrees, and each bone's mean distance to the target (m)
MEASURED_ANGLE_ERROR_DEG = {"ankle": 0.0037406187106618916, "subtalar": 0.00106509665189769}
MEASURED_MEAN_M = {
    "tibia": 4.700481954140043e-07,
    "talus": 2.661208763048195e-06,
    "calcaneus": 2.8741319008781748e-06,
}


def test_a_rigidly_posed_target_gives_back_the_joint_angles(rigid_case):
    """Each joint angle and each bone's mean distance within 1.25 times its measured error
    (the issue-32 margin of a deterministic error); the report written is the one returned,
    its picture shows the bones."""
    out, report = rigid_case
    jointed = report["methods"]["jointed"]
    for joint, truth in cases.POSE.items():
        error = abs(jointed["joint_angles_deg"][joint] - truth)
        assert error < 1.25 * MEASURED_ANGLE_ERROR_DEG[joint], (joint, error)
    for bone, row in jointed["bones"].items():
        assert row["mean"] < 1.25 * MEASURED_MEAN_M[bone], (bone, row["mean"])
    assert jointed["joint_constraint_error"] < 1e-10
    written = json.loads((out / "registration.json").read_text())
    assert written["methods"]["jointed"]["joint_angles_deg"] == jointed["joint_angles_deg"]
    V, _ = read_surface(out / "meshes" / "jointed_talus.stl")
    assert len(V) == report["bones"]["talus"]["vertices"]
    assert_picture(out / "registration.png")


#: mean surface distance (m) over the bones of the deformed partial target, per method,
#: measured (the fit is deterministic): the jointed bones 16 % below the single body
MEASURED_DEFORMED_M = {"rigid": 7.826e-4, "single": 1.519e-4, "jointed": 1.277e-4}


def test_jointed_bones_fit_a_deformed_partial_target_better_than_the_baselines(tmp_path):
    """Each method within 1.25 times its measured mean distance (MEASURED_DEFORMED_M), the
    jointed bones below both baselines; the joints held to round-off (measured 2e-14 m)."""
    ref, target = cases.write_case("synthetic", tmp_path / "input")
    report = register_skeleton(
        ref,
        target,
        tmp_path,
        material=MATERIAL,
        cell_size=CELL,
        methods=("rigid", "single", "jointed"),
        progress=lambda s: None,
    )
    mean = {
        m: np.mean([r["mean"] for r in row["bones"].values()])
        for m, row in report["methods"].items()
    }
    assert mean["jointed"] < mean["rigid"] and mean["jointed"] < mean["single"]
    assert mean["jointed"] < 1.25 * MEASURED_DEFORMED_M["jointed"]
    for baseline in ("rigid", "single"):  # the baselines' margin is real
        assert mean[baseline] > MEASURED_DEFORMED_M[baseline] / 1.25, (baseline, mean)
    jointed = report["methods"]["jointed"]
    assert jointed["joint_constraint_error"] < 1e-10
    assert jointed["min_det_F"] > 0 and report["methods"]["single"]["min_det_F"] > 0


def _copy(rigid_case, tmp_path):
    out, _ = rigid_case
    shutil.copytree(out / "input", tmp_path / "input")
    return tmp_path / "input" / "reference", tmp_path / "input" / "target"


def _run(ref, target, tmp_path):
    register_skeleton(
        ref,
        target,
        tmp_path / "out",
        material=MATERIAL,
        cell_size=CELL,
        methods=("jointed",),
        progress=lambda s: None,
    )


def test_bad_input_is_refused_before_any_solve(rigid_case, tmp_path):
    ref, target = _copy(rigid_case, tmp_path)
    spec = json.loads((target / "target.json").read_text())
    # units off by 1000
    (target / "target.json").write_text(json.dumps({**spec, "units": "mm"}))
    with pytest.raises(InputError, match="bone 'tibia'.*units off"):
        _run(ref, target, tmp_path)
    # a bone without a target
    (target / "target.json").write_text(
        json.dumps({**spec, "bones": {b: f for b, f in spec["bones"].items() if b != "talus"}})
    )
    with pytest.raises(InputError, match="no target for bone.*talus"):
        _run(ref, target, tmp_path)
    # a target far from its bone
    V, T = read_surface(target / "calcaneus.stl")
    write_surface(target / "far.stl", V + [0.0, 0.0, 0.3], T)
    (target / "target.json").write_text(
        json.dumps({**spec, "bones": {**spec["bones"], "calcaneus": "far.stl"}})
    )
    with pytest.raises(InputError, match="pre-alignment: bone 'calcaneus'"):
        _run(ref, target, tmp_path)
    (target / "target.json").write_text(json.dumps(spec))
    # an open, then an inverted bone surface
    V, T = read_surface(ref / "talus.vtp")
    write_surface(ref / "talus.vtp", V, T[1:])
    with pytest.raises(MeshError, match="bone 'talus' is not a closed surface"):
        _run(ref, target, tmp_path)
    write_surface(ref / "talus.vtp", V, T[:, ::-1])
    with pytest.raises(MeshError, match="bone 'talus' is inward"):
        _run(ref, target, tmp_path)
    write_surface(ref / "talus.vtp", V, T)
    # a joint centre outside its bones
    skeleton = json.loads((ref / "skeleton.json").read_text())
    skeleton["joints"][1]["centre"] = [0.0, -0.3, 0.2]
    (ref / "skeleton.json").write_text(json.dumps(skeleton))
    with pytest.raises(InputError, match="joint 'subtalar'.*from bone"):
        _run(ref, target, tmp_path)


def test_the_register_command_writes_its_report(rigid_case, tmp_path):
    """``artifem register`` on the rigid case's directories, the ICP baselines only: each
    bone moved rigidly, so per-bone rigid ICP ends on the target (to 1 micrometre). The
    picture has the distance's colour bar (viridis' yellow end, 1 mm: the bones, within a
    micrometre or so of their targets, are at its dark end)."""
    import pyvista as pv

    from artifem.cli import main

    out, _ = rigid_case
    assert (
        main(
            [
                "register",
                "--reference",
                str(out / "input" / "reference"),
                "--target",
                str(out / "input" / "target"),
                "--out",
                str(tmp_path),
                "--methods",
                "rigid,affine",
            ]
        )
        == 0
    )
    report = json.loads((tmp_path / "registration.json").read_text())
    assert set(report["methods"]) == {"rigid", "affine"}
    for row in report["methods"]["rigid"]["bones"].values():
        assert row["mean"] < 1e-6
    rgb = np.asarray(pv.read(tmp_path / "registration.png").point_data.active_scalars)[:, :3]
    assert (np.abs(rgb.astype(float) - [253, 231, 37]).max(axis=1) < 30).sum() > 50
    assert (
        main(
            [
                "register",
                "--reference",
                str(out / "input" / "reference"),
                "--target",
                str(out / "input" / "target"),
                "--out",
                str(tmp_path),
                "--methods",
                "elastic",
            ]
        )
        == 2
    )


def test_an_interrupted_registration_resumes_where_it_stopped(rigid_case, tmp_path, monkeypatch):
    """The jointed method stopped after its first weight stage (its checkpoint written),
    then run again with resume=True: the same bones as an uninterrupted run, and no
    checkpoint left."""
    import artifem.registration.skeletal as skeletal

    ref, target = rigid_case[0] / "input" / "reference", rigid_case[0] / "input" / "target"
    options = dict(
        material=MATERIAL,
        cell_size=CELL,
        weights=(1e2, 1e3),
        methods=("jointed",),
        progress=lambda s: None,
    )
    whole = register_skeleton(ref, target, tmp_path / "whole", **options)
    real = skeletal.register

    def interrupted(scene, forces, weights, **kwargs):
        real(scene, forces, weights[:1], **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(skeletal, "register", interrupted)
    with pytest.raises(KeyboardInterrupt):
        register_skeleton(ref, target, tmp_path / "run", **options)
    assert (tmp_path / "run" / "jointed.checkpoint").exists()
    monkeypatch.setattr(skeletal, "register", real)
    resumed = register_skeleton(ref, target, tmp_path / "run", resume=True, **options)
    assert not (tmp_path / "run" / "jointed.checkpoint").exists()
    assert resumed["methods"]["jointed"]["weights"] == [1e2, 1e3]
    for bone, row in whole["methods"]["jointed"]["bones"].items():
        assert resumed["methods"]["jointed"]["bones"][bone]["mean"] == pytest.approx(
            row["mean"], rel=1e-9, abs=1e-15
        )
