"""Embedded meshes on 2 MPI ranks equal the serial run.

The same script runs serially and under ``mpiexec -n 2``: a box body (hexahedra,
then tetrahedra), points inside, on faces and nodes of the mesh (shared by the
ranks' cells), outside (snapped), and a triangle surface that pokes out of the
body. Under a nonlinear displacement field the embedded positions must agree
with the serial run to round-off (1e-12 relative), an affine field must be
reproduced exactly, and the virtual work of random point forces, summed over
the ranks' owned dofs, must equal f . v on 2 ranks (the ghosts' shares reach their
owners). Every rank must hold the same
gathered arrays. With ``snap=False`` an outside point must raise
OutsideMeshError on every rank, with the same message (no hang: a timeout).
"""

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

MPIEXEC = Path(sys.executable).parent / "mpiexec"

SCRIPT = textwrap.dedent('''
    import json, sys
    import artifem  # noqa: F401  (before dolfinx)
    import numpy as np
    import pyvista as pv
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    from artifem.embedding import EmbeddedMesh, OutsideMeshError
    from artifem.fem_body import FemBody
    from artifem.forms import NeoHookean

    comm = MPI.COMM_WORLD
    A = np.array([[0.1, -0.2, 0.05], [0.3, 0.02, -0.1], [0.0, 0.15, -0.05]])
    C = np.array([0.01, -0.02, 0.03])
    SIZE = np.array([1.0, 0.9, 0.8])

    def body_of(cell_type):
        msh = dmesh.create_box(comm, [np.zeros(3), SIZE], [6, 5, 4],
                               getattr(dmesh.CellType, cell_type))
        return FemBody(msh, NeoHookean.from_young_poisson(1.0e4, 0.3), 1000.0)

    def same_on_all_ranks(a):
        return bool(all(np.array_equal(a, b) for b in comm.allgather(a)))

    if sys.argv[2] == "outside":
        body = body_of("hexahedron")
        try:
            EmbeddedMesh(body, np.array([[0.5, 0.45, 0.4], [1.3, 0.45, 0.4]]))
            message = "no error"
        except OutsideMeshError as e:
            message = str(e)
        with open(f"{sys.argv[1]}.{comm.rank}", "w") as f:
            f.write(message)
        sys.exit(0)

    rng = np.random.default_rng(0)
    inside = (0.02 + 0.96 * rng.random((300, 3))) * SIZE
    on_mesh = np.array([[0.5, 0.45, 0.4], [0.5, 0.36, 0.3], [1 / 3, 0.54, 0.2],
                        [0.5, 0.9, 0.8], [0.5, 0.1, 0.0]])       # nodes, faces, boundary
    outside = np.array([[1.2, 0.5, 0.4], [-0.3, -0.4, 0.4], [1.1, 1.0, 1.1],
                        [0.5, 0.45, -0.25], [0.5, -0.2, 0.3]])
    points = np.vstack([inside, on_mesh, outside])
    s = pv.Sphere(radius=0.3, center=(0.5, 0.45, 0.65), theta_resolution=12,
                  phi_resolution=12).triangulate().clean()
    sphere, tris = np.asarray(s.points, dtype=float), s.faces.reshape(-1, 4)[:, 1:]

    result = {"ranks": comm.size}
    for cell_type in ("hexahedron", "tetrahedron"):
        body = body_of(cell_type)
        n3 = 3 * body.V.dofmap.index_map.size_local
        emb = EmbeddedMesh(body, points, snap=True)
        surface = EmbeddedMesh(body, sphere, tris, "triangle", snap=True)
        weights = np.concatenate([emb.G.data, surface.G.data])
        out = {"owned": comm.allgather(int(emb.owned.size)),
               "rows": comm.allreduce(emb.G.shape[0]),
               "weights": [comm.allreduce(weights.min(), MPI.MIN),
                           comm.allreduce(weights.max(), MPI.MAX)],
               "distance": emb.distance.tolist(),
               "surface_distance": surface.distance.tolist(),
               "rest": emb.rest_positions.tolist()}
        body.u.interpolate(lambda x: np.vstack([0.1 * np.sin(2 * x[1]) * x[2],
                                                0.05 * x[0] ** 2 + 0.02 * x[1] * x[2],
                                                0.03 * np.cos(3 * x[0]) * x[1]]))
        body.u.x.scatter_forward()
        out["positions"] = emb.positions().tolist()
        out["surface"] = surface.positions().tolist()
        out["same_on_all_ranks"] = all(same_on_all_ranks(a) for a in (
            np.array(out["positions"]), np.array(out["surface"]), emb.distance,
            emb.rest_positions, surface.rest_positions))
        body.u.interpolate(lambda x: A @ x + C[:, None])
        body.u.x.scatter_forward()
        out["affine_error"] = max(
            float(np.abs(e.positions() - (e.rest_positions @ (np.eye(3) + A).T + C)).max())
            for e in (emb, surface))
        # An oscillating velocity field of the node's position (not of its number, as f is of
        # the point's index): the same on any number of ranks.
        K = np.array([[13.1, -7.3, 9.7], [-5.9, 11.3, 8.1], [7.7, 6.1, -12.9]])
        body.v.interpolate(lambda x: np.sin(K @ x + np.arange(3)[:, None]))
        body.v.x.scatter_forward()
        for name, e in (("points", emb), ("surface", surface)):
            f = np.random.default_rng(1).standard_normal((e.num_points, 3))
            f_nodes = e.force_to_nodes(f)
            assert f_nodes.shape == (n3,)
            out[f"work_{name}"] = float(np.sum(f * e.velocities()))
            out[f"work_nodes_{name}"] = comm.allreduce(float(f_nodes @ body.v.x.array[:n3]))
            out[f"force_{name}"] = (comm.allreduce(f_nodes.reshape(-1, 3).sum(axis=0))
                                    - f.sum(axis=0)).tolist()
        result[cell_type] = out
    if comm.rank == 0:
        with open(sys.argv[1], "w") as f:
            json.dump(result, f)
''')


