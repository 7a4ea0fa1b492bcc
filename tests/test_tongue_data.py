"""The ArtiSynth tongue data: muscle bundles, fibers, element directions, 2x2x2 refinement."""

import re
from pathlib import Path

import artifem  # noqa: F401  (must precede dolfinx)

import numpy as np
import pytest
from scipy.spatial import cKDTree

from artifem.io.mesh_checks import element_jacobians, element_volumes, volume
from artifem.io.mesh_data import MeshData
from artifem.io.readers import read_mesh
from artifem.io.refine import carry_cell_set, carry_node_set, refine_hexahedra
from artifem.models.tongue.apdl import (
    read_fibers,
    read_muscle_elements,
    read_muscle_groups,
    read_muscle_names,
)
from artifem.models.tongue.fibers import (
    EXTRA_NODES,
    bundle_geometry,
    element_directions,
    fiber_points,
)

DATA = Path(__file__).resolve().parents[1] / "models" / "data" / "artisynth-tongue"

# Counts read from CreateMuscles.mac / Fibers.mac (see the report of this issue).
ELEMENTS = {
    "GGP": 49,
    "GGM": 11,
    "GGA": 14,
    "STY": 16,
    "GH": 12,
    "MH": 24,
    "HG": 20,
    "VERT": 94,
    "TRANS": 132,
    "IL": 14,
}
FIBERS = {
    "GGP": 12,
    "GGM": 4,
    "GGA": 6,
    "STY": 9,
    "GH": 6,
    "MH": 14,
    "HG": 10,
    "VERT": 27,
    "TRANS": 51,
    "IL": 4,
}
NAMES = [f"{m}_{s}" for m in ELEMENTS for s in "LR"] + ["SL"]
PAIRS = [(f"{m}_L", f"{m}_R") for m in ELEMENTS]
# Coordinates are written with 7 significant digits (0.1 um); the worst mirror
# mismatch found is 4.2e-6 m (HG fibers): 1e-5 m = 0.01 mm is far below any
# element size (6 mm and more).
MIRROR_TOL = 1e-5


