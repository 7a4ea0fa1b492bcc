"""A 2-rank MPI run of an FEM body equals the serial run.

The same script (box beam, neo-Hookean bulk, a muscle in its upper half,
gravity; 10 semi-implicit steps then 3 implicit steps, each in a Scene where the
body is an island of its own, its PETSc solver distributed) runs serially and under
``mpiexec -n 2``; node and cell arguments are input indices, so the script is
identical on any number of ranks. Displacements of a few input nodes and the
total energy must agree to 1e-8 relative (a direct solver on both sides; the
differences are round-off in the order of summation), and every node of the box is its
own nearest node on either.
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
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    from artifem.fem_body import FemBody
    from artifem.forms import BlemkerFiber, NeoHookean
    from artifem.scene import Scene

    comm = MPI.COMM_WORLD
    L, W, H = 1.0, 0.3, 0.2
    msh = dmesh.create_box(comm, [np.zeros(3), np.array([L, W, H])], [8, 3, 2],
                           dmesh.CellType.hexahedron)
    body = FemBody(msh, NeoHookean.from_young_poisson(2.0e4, 0.3), 1000.0,
                   rayleigh=(0.5, 0.002), gravity=(0.0, 0.0, -9.81))

    def gather_inputs(mask):
        local = np.asarray(msh.geometry.input_global_indices)[mask]
        return np.unique(np.concatenate(comm.allgather(local))).astype(np.int64)

    x = msh.geometry.x
    body.fix_nodes(gather_inputs(x[:, 0] < 1e-12))
    tdim = msh.topology.dim
    n_owned = msh.topology.index_map(tdim).size_local
    centroids = x[msh.geometry.dofmaps[0][:n_owned]].mean(axis=1)
    cells = np.asarray(msh.topology.original_cell_index[:n_owned])[centroids[:, 2] > H / 2]
    cells = np.unique(np.concatenate(comm.allgather(cells)))
    body.add_muscle("top", cells, [1.0, 0.0, 0.0], BlemkerFiber(5.0e3), excitation=0.3)

    tip = gather_inputs(np.abs(x[:, 0] - L) < 1e-12)
    mid = gather_inputs((np.abs(x[:, 0] - L / 2) < 1e-12) & (np.abs(x[:, 2] - H) < 1e-12))
    probes = np.concatenate([tip, mid])

    # The body's gravity (Scene.add sets the body's gravity to the scene's).
    semi = Scene(gravity=(0.0, 0.0, -9.81), integrator="semi-implicit", linear_solver="mumps")
    semi.add(body)
    islands = semi.islands()
    assert islands == ([body], []), islands     # stepped on its own: distributed
    for _ in range(10):
        semi.step(0.01)
    after_semi = body.displacement_at(probes)
    energy_semi = semi.energy()
    implicit = Scene(gravity=(0.0, 0.0, -9.81), integrator="implicit", linear_solver="mumps")
    implicit.add(body)
    for _ in range(3):
        implicit.step(0.01)
    lattice = [(L * i / 8, W * j / 3, H * k / 2)
               for i in range(9) for j in range(4) for k in range(3)]
    result = {
        "nearest": [body.nearest_node(point) for point in lattice],
        "ranks": comm.size,
        "probes": probes.tolist(),
        "after_semi": after_semi.tolist(),
        "energy_semi": energy_semi,
        "after_implicit": body.displacement_at(probes).tolist(),
        "energy_implicit": implicit.energy(),
        "time": semi.t + implicit.t,
        "halvings": semi.halvings + implicit.halvings,
        "cells_in_muscle": int(cells.size),
    }
    if comm.rank == 0:
        with open(sys.argv[1], "w") as f:
            json.dump(result, f)
''')


def run(tmp_path: Path, ranks: int) -> dict:
    script = tmp_path / "beam_mpi.py"
    script.write_text(SCRIPT)
    out = tmp_path / f"result_{ranks}.json"
    command = [sys.executable, str(script), str(out)]
    if ranks > 1:
        command = [str(MPIEXEC), "-n", str(ranks)] + command
    proc = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, f"{' '.join(command)} failed:\n{proc.stdout}\n{proc.stderr}"
    return json.loads(out.read_text())


@pytest.mark.slow
@pytest.mark.skipif(not MPIEXEC.exists(), reason=f"no mpiexec next to the interpreter ({MPIEXEC})")
def test_two_ranks_equal_serial(tmp_path):
    serial = run(tmp_path, 1)
    parallel = run(tmp_path, 2)
    assert serial["ranks"] == 1 and parallel["ranks"] == 2
    assert serial["probes"] == parallel["probes"] and len(serial["probes"]) >= 8
    assert serial["cells_in_muscle"] == parallel["cells_in_muscle"] == 24
    assert serial["halvings"] == parallel["halvings"]
    # each of the box's 108 nodes is its own nearest node, whichever rank holds it
    assert sorted(serial["nearest"]) == list(range(9 * 4 * 3))
    assert parallel["nearest"] == serial["nearest"]
    assert serial["time"] == pytest.approx(0.13) and parallel["time"] == pytest.approx(0.13)
    for key in ("after_semi", "after_implicit"):
        a, b = np.array(serial[key]), np.array(parallel[key])
        # Something happened: the beam sags and the muscle pulls the tip back.
        assert np.abs(a).max() > 1e-3
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-8 * np.abs(a).max(), err_msg=key)
    for key in ("energy_semi", "energy_implicit"):
        assert serial[key] != 0.0
        assert parallel[key] == pytest.approx(serial[key], rel=1e-8), key
