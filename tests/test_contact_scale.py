"""Many contact rows (artifem.scene.constraints): the sparse KKT path and the Schur
complement give the same velocities and impulses (many rows, friction bounds from the
impulses, redundant rows); the active set warm-started from the last solve's rows (row
keys) gives the same answer in fewer trials; the many-at-once active set settles an FEM
block resting on ~100 rows in a few trials; ``artifem bench contact --quick`` writes its
JSON and finds both paths alike."""

import json

import numpy as np
import pytest
from scipy import sparse

import artifem as af  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.multibody.constraint_rows import Friction, RowBlock
from artifem.scene import constraints
from artifem.scene.constraints import ActiveSetMemory, StepRows, solve_constrained, use_kkt
from artifem.scene.direct_solver import DirectSolver

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial solves")

H, G = 0.01, 9.81


class _Owner:
    name = "points"


def _points_problem(rng, nodes=200, contacts=60, mu=0.5, redundant=0):
    """Point masses (3 dofs each) chained by springs (A = M + h^2 K, sparse SPD, 3 nodes
    > DENSE_MAX dofs), pushed down and sideways; ``contacts`` of them on a floor: a normal
    row on z ([0, inf), c from a random gap: some reach the floor, some not) and, with mu,
    friction rows on x and y (|lambda_t| <= mu lambda_n); ``redundant`` normal rows
    repeated (two rows on the same dof)."""
    n = 3 * nodes
    m_i = 1.0 + rng.random(n)
    chain = sparse.diags([-np.ones(n - 3), 2 * np.ones(n), -np.ones(n - 3)], [-3, 0, 3])
    A = sparse.csr_matrix(sparse.diags(m_i) + H * H * 1e3 * chain)
    b = H * np.concatenate([[0.3 * G, -0.1 * G, -G] * nodes]) * np.repeat(
        m_i[::3], 3
    ) + 1e-3 * rng.standard_normal(n)
    idx = np.sort(rng.choice(nodes, contacts, replace=False))
    idx = np.concatenate([idx, idx[:redundant]])
    k = len(idx)
    dirs = [2, 0, 1] if mu > 0 else [2]
    cols = np.concatenate([3 * idx + d for d in dirs])
    Gm = sparse.csr_matrix((np.ones(len(cols)), (np.arange(len(cols)), cols)), shape=(len(cols), n))
    gap = rng.uniform(-0.5, 1.5, k) * G * H * H  # phi: within reach or not
    gap[k - redundant :] = gap[:redundant]  # a repeated row's own phi
    c = np.concatenate([-gap / H, np.zeros(len(cols) - k)])
    lo, hi = np.zeros(len(cols)), np.zeros(len(cols))
    hi[:k] = np.inf

    keys = np.column_stack([np.tile(np.arange(k), len(dirs)), np.repeat(np.arange(len(dirs)), k)])
    block = RowBlock(
        _Owner(),
        np.zeros(len(cols)),
        ((None, Gm),),
        lo,
        hi,
        lambda lam: None,
        Friction.tangents(k, mu) if mu > 0 else None,
        keys,
    )
    return A, b, [StepRows(block, Gm, c)]


def _solve(A, b, rows, path, memory=None):
    info = {}
    z, lam, active = solve_constrained(
        DirectSolver(), A, b, rows, "test", path=path, memory=memory, info=info
    )
    return z, lam, active, info


@pytest.mark.parametrize("mu", [0.0, 0.5])
def test_kkt_and_schur_give_the_same_velocities_and_impulses(rng, mu):
    """60 contacts on 200 point masses (600 dofs, 60 or 180 rows): the sparse KKT (MUMPS)
    and the Schur complement find the same z and lambda to 1e-10 (relative), some rows
    active, some held at a bound; the rule picks the KKT path here."""
    A, b, rows = _points_problem(rng, mu=mu)
    z1, lam1, n1, info1 = _solve(A, b, rows, "kkt")
    z2, lam2, n2, info2 = _solve(A, b, rows, "schur")
    assert (info1["path"], info2["path"]) == ("kkt", "schur")
    assert use_kkt(A, len(rows[0].c)) == (len(rows[0].c) >= constraints.KKT_ROWS)
    assert 0 < n1 == n2 < len(lam1)
    np.testing.assert_allclose(z1, z2, rtol=0, atol=1e-10 * np.abs(z2).max())
    np.testing.assert_allclose(lam1, lam2, rtol=0, atol=1e-10 * np.abs(lam2).max())
    if mu:  # some friction rows slide (held at the bound)
        k = 60
        cap = mu * lam2[:k]
        assert np.any(np.isclose(np.abs(lam2[k : 2 * k]), cap) & (cap > 0))