def mirrored(x):
    return np.asarray(x) * np.array([1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def md():
    return read_mesh(DATA / "tongue.node")


@pytest.fixture(scope="module")
def bundles():
    return read_muscle_elements(DATA / "CreateMuscles.mac")


@pytest.fixture(scope="module")
def fibers():
    return read_fibers(DATA / "Fibers.mac", names=read_muscle_names(DATA / "CreateMuscles.mac"))


@pytest.fixture(scope="module")
def fibers_xyz(md, fibers):
    return fiber_points(md, fibers)


@pytest.fixture(scope="module")
def refined(md):
    return refine_hexahedra(md)


def centroids(md, ids):
    return md.points[md.cells[md.cell_rows(ids)]].mean(axis=1)


# ---------------------------------------------------------------- CreateMuscles.mac


def test_bundles_names_counts_and_ids(md, bundles):
    assert read_muscle_names(DATA / "CreateMuscles.mac") == NAMES
    assert list(bundles) == NAMES  # NEW_TISSUE is an empty selection: no component
    for name, ids in bundles.items():
        expected = 102 if name == "SL" else ELEMENTS[name[:-2]]
        assert len(ids) == expected, name
        assert len(np.unique(ids)) == len(ids)
        assert np.isin(ids, md.cell_ids).all(), name
    groups = read_muscle_groups(DATA / "CreateMuscles.mac")
    assert groups == {m: [f"{m}_L", f"{m}_R"] for m in ELEMENTS}


def test_midplane_and_bundle_mirror_pairs(md, bundles):
    assert (md.points[:, 1] == 0).sum() == 120
    for left, right in PAIRS:
        cl, cr = centroids(md, bundles[left]), centroids(md, bundles[right])
        assert (cl[:, 1] < 0).all() and (cr[:, 1] > 0).all(), left  # _L is the y < 0 side
        dist, _ = cKDTree(mirrored(cr)).query(cl)
        assert dist.max() < MIRROR_TOL, left
    sl = centroids(md, bundles["SL"])
    assert cKDTree(mirrored(sl)).query(sl)[0].max() < MIRROR_TOL


def test_apdl_selection_semantics(tmp_path):
    mac = tmp_path / "sel.mac"
    mac.write_bytes(
        "! commentaire d\xe9fini en latin-1\n/NOPR\n*DIM,x,,3\nn = 3\n"
        "ESEL,S,ELEM,,1,10\nESEL,U,ELEM,,2,10,2\nESEL,A,ELEM,,20\n"
        "ESEL,R,ELEM,,1,20,3  ! keeps 1, 7, ... of the set\nCM,A,ELEM\n"
        "ESEL,NONE\nCM,EMPTY,ELEM\nESEL,S,ELEM,,5\nCMSEL,A,A\nCM,B,ELEM\n"
        "ESEL,ALL\nESEL,U,ELEM,,1,3\nCM,C,ELEM\n".encode("latin-1")
    )
    got = read_muscle_elements(mac, all_elements=np.arange(1, 8))
    assert {k: v.tolist() for k, v in got.items()} == {
        "A": [1, 7],
        "B": [1, 5, 7],
        "C": [4, 5, 6, 7],
    }
    with pytest.raises(ValueError, match=r"sel\.mac:15: ESEL,ALL"):
        read_muscle_elements(mac)  # ALL needs the mesh's elements
    bad = tmp_path / "bad.mac"
    bad.write_text("ESEL,S,ELEM,,1\nESEL,S,MAT,,1\nCM,X,ELEM\n")
    with pytest.raises(ValueError, match=r"bad\.mac:2: ESEL by 'MAT'"):
        read_muscle_elements(bad)
    bad.write_text("ESEL,S,ELEM,,1\nESLN,S\nCM,X,ELEM\n")
    with pytest.raises(ValueError, match=r"bad\.mac:2: command ESLN"):
        read_muscle_elements(bad)
    with pytest.raises(FileNotFoundError, match="nothere.mac"):
        read_muscle_elements(tmp_path / "nothere.mac")
    with pytest.raises(FileNotFoundError, match="nothere.mac"):
        read_fibers(tmp_path / "nothere.mac", names=["A"])


# ---------------------------------------------------------------- Fibers.mac


def test_fibers_counts_nodes_and_pairing(md, bundles, fibers):
    # Fibers.mac has no muscleName array: without names it cannot be read.
    with pytest.raises(ValueError, match="no muscleName array"):
        read_fibers(DATA / "Fibers.mac")
    assert list(fibers) == NAMES
    known = set(md.node_ids.tolist())
    for name, polylines in fibers.items():
        assert len(polylines) == (22 if name == "SL" else FIBERS[name[:-2]]), name
        bundle_nodes = set(md.node_ids[np.unique(md.cells[md.cell_rows(bundles[name])])].tolist())
        for ids in polylines:
            assert len(ids) >= 2 and (np.diff(ids) != 0).all()
            outside = [i for i in ids.tolist() if i not in known]
            # only the styloglossus leaves the mesh, to the styloid process, at its last node
            if name.startswith("STY"):
                assert outside == [4037 if name == "STY_L" else 4042] and ids[-1] == outside[0]
            else:
                assert outside == []
            # pairing by index with CreateMuscles.mac is right: the fiber runs
            # through the elements of the bundle of the same name
            assert set(ids.tolist()) - set(outside) <= bundle_nodes, name


def test_fibers_mirror(fibers_xyz):
    for left, right in PAIRS:
        for a, b in zip(fibers_xyz[left], fibers_xyz[right], strict=True):
            assert a.shape == b.shape and np.abs(a - mirrored(b)).max() < MIRROR_TOL, left
    sl = fibers_xyz["SL"]
    for a in sl:  # SL is one bundle across the midplane: its fiber set mirrors onto itself
        assert (
            min(np.abs(mirrored(a) - b).max() if b.shape == a.shape else np.inf for b in sl)
            < MIRROR_TOL
        )
    assert EXTRA_NODES[4037][1] < 0 < EXTRA_NODES[4042][1]


# ---------------------------------------------------------------- element directions


def _nearest_segment_bruteforce(c, polylines):
    best = (np.inf, None)
    for pts in polylines:
        for a, b in zip(pts[:-1], pts[1:]):
            d = b - a
            t = min(max(np.dot(c - a, d) / np.dot(d, d), 0.0), 1.0)
            dist = np.linalg.norm(c - (a + t * d))
            if dist < best[0]:
                best = (dist, d / np.linalg.norm(d))
    return best


def test_element_directions_follow_nearest_segment(md, bundles, fibers_xyz):
    x = md.points[md.cells]
    diameter = np.linalg.norm(x[:, :, None] - x[:, None], axis=3).max(axis=(1, 2))
    worst = 0.0
    for name in NAMES:
        rows = md.cell_rows(bundles[name])
        dirs, dist = element_directions(md.points, md.cells, rows, fibers_xyz[name])
        assert dirs.shape == (len(rows), 3) and dist.shape == (len(rows),)
        assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-14)
        for k, row in enumerate(rows):
            ref_dist, ref_dir = _nearest_segment_bruteforce(
                md.points[md.cells[row]].mean(0), fibers_xyz[name]
            )
            assert abs(np.dot(dirs[k], ref_dir)) == pytest.approx(1.0, abs=1e-12)
            assert dist[k] == pytest.approx(ref_dist, abs=1e-15)
        # Every element has a fiber of its bundle within one element diameter of
        # its centroid (measured worst: 0.87 diameters, in VERT), so the
        # direction is that of a fiber through the element or its neighbour.
        worst = max(worst, (dist / diameter[rows]).max())
    assert worst < 1.0


def test_directions_anatomy(md, bundles, fibers_xyz):
    """Measured mean |a0 . e| (x anterior->posterior, y left-right, z up):
    TRANS y 0.90; GH x 0.99; SL x 0.64 (z 0.59: it follows the curved dorsum
    down to the root); IL x 0.72; VERT z 0.54 (x 0.67: vertical to the curved
    dorsum, not to the xy plane); sagittal muscles |y| <= 0.25."""

    def dirs(name):
        rows = md.cell_rows(bundles[name])
        return element_directions(md.points, md.cells, rows, fibers_xyz[name])[0]

    mean_abs = {n: np.abs(dirs(n)).mean(axis=0) for n in NAMES}
    assert mean_abs["TRANS_L"][1] > 0.85
    assert mean_abs["GH_L"][0] > 0.95
    assert mean_abs["SL"][0] > 0.55 and mean_abs["IL_L"][0] > 0.65
    assert mean_abs["VERT_L"][2] > 0.45
    for n in ("GGP_L", "GGM_L", "GGA_L", "GH_L", "HG_L", "VERT_L", "IL_L", "SL"):
        assert mean_abs[n][1] < 0.3, n
    # the three intrinsic systems are roughly orthogonal where they meet
    sl_c, sl_d = centroids(md, bundles["SL"]), dirs("SL")
    for n in ("VERT_L", "TRANS_L"):
        _, near = cKDTree(sl_c).query(centroids(md, bundles[n]))
        assert np.abs((dirs(n) * sl_d[near]).sum(axis=1)).mean() < 0.35, n


def test_bundle_geometry(md, bundles, fibers):
    geo = bundle_geometry(md, bundles, fibers)
    vols = np.abs(element_volumes(md.points, md.cell_type, md.cells))
    for name, g in geo.items():
        assert g["elements"] == len(bundles[name]) and g["fibers"] == len(fibers[name])
        assert g["volume_m3"] == pytest.approx(vols[md.cell_rows(bundles[name])].sum())
        assert g["volume_m3"] > 0 and g["mean_fiber_length_m"] > 0
        assert g["cross_section_m2"] == pytest.approx(g["volume_m3"] / g["mean_fiber_length_m"])
        assert g["mean_fiber_length_inside_m"] <= g["mean_fiber_length_m"]
    for left, right in PAIRS:
        for key in ("volume_m3", "mean_fiber_length_m", "cross_section_m2"):
            assert geo[left][key] == pytest.approx(geo[right][key], rel=0.01), (left, key)
    assert geo["STY_L"]["mean_fiber_length_inside_m"] < 0.6 * geo["STY_L"]["mean_fiber_length_m"]
    assert geo["SL"]["volume_m3"] < volume(md)


# ---------------------------------------------------------------- refinement


def _hex_edges_faces(cells):
    """Unique edges and faces of a VTK-ordered hex mesh, from the reference cube."""
    ref = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
    local_edges = [
        (i, j)
        for i in range(8)
        for j in range(i + 1, 8)
        if sum(a != b for a, b in zip(ref[i], ref[j])) == 1
    ]
    local_faces = [
        tuple(i for i in range(8) if ref[i][ax] == side) for ax in range(3) for side in (0, 1)
    ]
    edges = {frozenset(int(c[i]) for i in e) for c in cells for e in local_edges}
    faces = {frozenset(int(c[i]) for i in f) for c in cells for f in local_faces}
    return edges, faces


def test_refined_tongue(md, refined):
    r = refined.mesh
    edges, faces = _hex_edges_faces(md.cells)
    n_nodes = 946 + len(edges) + len(faces) + 740
    assert (len(edges), len(faces)) == (2609, 2404)
    assert r.points.shape == (n_nodes, 3) == (6699, 3)
    assert r.cells.shape == (5920, 8)
    assert volume(r) == pytest.approx(volume(md), rel=1e-12)
    assert element_jacobians(r).min() > 0
    assert np.array_equal(r.points[:946], md.points)
    assert np.array_equal(r.node_ids, np.arange(1, n_nodes + 1))
    assert np.array_equal(r.cell_ids, np.arange(1, 5921))
    assert np.array_equal(refined.parent_cell, np.repeat(np.arange(740), 8))
    assert np.array_equal(r.cell_tags, np.repeat(md.cell_tags, 8))
    # children tile their parent: volumes add up element by element
    vc = element_volumes(md.points, "hexahedron", md.cells)
    vf = element_volumes(r.points, "hexahedron", r.cells).reshape(740, 8).sum(axis=1)
    assert np.allclose(vf, vc, rtol=1e-12)
    # conforming: no face is shared by more than two cells, and the boundary
    # has exactly 4 refined faces per coarse boundary face (no cracks)
    fine = _face_counts(r.cells)
    assert max(fine.values()) == 2
    boundary_coarse = sum(1 for k in _face_counts(md.cells).values() if k == 1)
    assert sum(1 for k in fine.values() if k == 1) == 4 * boundary_coarse
    # new nodes are the means of their parents
    n_new = n_nodes - 946
    assert len(refined.node_parents) == n_new
    for k in (0, len(edges), len(edges) + len(faces), n_new - 1):
        assert np.allclose(r.points[946 + k], md.points[refined.node_parents[k]].mean(axis=0))
    assert sorted({len(p) for p in refined.node_parents}) == [2, 4, 8]
    # the grouped parents are the same arrays, and a repr leaves them out (kept short)
    np.testing.assert_array_equal(
        refined.edge_parents, np.array(refined.node_parents[: len(edges)])
    )
    assert not {"edge_parents", "face_parents", "centre_parents"} & set(
        re.findall(r"(\w+)=", repr(refined))
    )


def _face_counts(cells):
    out = {}
    for c in cells:
        for f in (
            (0, 1, 2, 3),
            (4, 5, 6, 7),
            (0, 1, 5, 4),
            (1, 2, 6, 5),
            (2, 3, 7, 6),
            (3, 0, 4, 7),
        ):
            key = frozenset(c[list(f)].tolist())
            out[key] = out.get(key, 0) + 1
    return out


def test_attachment_files_are_zero_based_rows(md):
    """jawAttachments.txt / hyoidAttachments.txt hold ArtiSynth node numbers
    (0-based rows = ANSYS id - 1), not ANSYS ids: ArtiSynth reads them with
    fem.getNode(idx).  As rows all of them are surface nodes; read as ANSYS
    ids only 61 % / 55 % would be."""
    surface = {n for f, k in _face_counts(md.cells).items() if k == 1 for n in f}
    for name in ("jawAttachments.txt", "hyoidAttachments.txt"):
        rows = np.loadtxt(DATA / name, dtype=np.int64).ravel()
        assert all(int(r) in surface for r in rows), name
        assert np.mean([int(r) in surface for r in md.node_rows(rows)]) < 0.7, name


def test_carry_jaw_attachment_set(md, refined):
    jaw = np.loadtxt(DATA / "jawAttachments.txt", dtype=np.int64).ravel()  # 0-based rows
    carried = carry_node_set(refined, jaw)
    assert set(jaw.tolist()) <= set(carried.tolist())
    new = carried[carried >= 946]
    assert len(jaw) == 59 and len(new) == 122
    surface = {n for f, k in _face_counts(refined.mesh.cells).items() if k == 1 for n in f}
    coarse_surface = {f for f, k in _face_counts(md.cells).items() if k == 1}
    jaw_set = set(jaw.tolist())
    for row in new.tolist():
        parents = refined.node_parents[row - 946]
        assert set(parents.tolist()) <= jaw_set
        assert row in surface  # on the refined surface
        if len(parents) == 4:  # a face centre: of a coarse surface face inside the patch
            assert frozenset(parents.tolist()) in coarse_surface
        else:
            assert len(parents) == 2  # edge midpoint; never a cell centre
    cells = carry_cell_set(refined, [0, 5])
    assert cells.tolist() == list(range(8)) + list(range(40, 48))
    assert (refined.parent_cell[cells] == np.repeat([0, 5], 8)).all()


def test_refine_unit_cube():
    cube = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
        dtype=float,
    )
    md = MeshData(
        points=cube,
        cell_type="hexahedron",
        cells=np.arange(8)[None],
        node_ids=np.arange(1, 9),
        cell_ids=[7],
        cell_tags=[3],
    )
    ref = refine_hexahedra(md)
    r = ref.mesh
    assert r.points.shape == (27, 3) and r.cells.shape == (8, 8)
    grid = {tuple(p) for p in (np.array(np.meshgrid(*[[0, 0.5, 1]] * 3)).reshape(3, -1).T)}
    assert {tuple(p) for p in r.points} == grid
    vols = element_volumes(r.points, "hexahedron", r.cells)
    assert np.allclose(vols, 1 / 8, rtol=1e-14)
    for child in range(8):
        x = r.points[r.cells[child]]
        # each child is the unit-eighth cube at its parent corner, same node order
        assert np.allclose(x, cube[child] / 2 + cube / 2)
    assert r.cell_tags.tolist() == [3] * 8 and r.node_ids.tolist() == list(range(1, 28))
    assert carry_node_set(ref, [0, 1, 2, 3]).size == 9  # bottom face -> 3x3 nodes
    assert carry_node_set(ref, [0, 1]).size == 3
