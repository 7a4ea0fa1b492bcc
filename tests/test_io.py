"""Mesh readers, checks, DOLFINx conversion, mesh info, result files and rendering."""

import argparse
import json
import subprocess
import sys
from pathlib import Path

import artifem  # noqa: F401  (must precede dolfinx)
import meshio
import numpy as np
import pytest
import ufl
from dolfinx import fem
from mpi4py import MPI

from artifem.io import mesh_info
from artifem.io.ansys import read_ansys
from artifem.io.mesh_checks import check_orientation, degenerate_elements, element_jacobians, volume
from artifem.errors import MeshError
from artifem.io.mesh_data import MeshData
from artifem.io.readers import read_mesh
from artifem.io.results import ResultWriter
from artifem.io.to_dolfinx import (
    dolfinx_cell_ids,
    dolfinx_node_ids,
    dolfinx_node_to_input,
    to_dolfinx,
)
from artifem.render import render_bodies
from outputs import read_series, same_rows

# The ArtiSynth tongue shipped with the project (models/data, with its LICENSE).
TONGUE = (
    Path(__file__).resolve().parents[1] / "models" / "data" / "artisynth-tongue" / "tongue.node"
)
UNIT_HEX = np.array(
    [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
    dtype=float,
)
BASIX_HEX_CORNERS = np.array(
    [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]],
    dtype=float,
)


@pytest.fixture(scope="module")
def tongue():
    return read_ansys(TONGUE)


def hex_mesh(cells, points=UNIT_HEX, source="test"):
    """MeshData of hexahedra on the given points, ids 1..M."""
    cells = np.atleast_2d(cells)
    return MeshData(
        points=points,
        cell_type="hexahedron",
        cells=cells,
        node_ids=np.arange(1, len(points) + 1),
        cell_ids=np.arange(1, len(cells) + 1),
        cell_tags=np.zeros(len(cells)),
        source=source,
    )


def write_ansys(tmp_path, nodes, elems, name="m"):
    """Write .node/.elem text files; return the .node path."""
    (tmp_path / f"{name}.node").write_text(nodes)
    (tmp_path / f"{name}.elem").write_text(elems)
    return tmp_path / f"{name}.node"


UNIT_NODES = "".join(f"{i + 1} {x} {y} {z}\n" for i, (x, y, z) in enumerate(UNIT_HEX))


def elem_line(nodes, eid=1, mat=3):
    return " ".join(map(str, nodes)) + f" {mat} 1 1 1 0 {eid}\n"