def run(tmp_path: Path, ranks: int, mode: str = "embed"):
    script = tmp_path / "embedding_mpi.py"
    script.write_text(SCRIPT)
    out = tmp_path / f"{mode}_{ranks}.json"
    command = [sys.executable, str(script), str(out), mode]
    if ranks > 1:
        command = [str(MPIEXEC), "-n", str(ranks)] + command
    proc = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, f"{' '.join(command)} failed:\n{proc.stdout}\n{proc.stderr}"
    if mode == "outside":
        return [Path(f"{out}.{r}").read_text() for r in range(ranks)]
    return json.loads(out.read_text())


needs_mpiexec = pytest.mark.skipif(
    not MPIEXEC.exists(), reason=f"no mpiexec next to the interpreter ({MPIEXEC})"
)


@needs_mpiexec
def test_two_ranks_equal_serial(tmp_path):
    serial, parallel = run(tmp_path, 1), run(tmp_path, 2)
    assert serial["ranks"] == 1 and parallel["ranks"] == 2
    for cell_type in ("hexahedron", "tetrahedron"):
        s, p = serial[cell_type], parallel[cell_type]
        n = len(s["rest"])
        assert len(p["owned"]) == 2 and min(p["owned"]) > 0 and sum(p["owned"]) == n
        assert s["rows"] == p["rows"] == 3 * n
        assert p["same_on_all_ranks"]
        for r in (s, p):
            assert -1e-12 < r["weights"][0] and r["weights"][1] < 1 + 1e-12
            assert r["affine_error"] < 1e-13, cell_type
            np.testing.assert_allclose(r["force_points"], 0.0, atol=1e-11)
        # On 2 ranks the nodal forces G^T f, summed over each rank's owned dofs, do the
        # work of f on the gathered velocities G v only if the ghosts' shares reached their
        # owners (scatter_reverse). (On one rank it is G^T f . v = f . G v, true for any G:
        # the velocities themselves are checked against DOLFINx's point evaluation in
        # test_embedding, and their work here against the serial run.)
        for name in ("points", "surface"):
            assert p[f"work_nodes_{name}"] == pytest.approx(p[f"work_{name}"], rel=1e-12)
        np.testing.assert_allclose(
            s["distance"][-5:], [0.2, 0.5, np.sqrt(0.11), 0.25, 0.2], atol=1e-12
        )
        np.testing.assert_allclose(s["distance"][:-5], 0.0, atol=0)
        assert max(s["surface_distance"]) > 0.1  # the sphere pokes out of the box
        for key in ("distance", "surface_distance", "rest", "positions", "surface"):
            a, b = np.array(s[key]), np.array(p[key])
            np.testing.assert_allclose(
                b, a, rtol=0, atol=1e-12 * np.abs(a).max(), err_msg=f"{cell_type} {key}"
            )
        for key in ("work_points", "work_surface"):
            assert p[key] == pytest.approx(s[key], rel=1e-12), key


@needs_mpiexec
def test_outside_point_raises_on_every_rank(tmp_path):
    serial, parallel = run(tmp_path, 1, "outside"), run(tmp_path, 2, "outside")
    assert serial[0].startswith("1 embedded point(s) lie outside FEM body")
    assert "point 1 at distance 0.3" in serial[0]
    assert parallel == [serial[0], serial[0]]
