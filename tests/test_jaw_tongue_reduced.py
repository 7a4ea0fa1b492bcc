"""The jaw-tongue scene with a reduced tongue (models/jaw_tongue/reduced.py, study.py), trained on
short full runs: the jaw-attachment nodes ride on the jaw exactly, the hinge holds, and the
tongue and the jaw angle follow the full scene, on inputs it was not trained on too."""

import json
from pathlib import Path

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.models.jaw_tongue import reduced as jtr
from artifem.cli import main
from outputs import assert_picture, assert_split_as_committed, quick_split

#: ``artifem simulate jaw-tongue`` (protrusion, the default JawTongueConfig, dt = 0.01 s) as
#: committed: the full scene of ``compare``, bit-identical to a fresh run at the same steps
COMMITTED = json.loads(
    (Path(__file__).resolve().parents[1] / "docs" / "img" / "jaw_tongue.json").read_text()
)


#: the committed quick split (scripts/quick_splits.py -> docs/benchmarks/quick_splits.json)
QUICK = quick_split("jaw-tongue")


@pytest.fixture(scope="module")
def figures(tmp_path_factory, quick_jaw_tongue):
    """The committed quick split's command, ``artifem study jaw-tongue --quick --duration
    0.15 --held-out 2``, on the quick training (the session fixture ``quick_jaw_tongue`` in
    tests/conftest.py, shared with test_airway: its cache holds the training, so the study
    loads it, runs the full and the reduced scene and the train/test split)."""
    out = tmp_path_factory.mktemp("jaw_tongue_reduced")
    assert quick_jaw_tongue.config == jtr.quick_config()  # --quick's training
    argv = [*QUICK["argv"], "--cache", str(quick_jaw_tongue.cache), "--out", str(out)]
    assert main(argv) == 0
    return json.loads((out / "jaw_tongue_reduced.json").read_text()), out


def test_reduced_jaw_tongue_follows_the_full_scene(figures):
    """The full scene is the committed ``simulate jaw-tongue`` run over its first 0.15 s
    (its tip moves 4.3 mm, the jaw opens 4.5 degrees; rel 1e-6). The reduced one (r = 12
    + 12, 150 points) follows it within 1.25 x the committed quick study's errors (mean
    node error 0.26 mm, jaw angle 0.11 degrees), the report's row is the JSON's, the
    picture shows the scenes."""
    f, out = figures
    r = f["motions"]["protrusion"]
    n = 16  # t = 0 and 15 steps of 0.01 s
    tips = np.linalg.norm(COMMITTED["tip_displacement_mm"][:n], axis=1)
    assert r["max_tip_displacement_mm"] == pytest.approx(tips.max(), rel=1e-6)
    angle = max(COMMITTED["opening_angle_deg"][:n])
    assert r["max_angle_deg"]["full"] == pytest.approx(angle, rel=1e-6)
    committed = QUICK["runs"]["protrusion"]
    assert r["max_mean_error_mm"] <= QUICK["margin"] * committed["max_mean_error_mm"]
    assert r["max_angle_difference_deg"] <= QUICK["margin"] * committed["max_angle_difference_deg"]
    assert r["max_attachment_error_m"] < 1e-12  # carried nodes exactly on the jaw
    assert r["max_joint_error"] < 1e-5
    assert_picture(out / r["png"])
    row = (
        f"| protrusion | {r['full_ms_per_step']:.1f} | {r['reduced_ms_per_step']:.2f} | "
        f"{r['speedup']:.0f}x | {r['max_mean_error_mm']:.2f} | {r['max_node_error_mm']:.2f} | "
        f"{r['max_angle_deg']['full']:.2f} / {r['max_angle_deg']['reduced']:.2f} |"
    )
    assert row in (out / "jaw_tongue_reduced.md").read_text().splitlines()


def test_the_quick_split_generalizes_as_committed(figures):
    """``--held-out 2``: the reduced scene on its own training runs (each exciter alone), on
    the three motions and on two random multi-exciter schedules it was never trained on
    (seed 1000), each against the full scene: no run failed, and every error is within
    25 % of the committed quick split's (docs/benchmarks/quick_splits.json)."""
    _, out = figures
    assert_split_as_committed(out, "jaw-tongue")
    assert len(QUICK["sets"]["held-out"]) == 2
    assert_picture(out / "generalization.png")


def test_lift_basis_vanishes_on_the_fixed_and_carried_nodes(quick_jaw_tongue):
    quick, model = quick_jaw_tongue.config, quick_jaw_tongue.model
    s = jtr.build_reduced_scene(model, quick)
    body = s.tongue.body
    carried = (3 * s.attachment.lift.dofs[:, None] + np.arange(3)).ravel()
    fixed = (3 * body.fixed_dofs[:, None] + np.arange(3)).ravel()
    U = model.basis[:, : quick.r]  # the POD vectors, then the jaw's lift
    assert np.abs(U[carried]).max() < 1e-12
    assert np.abs(model.basis[fixed]).max() == 0.0
    assert [c.body for c in model.carriers] == ["jaw"]
    assert np.array_equal(model.basis[:, quick.r :], s.attachment.lift.columns)
    assert s.scene.master_count() == quick.r + 6


def test_the_jaw_opener_is_a_load_input_of_the_reductor_model():
    """The opener's excitation is a load case of the model: a schedule that leaves it out
    lets the opener follow its own ramp (to 0.5 over 0.2 s); one naming it at 0 keeps the
    jaw nearly shut (it settles under gravity); one naming it at 1 opens it further. The jaw
    turns by 2.6150, 0.2148 and 7.4486 degrees by t = 0.1 s (measured, deterministic: the
    same with OpenBLAS's Haswell and Sandybridge kernels; asserted to 1e-5 relative)."""
    from artifem.excitation import ExcitationSchedule
    from artifem.scene import simulate

    model = jtr.reducible(jtr.quick_config())
    angles = {}
    for name, values in (
        ("own ramp", {}),
        ("held at 0", {"opener": np.zeros(2)}),
        ("held at 1", {"opener": np.ones(2)}),
    ):
        scene = model.build()
        model.drive(scene, ExcitationSchedule(np.array([0.0, 0.1]), {"GGP": np.zeros(2), **values}))
        assert model.input_names(model.fem_body(scene))[-1] == "opener"
        jaw = next(b for b in scene.rigid_bodies if b.name == "jaw")
        start = jaw.rotation.copy()
        simulate(scene, 0.1, 0.01, progress=False)
        angles[name] = np.degrees(
            np.arccos(np.clip((np.trace(start.T @ jaw.rotation) - 1) / 2, -1.0, 1.0))
        )
    measured = {"own ramp": 2.61495818, "held at 0": 0.21482999, "held at 1": 7.44859994}
    assert angles == pytest.approx(measured, rel=1e-5)
