"""The foot's geometry (artifem.models.foot): bones assembled from the Hamner osim, the
skin envelope, the coarse (level 0) soft-tissue mesh, and the refusals of bad input."""

from dataclasses import replace

import numpy as np
import pytest

from artifem.errors import InputError, MeshError
from artifem.models.foot import bones as fb
from artifem.models.foot import mesh as fm
from artifem.models.foot import skin as fs


@pytest.fixture(scope="module")
def bones():
    return fb.load_bones()


@pytest.fixture(scope="module")
def foot(foot_cache):
    return fm.foot_mesh(0, cache=foot_cache)


def test_osim_offsets_and_bodies():
    joints = fb.joint_frames()
    expected = {
        "ankle_r": ("tibia_r", "talus_r", [0, -0.43, 0]),
        "subtalar_r": ("talus_r", "calcn_r", [-0.04877, -0.04195, 0.00792]),
        "mtp_r": ("calcn_r", "toes_r", [0.1788, -0.002, 0.00108]),
    }
    for name, (parent, child, offset) in expected.items():
        j = joints[name]
        assert (j["parent"]["body"], j["child"]["body"]) == (parent, child)
        assert np.allclose(j["parent"]["translation"], offset)
        for role in ("parent", "child"):
            assert np.allclose(j[role]["orientation"], 0)
        assert np.allclose(j["child"]["translation"], 0)
        assert np.allclose(j["spatial"], np.eye(4))  # default pose: coordinates 0
    fb.check_bodies()
    meshes = fb.body_meshes()
    assert meshes["tibia_r"] == ["tibia_r.vtp", "fibula_r.vtp"]
    assert meshes["talus_r"] == ["talus_rv.vtp"]


def test_bones_assembled(bones):
    assert len(bones) == 28 and len(fb.GROUPS) == 11
    assert sorted(b for g in fb.GROUPS.values() for b in g) == sorted(fb.BONES)
    by_name = {b.name: b for b in bones}
    raw = fb.read_vtp(fb.DATA / "calcaneous_rv.vtp")[0]
    talus_origin = np.array([0, -0.43, 0])
    assert np.allclose(
        by_name["calcaneus"].vertices, raw + talus_origin + [-0.04877, -0.04195, 0.00792]
    )
    raw = fb.read_vtp(fb.DATA / "distal_phalanx1_rvs.vtp")[0]
    assert np.allclose(
        by_name["distal_phalanx1"].vertices,
        raw + talus_origin + [-0.04877, -0.04195, 0.00792] + [0.1788, -0.002, 0.00108],
    )
    for b in bones:
        assert fb.edge_defects(b.triangles) == (0, 0), b.name
        assert fb.signed_volume(b.vertices, b.triangles) > 0, b.name
    assert fb.penetrations(bones) == []
    assert min(fb.min_gaps(bones).values()) > 1e-4


def test_skin_and_mesh(bones, foot):
    v, f = foot.skin
    assert fb.edge_defects(f) == (0, 0) and fb.signed_volume(v, f) > 0
    for b in bones:
        below = b.vertices[b.vertices[:, 1] < foot.cap_y]
        assert (fs.signed_distance(below, v, f) < 0).all(), b.name
    assert foot.stats["nodes"] < 2500
    p, c = foot.points, foot.cells
    a, b_, c_, d = (p[c[:, i]] for i in range(4))
    vol = np.einsum("ij,ij->i", b_ - a, np.cross(c_ - a, d - a)) / 6
    assert (vol > 0).all()
    holes = sum(fb.signed_volume(*foot.group_surfaces[g]) for g in foot.groups)
    expected = fb.signed_volume(v, f) - holes  # the tibia's surface is cut at the cap
    assert vol.sum() == pytest.approx(expected, rel=0.03)
    tags = set(np.unique(foot.facet_tags))
    assert tags == {fm.SKIN, fm.CAP} | {foot.tag(g) for g in foot.groups}
    cap = foot.points[foot.facets[foot.facet_tags == fm.CAP]]
    assert np.allclose(cap[:, :, 1], foot.cap_y)
    # bone-tagged facets lie on their group's bones (within the shrink + decimation)
    for g in ("calcaneus", "tibia", "toes2_5"):
        x = foot.points[foot.facets[foot.facet_tags == foot.tag(g)]].mean(1)
        gb = [b for b in bones if b.group == g]
        d = np.min([np.abs(fs.signed_distance(x, b.vertices, b.triangles)) for b in gb], 0)
        h = fm.LEVELS[0].h_bone  # chords of the coarse surfaces
        assert np.percentile(d, 95) < 0.3 * h and d.max() < 0.5 * h, g


def test_dolfinx(foot):
    msh, tags = fm.to_dolfinx(foot)
    assert msh.topology.index_map(3).size_local == len(foot.cells)
    assert len(tags.values) == len(foot.facets)
    assert set(np.unique(tags.values)) == set(np.unique(foot.facet_tags))


def test_cache(foot, tmp_path):
    fm._save(foot, tmp_path / "m.npz")
    again = fm._load(tmp_path / "m.npz")
    assert np.array_equal(again.cells, foot.cells) and again.groups == foot.groups


def _moved(bones, name, f):
    return [replace(b, vertices=f(b.vertices)) if b.name == name else b for b in bones]


def test_bad_input(bones):
    with pytest.raises(InputError, match="units"):
        fm.check_input([replace(b, vertices=b.vertices * 1000) for b in bones])
    b = next(b for b in bones if b.name == "navicular")
    with pytest.raises(MeshError, match="navicular.*not closed"):
        fb.check_closed(f"bone {b.name} ({b.file})", b.vertices, b.triangles[5:])
    talus = next(b for b in bones if b.name == "talus")
    shift = talus.vertices.mean(0) - b.vertices.mean(0)
    with pytest.raises(MeshError, match="navicular|talus") as err:
        fm.check_input(_moved(bones, "navicular", lambda v: v + shift))
    assert "intersect" in str(err.value)
    params = fm.LEVELS[0].skin
    skin = fs.envelope([x for x in bones if x.name != "calcaneus"], params)
    with pytest.raises(MeshError, match="calcaneus"):
        fm.check_input(bones, skin, params.cap_y)
    with pytest.raises(InputError, match="level"):
        fm.foot_mesh(7, cache=None)