def test_kkt_low_rank_updates_give_the_factorizations_answer(rng, monkeypatch):
    """The sparse KKT path's trials whose active set differs from the last factored one by
    a few rows (friction rows sliding in one pass, sticking in the next) correct that
    factorization by Sherman-Morrison-Woodbury instead of a new one: the same z and lambda
    as with a factorization for every set (KKT_UPDATE_ROWS = 0), to 1e-11, with fewer
    factorizations."""
    A, b, rows = _points_problem(rng)
    z1, lam1, _, info1 = _solve(A, b, rows, "kkt")
    monkeypatch.setattr(constraints, "KKT_UPDATE_ROWS", 0)
    z2, lam2, _, info2 = _solve(A, b, rows, "kkt")
    assert info1["updates"] > 0 and info2["updates"] == 0
    assert info1["factorizations"] < info2["factorizations"]
    np.testing.assert_allclose(z1, z2, rtol=0, atol=1e-11 * np.abs(z2).max())
    np.testing.assert_allclose(lam1, lam2, rtol=0, atol=1e-11 * np.abs(lam2).max())


@pytest.mark.parametrize("agree", [True, False])
def test_redundant_rows_solve_alike_on_both_paths(rng, agree):
    """10 normal rows repeated (two rows on one dof, lambda not unique), with friction: the
    same velocities and the same forces G^T lambda on both paths; the KKT's regularized
    multiplier block shares each pair's impulse (halves to 1e-5; the Schur's one row at a
    time activates one row of a pair, the other satisfied at 0). Pairs
    whose phi disagree (no z meets both): the KKT's refinement cannot converge and the
    solve falls back to the Schur complement's least squares."""
    A, b, rows = _points_problem(rng, redundant=10)
    if not agree:
        g = rows[0]
        c = g.c.copy()
        c[60:70] += 1e-3
        rows = [StepRows(g.block, g.G, c)]
    Gm = rows[0].G
    z1, lam1, _, info = _solve(A, b, rows, "kkt")
    assert info["path"] == ("kkt" if agree else "schur")
    z2, lam2, _, _ = _solve(A, b, rows, "schur")
    np.testing.assert_allclose(z1, z2, rtol=0, atol=1e-10 * np.abs(z2).max())
    f1, f2 = Gm.T @ lam1, Gm.T @ lam2
    np.testing.assert_allclose(f1, f2, rtol=0, atol=1e-10 * np.abs(f2).max())
    assert lam1[:70].min() >= 0 and lam2[:70].min() >= 0
    if agree:
        np.testing.assert_allclose(lam1[60:70], lam1[:10], rtol=1e-5)


@pytest.mark.parametrize("path", ["kkt", "schur"])
def test_warm_start_gives_the_same_answer_in_fewer_trials(rng, path):
    """The next step's problem (c and b a little changed) from the last solve's active set
    (ActiveSetMemory, by row keys): the same z and lambda as from cold, in fewer trials
    (counted, with friction: the KKT's many at once from 6 trials to 3, the Schur's one
    row at a time from 46 to 2: one per pass of the friction bounds, and the KKT's last
    pass again, refined, with the bounds of the refined impulses)."""
    A, b, rows = _points_problem(rng, contacts=40)
    memory = ActiveSetMemory()
    _solve(A, b, rows, path, memory)  # the last step
    g = rows[0]
    nxt = [StepRows(g.block, g.G, g.c * 1.01)]
    z_cold, lam_cold, _, cold = _solve(A, b * 1.01, nxt, path)
    z_warm, lam_warm, _, warm = _solve(A, b * 1.01, nxt, path, memory)
    np.testing.assert_allclose(z_warm, z_cold, rtol=0, atol=1e-11 * np.abs(z_cold).max())
    np.testing.assert_allclose(lam_warm, lam_cold, rtol=0, atol=1e-11 * np.abs(lam_cold).max())
    assert warm["trials"] < cold["trials"]
    assert (cold["trials"], warm["trials"]) == {"kkt": (6, 3), "schur": (46, 2)}[path]


def test_many_rows_at_once_settle_a_resting_block():
    """An FEM block of 9 x 9 x 2 hexahedra (300 nodes, 900 dofs) put on a plane by its 100
    bottom nodes: the rule takes the KKT path; the first step's active set (cold) takes all
    100 rows in one trial (2 trials; one row per trial would take 101), the later steps
    start from the last one's (1 trial, 1 factorization); the velocities equal the Schur
    path's to round-off and the normal forces bear the block: on both paths they are the
    last step's momentum balance, H sum N = dP_z + H (m g + alpha P_z) with the Rayleigh
    term at the step's end momentum (alpha = 10; measured to 1e-14, the bound 1e-9)."""
    from artifem.bench_contact import fem_scene, forced_path

    runs = {}
    for path in (None, "schur"):
        scene, body, pc = fem_scene((9, 9, 2), None)
        trials = []
        with forced_path(path):
            for _ in range(4):
                before = scene.momentum()[2]
                scene.step(H)
                trials.append(scene.last_solve["trials"])
        after = scene.momentum()[2]
        # gravity along -z, a frictionless plane: nothing pushes the block sideways
        sideways = np.abs(scene.momentum()[:2]).max()
        assert sideways <= 1e-12 * body.total_mass() * G * H, sideways
        balance = after - before + H * (body.total_mass() * G + 10.0 * after)
        assert H * scene.contact_forces(pc).normal.sum() == pytest.approx(balance, rel=1e-9)
        runs[path] = (
            body.v.x.array.copy(),
            scene.contact_forces(pc),
            trials,
            scene.last_solve["path"],
        )
    v, forces, trials, taken = runs[None]
    assert taken == "kkt" and runs["schur"][3] == "schur"
    assert forces.normal.size == 100 and np.all(forces.normal > 0)  # every node presses
    assert trials == [2, 1, 1, 1]
    assert runs["schur"][2][0] == 101
    np.testing.assert_allclose(v, runs["schur"][0], rtol=0, atol=1e-10 * G * H)
    np.testing.assert_allclose(forces.normal, runs["schur"][1].normal, rtol=1e-9)


