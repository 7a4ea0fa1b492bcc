"""The jaw-tongue scene with a reduced tongue (models/jaw_tongue/reduced.py, study.py), trained on
short full runs: the jaw-attachment nodes ride on the jaw exactly, the hinge holds, and the
tongue and the jaw angle follow the full scene."""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.models.jaw_tongue import reduced as jtr
from artifem.models.jaw_tongue import study as jts


@pytest.fixture(scope="module")
def figures(tmp_path_factory, quick_jaw_tongue):
    """compare() of the quick training (the session fixture ``quick_jaw_tongue`` in
    tests/conftest.py, shared with test_airway): its cache holds the training, so compare
    loads it and runs the full and the reduced scene."""
    out = tmp_path_factory.mktemp("jaw_tongue_reduced")
    return jts.compare(
        quick_jaw_tongue.config,
        out,
        motions=("protrusion",),
        duration=0.15,
        cache=quick_jaw_tongue.cache,
    ), out


def test_reduced_jaw_tongue_follows_the_full_scene(figures):
    """Measured (r = 12 + 12, 150 points, 0.15 s): mean error 0.2 mm, jaw angle within
    0.05 degrees of the full scene's."""
    f, out = figures
    r = f["motions"]["protrusion"]
    assert r["max_tip_displacement_mm"] > 2.0  # the tongue really moved
    assert r["max_mean_error_mm"] < 0.5
    assert r["max_angle_deg"]["full"] > 1.0  # the jaw really opened
    assert r["max_angle_difference_deg"] < 0.1 * r["max_angle_deg"]["full"]
    assert r["max_attachment_error_m"] < 1e-12  # carried nodes exactly on the jaw
    assert r["max_joint_error"] < 1e-5
    assert (out / r["png"]).stat().st_size > 10_000
    assert (out / "jaw_tongue_reduced.json").exists()


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
    jaw nearly shut (it settles under gravity: 0.2 against 2.6 degrees at 0.1 s, measured),
    one naming it at 1 opens it further."""
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
    assert angles["own ramp"] > 0.5
    assert angles["held at 0"] < 0.15 * angles["own ramp"]
    assert angles["held at 1"] > 1.5 * angles["own ramp"]