#: The six faces of a VTK-ordered hexahedron, counter-clockwise seen from outside.
HEX_FACES = np.array(
    [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
)


def surface_volume(mesh):
    """Volume of a hexahedral mesh by the divergence theorem, V = 1/3 sum over the cells'
    faces of int x . n dA: an algorithm independent of mesh_checks.volume (2x2x2 Gauss of
    det J). Exact with 2x2 Gauss per face: on a bilinear face x . (x_s x x_t) has degree 2
    in s and in t."""
    x = mesh.points[np.asarray(mesh.cells)][:, HEX_FACES]  # (cells, 6, 4, 3)
    total = 0.0
    for s in 0.5 + np.array([-0.5, 0.5]) / np.sqrt(3.0):
        for t in 0.5 + np.array([-0.5, 0.5]) / np.sqrt(3.0):
            N = np.array([(1 - s) * (1 - t), s * (1 - t), s * t, (1 - s) * t])
            Ns = np.array([t - 1, 1 - t, t, -t])
            Nt = np.array([s - 1, -s, s, 1 - s])
            p = np.einsum("k,cfkd->cfd", N, x)
            n = np.cross(np.einsum("k,cfkd->cfd", Ns, x), np.einsum("k,cfkd->cfd", Nt, x))
            total += 0.25 * np.einsum("cfd,cfd->", p, n) / 3.0
    return float(total)


def dolfinx_volume(msh):
    dx = ufl.dx(domain=msh, metadata={"quadrature_degree": 2})
    return msh.comm.allreduce(
        fem.assemble_scalar(fem.form(fem.Constant(msh, 1.0) * dx)), op=MPI.SUM
    )


# --- ANSYS reader --------------------------------------------------------------------------


def test_tongue_read(tongue):
    assert tongue.cell_type == "hexahedron"
    assert tongue.points.shape == (946, 3) and tongue.cells.shape == (740, 8)
    np.testing.assert_array_equal(tongue.node_ids, np.arange(1, 947))
    np.testing.assert_array_equal(tongue.cell_ids, np.arange(1, 741))
    assert dict(zip(*np.unique(tongue.cell_tags, return_counts=True))) == {1: 740}
    # first line of tongue.node and of tongue.elem
    np.testing.assert_allclose(tongue.points[0], [0.1136, -0.023972, 0.087835])
    np.testing.assert_array_equal(
        tongue.node_ids[tongue.cells[0]], [11, 9, 8, 10, 170, 171, 168, 169]
    )
    assert read_mesh(TONGUE.with_suffix(".elem")).cells.shape == (740, 8)


def test_tongue_is_valid(tongue):
    assert degenerate_elements(tongue) == []
    _, inverted = check_orientation(tongue)
    assert len(inverted) == 0
    assert element_jacobians(tongue).min() > 0
    # an independent algorithm (not a figure from an earlier run), and metres: an adult
    # tongue is tens of cm^3 (a reader keeping millimetres would be 1e9 times larger)
    assert volume(tongue) == pytest.approx(surface_volume(tongue), rel=1e-12)
    assert 50e-6 < volume(tongue) < 200e-6


def test_missing_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.node"):
        read_ansys(tmp_path / "nope.node")
    (tmp_path / "only.node").write_text(UNIT_NODES)
    with pytest.raises(MeshError, match=r"only\.elem"):
        read_ansys(tmp_path / "only.node")
    with pytest.raises(MeshError, match="nope.vtu"):
        read_mesh(tmp_path / "nope.vtu")


@pytest.mark.parametrize(
    "nodes, elems, message",
    [
        ("1 0 0 0\n2 1 0\n", "", r"bad\.node:2: expected 4 columns"),
        ("1 0 0 0\n\n2 1 0 x\n", "", r"bad\.node:3: node 2 has a non-numeric coordinate"),
        ("1 0 0 0\n1 1 0 0\n", "", r"bad\.node:2: node id 1 already defined at line 1"),
        (
            UNIT_NODES,
            elem_line(range(1, 9)) + "1 2 3 4 5 6 7 8 1 1 1 1 2\n",
            r"bad\.elem:2: expected 14 columns",
        ),
        (
            UNIT_NODES,
            "! comment\n1 2 3 4 5 6 7 8 1 1 1 1 0 x\n",
            r"bad\.elem:2: column 14 is not an integer",
        ),
        (
            UNIT_NODES,
            elem_line(range(1, 9)) + elem_line([1, 2, 3, 4, 5, 6, 7, 99], eid=7),
            r"bad\.elem:2: element 7 references node id\(s\) 99 not defined",
        ),
        (
            UNIT_NODES,
            elem_line(range(1, 9)) + elem_line(range(1, 9)),
            r"bad\.elem:2: element id 1 already defined at line 1",
        ),
    ],
)
def test_malformed_ansys(tmp_path, nodes, elems, message):
    node_path = write_ansys(tmp_path, nodes, elems, name="bad")
    with pytest.raises(MeshError, match=message):
        read_ansys(node_path)


def test_ansys_non_solid_elements_are_skipped_and_counted(tmp_path, capsys):
    """Shells, links and mass elements pad their unused node slots with id 0 (ANSYS EWRITE):
    the hexahedron is read, the others are counted by kind, and the mesh converts."""
    elems = (
        elem_line([1, 2, 3, 4, 0, 0, 0, 0], eid=5)  # SHELL181 on the bottom face
        + elem_line(range(1, 9), eid=6)
        + elem_line([1, 8, 0, 0, 0, 0, 0, 0], eid=7)  # LINK180
        + elem_line([5, 6, 7, 8, 0, 0, 0, 0], eid=8)
        + elem_line([3, 0, 0, 0, 0, 0, 0, 0], eid=9)
    )  # MASS21
    node_path = write_ansys(tmp_path, UNIT_NODES, elems, name="mixed")
    for mesh in (read_ansys(node_path), read_mesh(node_path.with_suffix(".elem"))):
        assert mesh.cells.shape == (1, 8) and list(mesh.cell_ids) == [6]
        assert mesh.skipped_cells == {
            "quad (shell or surface)": 2,
            "line (link or beam)": 1,
            "vertex (mass element)": 1,
        }
        assert mesh.skipped_volume_cells == {}
    msh, _ = to_dolfinx(read_ansys(node_path), MPI.COMM_SELF)
    assert dolfinx_volume(msh) == pytest.approx(volume(read_ansys(node_path)), rel=1e-12)
    assert mesh_info.run(argparse.Namespace(paths=[str(node_path)], json=False)) == 0
    assert (
        "skipped cells  2 quad (shell or surface), 1 line (link or beam), 1 vertex"
        in capsys.readouterr().out
    )
    # padding still names nodes that do not exist, and a file of shells alone has no solid
    bad = write_ansys(tmp_path, UNIT_NODES, elem_line([1, 2, 99, 0, 0, 0, 0, 0], eid=3), "bad")
    with pytest.raises(MeshError, match=r"bad\.elem:1: element 3 references node id\(s\) 99"):
        read_ansys(bad)
    shells = write_ansys(tmp_path, UNIT_NODES, elem_line([1, 2, 3, 4, 0, 0, 0, 0]), "shells")
    with pytest.raises(
        MeshError,
        match=r"no solid \(8-node\) elements found; only non-solid "
        r"ones: 1 quad",
    ):
        read_ansys(shells)


@pytest.mark.parametrize(
    "nodes, collapse",
    [
        ([1, 2, 3, 3, 5, 6, 7, 7], "wedge"),  # K=L, O=P
        ([1, 2, 3, 4, 5, 5, 5, 5], "pyramid"),  # M=N=O=P
        ([1, 2, 3, 3, 5, 5, 5, 5], "tetrahedron"),  # K=L, M=N=O=P
        ([1, 2, 3, 1, 5, 6, 7, 8], "irregular"),
    ],
)
def test_degenerate_hex_rejected(tmp_path, nodes, collapse):
    node_path = write_ansys(
        tmp_path, UNIT_NODES, elem_line(range(1, 9), eid=10) + elem_line(nodes, eid=42)
    )
    with pytest.raises(MeshError, match=f"element 42: {collapse}"):
        read_ansys(node_path)
    mesh = read_ansys(node_path, allow_degenerate=True)
    with pytest.raises(MeshError, match="element 42"):
        to_dolfinx(mesh, MPI.COMM_SELF)
    info = mesh_info.mesh_info([str(node_path)])[str(node_path)]
    assert info["degenerate"]["count"] == 1
    assert info["degenerate"]["elements"][0]["element"] == 42
    assert info["degenerate"]["elements"][0]["collapses_to"].startswith(collapse)


# --- orientation ---------------------------------------------------------------------------

TWO_CUBES = np.vstack([UNIT_HEX, [[2, 0, 0], [2, 1, 0], [2, 0, 1], [2, 1, 1]]])


def test_inverted_hex_reported_and_fixed():
    # Two unit cubes side by side; the second has its top and bottom faces swapped.
    mesh = hex_mesh([[0, 1, 2, 3, 4, 5, 6, 7], [5, 10, 11, 6, 1, 8, 9, 2]], points=TWO_CUBES)
    np.testing.assert_allclose(element_jacobians(mesh), [1.0, -1.0])
    fixed, inverted = check_orientation(mesh, fix=True)
    np.testing.assert_array_equal(inverted, [2])
    np.testing.assert_allclose(element_jacobians(fixed), [1.0, 1.0])
    assert element_jacobians(mesh)[1] == -1.0  # input untouched
    info_mesh = mesh_info.describe(mesh)
    assert info_mesh["inverted"] == {"count": 1, "elements": [2]}
    with pytest.raises(MeshError, match="inverted element"):
        to_dolfinx(mesh, MPI.COMM_SELF, reorient=False)
    msh, tags = to_dolfinx(mesh, MPI.COMM_SELF)
    assert tags is None
    assert dolfinx_volume(msh) == pytest.approx(2.0)


def test_inverted_tet_fixed():
    tet = MeshData(
        points=UNIT_HEX[[0, 1, 3, 4]],
        cell_type="tetrahedron",
        cells=[[0, 2, 1, 3]],
        node_ids=np.arange(4),
        cell_ids=[5],
        cell_tags=[0],
    )
    fixed, inverted = check_orientation(tet, fix=True)
    np.testing.assert_array_equal(inverted, [5])
    assert element_jacobians(fixed)[0] == pytest.approx(1.0)
    assert volume(tet) == pytest.approx(1 / 6)


def test_duplicate_element_refused():
    """Two cells on the same nodes would corrupt DOLFINx's topology: refused before it."""
    mesh = hex_mesh([[0, 1, 2, 3, 4, 5, 6, 7], [4, 5, 6, 7, 0, 1, 2, 3]])
    with pytest.raises(MeshError, match="element 2 repeats element 1"):
        to_dolfinx(mesh, MPI.COMM_SELF)


def test_tangled_hex_refused():
    mesh = hex_mesh([[0, 1, 2, 3, 4, 5, 6, 7], [1, 0, 2, 3, 4, 5, 6, 7]])
    with pytest.raises(MeshError, match=r"tangled.*ids 2"):
        check_orientation(mesh, fix=True)
    with pytest.raises(MeshError, match="ids 2"):
        to_dolfinx(mesh, MPI.COMM_SELF)
    assert mesh_info.describe(mesh)["tangled"]["elements"] == [2]


def test_distorted_hex_volume_exact():
    """2x2x2 Gauss volume of a trilinear hex equals a dolfinx integral at high degree."""
    rng = np.random.default_rng(0)
    points = UNIT_HEX + 0.15 * rng.standard_normal(UNIT_HEX.shape)
    mesh = hex_mesh([range(8)], points=points)
    msh, _ = to_dolfinx(mesh, MPI.COMM_SELF)
    dx = ufl.dx(domain=msh, metadata={"quadrature_degree": 8})
    exact = fem.assemble_scalar(fem.form(fem.Constant(msh, 1.0) * dx))
    assert volume(mesh) == pytest.approx(exact, rel=1e-13)
    assert surface_volume(mesh) == pytest.approx(exact, rel=1e-13)


# --- DOLFINx conversion --------------------------------------------------------------------


def test_tongue_to_dolfinx_positive_det_j(tongue):
    msh, tags = to_dolfinx(tongue, MPI.COMM_SELF)
    num_cells = msh.topology.index_map(3).size_local
    assert num_cells == 740
    det_j = fem.Expression(ufl.JacobianDeterminant(msh), BASIX_HEX_CORNERS)
    values = det_j.eval(msh, np.arange(num_cells, dtype=np.int32))
    assert values.min() > 0
    # corner det J computed by dolfinx matches the MeshData check, element by element
    cell_rows = msh.topology.original_cell_index
    np.testing.assert_allclose(values.min(axis=1), element_jacobians(tongue)[cell_rows], rtol=1e-10)
    assert dolfinx_volume(msh) == pytest.approx(volume(tongue), rel=1e-12)
    assert dict(zip(*np.unique(tags.values, return_counts=True))) == {1: 740}
    rows = dolfinx_node_to_input(msh)
    np.testing.assert_array_equal(msh.geometry.x[: len(rows)], tongue.points[rows])
    np.testing.assert_array_equal(dolfinx_node_ids(msh, tongue), tongue.node_ids[rows])
    np.testing.assert_array_equal(np.sort(dolfinx_cell_ids(msh, tongue)), np.arange(1, 741))


def test_tongue_to_dolfinx_two_ranks(tmp_path):
    mpiexec = Path(sys.executable).parent / "mpiexec"
    if not mpiexec.exists():
        pytest.skip("mpiexec not available")
    script = tmp_path / "run.py"
    script.write_text(
        "import artifem, ufl\nfrom mpi4py import MPI\nfrom dolfinx import fem\n"
        "from artifem.io.ansys import read_ansys\nfrom artifem.io.to_dolfinx import to_dolfinx\n"
        f"msh, tags = to_dolfinx(read_ansys({str(TONGUE)!r}))\n"
        "dx = ufl.dx(domain=msh, metadata={'quadrature_degree': 2})\n"
        "v = msh.comm.allreduce(fem.assemble_scalar(fem.form(1.0 * dx)), op=MPI.SUM)\n"
        "n = msh.comm.allreduce(msh.topology.index_map(3).size_local, op=MPI.SUM)\n"
        "t = msh.comm.allreduce(len(tags.values), op=MPI.SUM)\n"
        "if msh.comm.rank == 0: print(v, n, t, msh.comm.size)\n"
    )
    out = subprocess.run(
        [str(mpiexec), "-n", "2", sys.executable, str(script)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    v, n, t, size = out.stdout.split()
    assert float(v) == pytest.approx(surface_volume(read_ansys(TONGUE)), rel=1e-10)
    assert (int(n), int(t), int(size)) == (740, 740, 2)


# --- gmsh and meshio -----------------------------------------------------------------------


def _gmsh_box(path, hexes):
    import gmsh

    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        box = gmsh.model.occ.addBox(0, 0, 0, 0.2, 0.1, 0.05)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [box], tag=7)
        gmsh.model.addPhysicalGroup(2, [t for _, t in gmsh.model.getEntities(2)], tag=1)
        if hexes:
            for _, tag in gmsh.model.getEntities(1):
                gmsh.model.mesh.setTransfiniteCurve(tag, 4)
            for dim, tag in gmsh.model.getEntities(2):
                gmsh.model.mesh.setTransfiniteSurface(tag)
                gmsh.model.mesh.setRecombine(dim, tag)
            gmsh.model.mesh.setTransfiniteVolume(box)
        else:
            gmsh.option.setNumber("Mesh.MeshSizeMax", 0.04)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


@pytest.mark.parametrize("hexes", [False, True])
def test_gmsh_box(tmp_path, hexes):
    path = tmp_path / "box.msh"
    _gmsh_box(path, hexes)
    mesh = read_mesh(path)
    assert mesh.cell_type == ("hexahedron" if hexes else "tetrahedron")
    if hexes:
        assert len(mesh.cells) == 27
    assert set(mesh.cell_tags) == {7}
    assert set(mesh.skipped_cells) == {"quad" if hexes else "triangle"}  # boundary group
    assert volume(mesh) == pytest.approx(0.2 * 0.1 * 0.05, rel=1e-12)
    msh, tags = to_dolfinx(mesh, MPI.COMM_SELF)
    assert dolfinx_volume(msh) == pytest.approx(1e-3, rel=1e-12)
    assert set(tags.values) == {7}


def test_geo_file(tmp_path):
    geo = tmp_path / "cyl.geo"
    geo.write_text(
        'SetFactory("OpenCASCADE");\nCylinder(1) = {0, 0, 0, 0, 0, 0.1, 0.02};\n'
        "Physical Volume(3) = {1};\n"
    )
    mesh = read_mesh(geo, gmsh_mesh_size=0.01)
    assert mesh.cell_type == "tetrahedron" and set(mesh.cell_tags) == {3}
    exact = np.pi * 0.02**2 * 0.1
    assert 0.95 * exact < volume(mesh) < exact  # inscribed polygonal cylinder


def test_reading_a_geo_file_leaves_gmsh_as_it_found_it(tmp_path):
    """The reader finalizes gmsh only if it initialized it: a caller's session, its models,
    its current model and its options outlive the read."""
    import gmsh

    geo = tmp_path / "box.geo"
    geo.write_text('SetFactory("OpenCASCADE");\nBox(1) = {0, 0, 0, 0.1, 0.1, 0.1};\n')
    assert not gmsh.isInitialized()
    read_mesh(geo, gmsh_mesh_size=0.05)
    assert not gmsh.isInitialized()  # started and finalized by the reader
    gmsh.initialize(interruptible=False)
    try:
        gmsh.model.add("caller")
        gmsh.model.occ.addSphere(0, 0, 0, 1.0)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.3)
        models = gmsh.model.list()  # ["", "caller"]: initialize made the first
        read_mesh(geo, gmsh_mesh_size=0.05)
        assert gmsh.isInitialized() and gmsh.model.list() == models
        assert gmsh.model.getCurrent() == "caller" and gmsh.model.getEntities(3) == [(3, 1)]
        assert gmsh.option.getNumber("Mesh.MeshSizeMax") == 0.3
    finally:
        gmsh.finalize()


def test_a_planar_mesh_is_refused_for_its_2d_points(tmp_path):
    path = tmp_path / "square.mesh"  # medit keeps the dimension
    points = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    meshio.write(path, meshio.Mesh(points, [("triangle", np.array([[0, 1, 2], [0, 2, 3]]))]))
    with pytest.raises(MeshError, match="points are 2D; a volume mesh needs 3D points"):
        read_mesh(path)


def test_vtu_round_trip(tmp_path, tongue):
    path = tmp_path / "tongue.vtu"
    meshio.write(
        path,
        meshio.Mesh(
            tongue.points,
            [("hexahedron", tongue.cells)],
            cell_data={"material": [tongue.cell_tags]},
        ),
    )
    back = read_mesh(path)
    np.testing.assert_array_equal(back.points, tongue.points)
    np.testing.assert_array_equal(back.cells, tongue.cells)
    np.testing.assert_array_equal(back.cell_tags, tongue.cell_tags)


def test_mixed_mesh_reported_not_converted(tmp_path):
    points = np.vstack([UNIT_HEX, [[0.5, 0.5, 2.0]]])
    path = tmp_path / "mixed.vtu"
    meshio.write(
        path,
        meshio.Mesh(
            points,
            [
                ("hexahedron", [list(range(8))]),
                ("tetra", [[4, 5, 7, 8]]),
                ("triangle", [[0, 1, 2]]),
            ],
        ),
    )
    mesh = read_mesh(path)
    assert mesh.is_mixed and mesh.skipped_cells == {"triangle": 1}
    with pytest.raises(MeshError, match="single cell type"):
        to_dolfinx(mesh, MPI.COMM_SELF)
    info = mesh_info.describe(mesh)
    assert info["elements"] == {"hexahedron": 1, "tetrahedron": 1}
    assert info["volume"] == pytest.approx(1.0 + 1.0 / 6.0)


def test_unknown_extension():
    with pytest.raises(MeshError, match=r"unknown mesh file extension '\.foo'.*\.node"):
        read_mesh("mesh.foo")


# --- mesh info -----------------------------------------------------------------------------


def test_mesh_info_tongue(tongue):
    info = mesh_info.mesh_info([str(TONGUE), str(TONGUE.with_suffix(".elem"))])
    assert len(info) == 1  # the .node/.elem pair is one mesh
    t = info[str(TONGUE)]
    assert t["nodes"] == 946 and t["unused_nodes"] == 0
    assert t["elements"] == {"hexahedron": 740}
    assert t["cell_tags"] == {1: 740}
    assert t["volume"] == pytest.approx(surface_volume(tongue), rel=1e-10)  # ~102 cm^3
    np.testing.assert_allclose(t["bounding_box"]["min"], [0.05694847, -0.0324696, 0.0546162])
    np.testing.assert_allclose(t["bounding_box"]["max"], [0.130989, 0.03246955, 0.1139774])
    assert t["min_det_j"]["element"] == 146 and t["min_det_j"]["value"] > 0
    assert 0 < t["min_det_j_ratio"]["value"] < 1
    assert t["inverted"]["count"] == t["tangled"]["count"] == t["degenerate"]["count"] == 0


def test_mesh_info_cli(capsys, tmp_path):
    parser = argparse.ArgumentParser()
    mesh_info.add_arguments(parser)
    assert mesh_info.run(parser.parse_args([str(TONGUE), "--json"])) == 0
    assert json.loads(capsys.readouterr().out)[str(TONGUE)]["nodes"] == 946
    assert mesh_info.run(parser.parse_args([str(TONGUE)])) == 0
    assert "740 hexahedron" in capsys.readouterr().out
    assert mesh_info.run(parser.parse_args([str(tmp_path / "missing.msh")])) == 1
    assert "missing.msh" in capsys.readouterr().err


# --- results and rendering -----------------------------------------------------------------


def test_result_writer(tmp_path, tongue):
    msh, _ = to_dolfinx(tongue, MPI.COMM_SELF)
    u = fem.Function(fem.functionspace(msh, ("Lagrange", 1, (3,))), name="displacement")
    rows = msh.geometry.x.shape[0]
    with ResultWriter(tmp_path / "out" / "tongue", u) as writer:
        for t in (0.0, 0.1):
            u.x.array[:] = t * (1.0 + np.arange(u.x.array.size))  # distinct values per dof
            writer.write(t)
    assert writer.path.parent == tmp_path / "out"
    series = read_series(writer.path)
    np.testing.assert_array_equal(series.times, [0.0, 0.1])
    assert "displacement" in series.fields
    assert np.all(series.at("displacement", 0) == 0.0)
    assert same_rows(series.at("displacement"), u.x.array.reshape(rows, 3))


def test_render_png(tmp_path, tongue):
    """Two bodies side by side, into a directory two levels deep that does not exist yet;
    one body given as a bare (mesh, displacement) pair is drawn as the one-body list."""
    import pyvista as pv

    msh, _ = to_dolfinx(tongue, MPI.COMM_SELF)
    u = fem.Function(fem.functionspace(msh, ("Lagrange", 1, (3,))))
    u.interpolate(lambda x: np.vstack([0 * x[0], 0 * x[0], 0.2 * (x[0] - 0.057)]))
    bare, listed = (
        render_bodies(tmp_path / name, body, window_size=(300, 200))
        for name, body in (("bare.png", (msh, u)), ("listed.png", [(msh, u)]))
    )
    a, b = (np.asarray(pv.read(p).point_data.active_scalars, dtype=float) for p in (bare, listed))
    assert a.shape == b.shape and (np.abs(a - b) > 0.1).mean() < 0.01  # the same picture
    png = render_bodies(
        tmp_path / "img" / "tongue" / "tongue.png",
        [msh, (msh, u)],
        scalars=[None, "displacement"],
        titles=["rest", "deformed"],
        show_rest=True,
        window_size=(600, 400),
    )
    assert png.stat().st_size > 10_000
    pixels = np.asarray(pv.read(png).point_data.active_scalars)
    assert pixels.std() > 10  # not a blank image


@pytest.mark.parametrize("where", ["nodes", "cells"])
def test_render_colors_a_body_by_an_array_of_values(tmp_path, tongue, where):
    """An array of one value per node or per cell colors the body with the colormap and a
    color bar: viridis' yellow end (253, 231, 37) is in the picture, and not in the same
    body drawn without values (one flat color)."""
    import pyvista as pv

    msh, _ = to_dolfinx(tongue, MPI.COMM_SELF)
    n = msh.geometry.x.shape[0] if where == "nodes" else msh.topology.index_map(3).size_local
    values = np.linspace(0.0, 1.0, n)

    def yellow_pixels(png):
        rgb = np.asarray(pv.read(png).point_data.active_scalars, dtype=float)[:, :3]
        return int((np.abs(rgb - [253, 231, 37]).max(axis=1) < 30).sum())

    colored = render_bodies(tmp_path / "colored.png", msh, scalars=values, window_size=(600, 400))
    plain = render_bodies(tmp_path / "plain.png", msh, window_size=(600, 400))
    assert yellow_pixels(colored) > 50 and yellow_pixels(plain) == 0


def test_render_draws_rigid_surfaces_beside_the_bodies(tmp_path, tongue, icosphere):
    """``surfaces``: a triangle surface (a rigid ball under the tongue) drawn in the view:
    the picture changes, and the view takes in the surface's extent."""
    import pyvista as pv

    msh, _ = to_dolfinx(tongue, MPI.COMM_SELF)
    vertices, triangles = icosphere(2, 0.02)
    ball = (vertices + [0.05, 0.0, -0.04], triangles)
    plain = render_bodies(tmp_path / "plain.png", msh, window_size=(600, 400), camera="xz")
    with_ball = render_bodies(
        tmp_path / "ball.png", msh, window_size=(600, 400), camera="xz", surfaces=[ball]
    )
    a = np.asarray(pv.read(plain).point_data.active_scalars, dtype=float)
    b = np.asarray(pv.read(with_ball).point_data.active_scalars, dtype=float)
    assert a.shape == b.shape and np.abs(a - b).mean() > 1.0


def test_node_and_cell_rows_by_file_id(tongue):
    rows = tongue.node_rows([1, 920, 946])
    assert np.array_equal(tongue.node_ids[rows], [1, 920, 946])
    assert np.array_equal(tongue.cell_ids[tongue.cell_rows([740, 1])], [740, 1])
    with pytest.raises(MeshError, match="node ids not in the mesh: \\[947\\]"):
        tongue.node_rows([5, 947])


@pytest.mark.parametrize("bad", [-1, 8], ids=["negative", "past the last point"])
def test_cells_indexing_outside_the_points_are_refused(bad):
    """Either end of the range alone is an error: an index below 0, or one at or past the
    point count (8 points of the unit hexahedron)."""
    cells = np.arange(8)
    cells[3] = bad
    with pytest.raises(MeshError, match="cell connectivity indexes outside the 8 points"):
        hex_mesh(cells)