def test_bench_contact_quick_writes_its_json(tmp_path):
    """``artifem bench contact --quick``: the cases of the three kinds with the parts of the
    step, the no-contact references, and the KKT and Schur paths alike."""
    from artifem.cli import main

    out = tmp_path / "contact.json"
    assert (
        main(["bench", "contact", "--quick", "--steps", "1", "--warmup", "1", "--out", str(out)])
        == 0
    )
    report = json.loads(out.read_text())
    assert report["benchmark"] == "contact"
    kinds = {c["kind"] for c in report["cases"]}
    assert kinds == {"rigid", "fem", "plate"}
    for case in report["cases"]:
        for key in (
            "rows",
            "active_rows",
            "path",
            "step_ms",
            "detection_ms",
            "mapping_ms",
            "solve_ms",
            "trials_per_step",
            "ratio_to_no_contact",
        ):
            assert key in case
    assert any(c["path"] == "kkt" for c in report["cases"])
    agree = report["agreement"]
    assert agree["fem"]["paths"] == ["kkt", "schur"]
    assert agree["fem"]["velocity_over_gh"] < 1e-10
    assert agree["fem"]["normal_rel"] < 1e-10 and agree["fem"]["friction_rel"] < 1e-10
    assert agree["rigid"]["velocity_over_gh"] < 1e-10
    assert agree["rigid"]["total_normal_rel"] < 1e-10


def test_a_block_landing_and_sliding_on_an_incline_is_the_same_on_both_paths(sliding_block):
    """A 6 x 6 x 3 hex block (196 nodes, 588 dofs: MUMPS) thrown sideways at 0.3 m/s onto a
    plane tilted by 11 degrees, mu = 0.3: it lands, its rows grow from 0 to 219 (73 nodes
    within the margin, with friction) and it slides; over 40 steps of 5 ms the KKT path and the
    Schur complement give the same velocities (measured: 1e-15 m/s against 2e-4 m/s), the
    same normal and friction forces (1e-14 N against 0.15 N)."""
    from artifem.bench_contact import forced_path

    runs = {}
    for path in ("kkt", "schur"):
        scene, body, pc = sliding_block(0.004)
        with forced_path(path):
            for _ in range(40):
                scene.step(0.005)
        assert scene.last_solve["path"] == path
        runs[path] = (body.v.x.array.copy(), scene.contact_forces(pc))
    (v1, f1), (v2, f2) = runs["kkt"], runs["schur"]
    assert len(f2.normal) == 73 and np.count_nonzero(f2.normal) > 30
    assert np.abs(v2).max() > 1e-4
    np.testing.assert_allclose(v1, v2, rtol=0, atol=1e-10 * G * H)
    np.testing.assert_allclose(f1.normal, f2.normal, rtol=0, atol=1e-10 * f2.normal.max())
    np.testing.assert_allclose(f1.friction, f2.friction, rtol=0, atol=1e-10 * f2.normal.max())


def test_the_rigid_benchmark_box_rests_on_a_grid_spanning_its_bottom_face():
    """``bench contact``'s rigid case (``rigid_scene(n)``): n x n contact points on the
    plane spanning the box's bottom face, read from its rows: a point r from the centre of
    mass pushes along n = z with the twist row (n, r x n) = (0, 0, 1, y, -x, 0)."""
    from artifem.bench_contact import BOX, rigid_scene

    _, box, pc = rigid_scene(5)
    (block,) = pc.row_blocks()
    ((body, G),) = block.jacobians
    G = G.toarray() if hasattr(G, "toarray") else np.asarray(G)
    assert body is box and G.shape == (25, 6)
    np.testing.assert_array_equal(block.phi, 0.0)  # every point on the plane
    np.testing.assert_array_equal(G[:, :3], np.tile([0.0, 0.0, 1.0], (25, 1)))
    points = {(round(-x, 12), round(y, 12)) for y, x in G[:, 3:5]}
    s = np.linspace(-0.5, 0.5, 5)
    assert points == {(round(x * BOX[0], 12), round(y * BOX[1], 12)) for x in s for y in s}
