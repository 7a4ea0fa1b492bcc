"""Surface loads on FEM bodies (artifem.surface_loads): a follower pressure and a dead
traction, checked against closed-form solutions (an inflated thick sphere, a bar in
uniaxial tension), the consistency of their tangent and potential, Newton's quadratic
convergence, the three ways of choosing facets, and component-wise fixed nodes."""

import json
from pathlib import Path

import numpy as np
import pytest
import ufl

import artifem as af
from dolfinx import fem, mesh as dmesh
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc
from scipy import sparse
from scipy.optimize import brentq, fsolve

from artifem.integrators import ImplicitEuler, solve_static
from artifem.linear_solver import LinearSolver

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial checks")

#: scripts/static_newton_counts.py's figures (the larger cases of the static Newton)
STATIC_NEWTON = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "static_newton.json"


class LU:
    """A LinearSolver stand-in that factors by LU (the follower tangent is unsymmetric;
    LinearSolver's MUMPS Cholesky reads one triangle) and records each right-hand side's
    norm: solve_static passes -R, so ``norms`` are the Newton residuals."""

    def __init__(self):
        self.ksp = PETSc.KSP().create(MPI.COMM_SELF)
        self.ksp.setType("preonly")
        self.ksp.getPC().setType("lu")
        self.ksp.getPC().setFactorSolverType("mumps")
        self.norms = []

    def solve(self, A, b, x, rtol=None):  # a direct solve: no tolerance to take
        self.norms.append(b.norm())
        self.ksp.setOperators(A)
        self.ksp.solve(b, x)
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)


# ---- meshes and bodies --------------------------------------------------------------------


def symmetry_planes(body, planes=(0, 1, 2)) -> None:
    """u_k = 0 on the plane X_k = 0 (only that component)."""
    for k in planes:
        body.fix_nodes(body.find_nodes(lambda x, k=k: np.abs(x[k]) < 1e-9), components=(k,))


def box(n=(4, 2, 2), size=(2.0, 1.0, 1.0), cell=dmesh.CellType.hexahedron):
    return dmesh.create_box(MPI.COMM_SELF, [np.zeros(3), np.array(size)], list(n), cell)


def cantilever(name="beam"):
    """A soft cantilever (clamped at x = 0); its top face z = 0.2 is the loaded surface."""
    beam = af.FemBody(
        box((10, 2, 2), (1.0, 0.2, 0.2)),
        af.NeoHookean.from_young_poisson(1e5, 0.3),
        1000.0,
        gravity=(0, 0, 0),
        name=name,
    )
    beam.fix_nodes(beam.find_nodes(lambda x: x[0] < 1e-12))
    return beam


def top(x):
    return np.isclose(x[2], 0.2)


def residual(body) -> np.ndarray:
    body.assemble(tangent=False)
    return body.R.array.copy()


def tangent(body) -> np.ndarray:
    body.assemble(tangent=True, diag=1.0)
    ai, aj, av = body.K.getValuesCSR()
    return sparse.csr_matrix((av, aj, ai), shape=body.K.getSize()).toarray()


# ---- (a) the inflated thick sphere ---------------------------------------------------------


def inflation_pressure(la: float, mu: float, A: float, B: float) -> float:
    """Internal pressure of an incompressible neo-Hookean (W = mu/2 (I1 - 3)) thick sphere
    A <= R <= B whose inner radius is stretched by la = a / A (outer face free).

    Incompressibility: r^3 - R^3 = a^3 - A^3, so the hoop stretch l = r / R obeys
    lb^3 = 1 + (la^3 - 1) (A / B)^3 at R = B. Radial equilibrium
    d sigma_rr/dr = 2 (sigma_tt - sigma_rr) / r with sigma_tt - sigma_rr =
    mu (l^2 - l^-4), sigma_rr(a) = -p, sigma_rr(b) = 0, and dr / r = -dl / (l (l^3 - 1)):

        p = int_lb^la 2 mu (l^-2 + l^-5) dl = 2 mu (1/lb - 1/la) + mu/2 (lb^-4 - la^-4).
    """
    lb = (1.0 + (la**3 - 1.0) * (A / B) ** 3) ** (1.0 / 3.0)
    return 2 * mu * (1 / lb - 1 / la) + 0.5 * mu * (lb**-4 - la**-4)


def inflate(
    n: int,
    p: float,
    mu: float = 1.0,
    A: float = 1.0,
    B: float = 2.0,
    closed: bool = True,
    load_steps: int = 3,
):
    """The octant (n x n x n hexahedra per patch) under internal pressure p: la, lb, body."""
    body = af.FemBody(
        af.spherical_shell_octant(A, B, n, n),
        af.MooneyRivlin(C10=mu / 2, kappa=mu),
        1.0,
        incompressibility=1e3 * mu,
        gravity=(0, 0, 0),
        name="sphere",
    )
    symmetry_planes(body)
    body.add_pressure(p, where=lambda x: np.linalg.norm(x, axis=0) < A + 1e-9, closed=closed)
    counts = solve_static(body, LinearSolver(MPI.COMM_SELF, "mumps", body.V), load_steps=load_steps)
    X = body.V.tabulate_dof_coordinates()
    x = X + body.u.x.array.reshape(-1, 3)
    R = np.linalg.norm(X, axis=1)
    la = np.linalg.norm(x[np.isclose(R, A)], axis=1).mean() / A
    lb = np.linalg.norm(x[np.isclose(R, B)], axis=1).mean() / B
    return la, lb, counts, body


def test_inflated_sphere_matches_the_incompressible_solution():
    """Internal pressure p = 0.6 mu (la = 1.290 in closed form) on the octant with symmetry
    planes, kappa_inc = 1000 mu: the error of la - 1 falls as h^2 (measured 3.2 % on
    4 x 4 x 4 and 1.4 % on 6 x 6 x 6 hexahedra per patch) and the Richardson extrapolation
    of the two meshes is within 0.1 % of the closed form (measured 0.04 %). A dead load
    (the reference normal and area) gives la = 1.172, 41 % short, and the transposed
    cofactor fails too; a Nanson term without J is the bar test's to catch (here J ~ 1)."""
    mu, A, B, p = 1.0, 1.0, 2.0, 0.6
    exact = brentq(lambda la: inflation_pressure(la, mu, A, B) - p, 1.0, 1.6)
    exact_b = (1.0 + (exact**3 - 1.0) * (A / B) ** 3) ** (1.0 / 3.0)
    (la4, _, counts4, _), (la6, lb6, counts6, body) = inflate(4, p), inflate(6, p)
    e4, e6 = (la4 - exact) / (exact - 1), (la6 - exact) / (exact - 1)
    assert -0.02 < e6 < 0.0 and 1.8 < e4 / e6 < 2.8, (e4, e6)
    richardson = (36 * la6 - 16 * la4) / 20
    assert abs(richardson - exact) < 1e-3 * (exact - 1), (richardson, exact)
    assert abs(lb6 - exact_b) < 0.02 * (exact_b - 1)
    # closed pressure: a conservative body, Newton with the energy line search
    assert body.conservative and max(counts4 + counts6) <= 9, (counts4, counts6)


def test_closed_pressure_potential_is_consistent_and_its_tangent_symmetric(rng):
    """On the octant the closed pressure's potential -p V (V the cavity volume) has the
    residual as its gradient along every admissible variation, and the tangent is
    symmetric on the free dofs (so LinearSolver's Cholesky is exact for it); at u = 0 the
    potential is -p V with V the faceted cavity's volume (0.935 of the unit ball's octant):
    the shell's outer facets are its inner ones scaled by 2 (checked), so the region they
    close with the symmetry planes is 8 V and the shell's own volume int dX is 7 V (to
    round-off: measured 4e-16; rel 1e-12). A pressure on a face with a free border (the
    cantilever's top) has no potential: its tangent is unsymmetric."""
    body = af.FemBody(
        af.spherical_shell_octant(1.0, 2.0, 2, 2),
        af.MooneyRivlin(C10=0.5, kappa=5.0),
        1.0,
        gravity=(0, 0, 0),
    )
    symmetry_planes(body)
    load = body.add_pressure(0.3, where=lambda x: np.linalg.norm(x, axis=0) < 1 + 1e-9, closed=True)
    free = np.setdiff1d(np.arange(body.u.x.array.size), body.fixed_components)
    body.u.x.array[free] = 0.05 * rng.standard_normal(free.size)
    R = residual(body)
    d = np.zeros_like(R)
    d[free] = rng.standard_normal(free.size)
    u0, eps = body.u.x.array.copy(), 1e-6
    energies = []
    for s in (eps, -eps):
        body.u.x.array[:] = u0 + s * d
        energies.append(body.potential_energy())
    body.u.x.array[:] = u0
    assert abs((energies[0] - energies[1]) / (2 * eps) - R @ d) < 1e-7 * abs(R @ d)
    K = tangent(body)[np.ix_(free, free)]
    assert np.abs(K - K.T).max() < 1e-12 * np.abs(K).max()
    # the cavity volume at u = 0: the faceted octant of the unit ball, a seventh of the shell's
    body.u.x.array[:] = 0.0
    x = body.mesh.geometry.x
    r = np.linalg.norm(x, axis=1)
    inner, outer = (set(map(tuple, np.round(x[np.isclose(r, a)] / a, 12))) for a in (1.0, 2.0))
    assert inner == outer
    assert body.potential_energy() == pytest.approx(-0.3 * body.volume() / 7, rel=1e-12)
    assert load.conservative and body.conservative
    beam = cantilever()
    beam.add_pressure(150.0, where=top)
    assert not beam.conservative
    free = np.setdiff1d(np.arange(beam.u.x.array.size), beam.fixed_components)
    beam.u.x.array[free] = 0.01 * rng.standard_normal(free.size)
    bare = cantilever()
    bare.u.x.array[:] = beam.u.x.array
    K = tangent(beam)[np.ix_(free, free)]
    load_stiffness = K - tangent(bare)[np.ix_(free, free)]
    assert np.abs(K - K.T).max() > 0.1 * np.abs(load_stiffness).max() > 0


def test_a_closed_pressure_with_a_free_border_is_refused():
    body = cantilever()
    body.add_pressure(100.0, where=top, closed=True)
    with pytest.raises(af.InputError, match=r"declared closed, but \d+ edge\(s\) of its border"):
        body.assemble()


# ---- (b) Newton's quadratic convergence ----------------------------------------------------


def newton_residuals(body, solver, iterations=8) -> list[float]:
    """Plain Newton (no line search) on R(u) = 0: the residual norms (free dofs)."""
    u = body.u.x.petsc_vec
    du, norms = u.duplicate(), []
    for _ in range(iterations):
        body.assemble(tangent=True, diag=1.0)
        r = body.R.copy()
        body.zero_fixed(r)
        norms.append(r.norm())
        if norms[-1] < 1e-12 * norms[0]:
            break
        r.scale(-1.0)
        solver.solve(body.K, r, du)
        body.zero_fixed(du)
        u.axpy(1.0, du)
        u.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    return norms


def test_newton_converges_quadratically_under_a_follower_pressure():
    """The cantilever under an open follower pressure on its top face (bending to 10 % of
    its length, unsymmetric tangent): from the equilibrium at 95 % of the load, Newton
    reaches the round-off floor (|R| ~ 1e-12) in four iterations with r_{k+1} / r_k^2
    bounded once the first step is taken (measured 1e-4 and 2.7; a tangent without the
    load stiffness converges linearly: ratios in the thousands). The line-searched static
    solve converges too, in 12 load steps to the equilibrium of
    docs/benchmarks/static_newton.json's ``cantilever150`` (the same beam and load by
    scripts/static_newton_counts.py through Scene.solve_static): the same Newton counts
    per increment and the same lowest u_z (measured to 8e-15; rel 1e-8)."""
    beam = cantilever()
    load = beam.add_pressure(150.0, where=top)
    counts = solve_static(beam, LU(), load_steps=12)
    tip = beam.u.x.array.reshape(-1, 3)[:, 2].min()
    committed = json.loads(STATIC_NEWTON.read_text())["cantilever150"]
    assert tip == pytest.approx(committed["min_uz"], rel=1e-8)
    assert list(counts) == committed["counts"] and counts.failed == 0
    load.set(150.0 / 0.95)
    norms = newton_residuals(beam, LU())
    above_floor = [r for r in norms if r > 1e-10]
    ratios = [b / a**2 for a, b in zip(above_floor, above_floor[1:])]
    assert norms[-1] < 1e-10 * norms[0] and len(above_floor) <= 5, norms
    assert len(ratios) >= 3 and max(ratios[1:]) < 10.0, ratios


def test_the_sphere_converges_quadratically_with_the_closed_pressure():
    """The same on the nearly incompressible sphere, with LinearSolver's Cholesky (the
    closed pressure's tangent is symmetric): measured ratios 1.5e-3, 0.16, 3.8."""
    body = af.FemBody(
        af.spherical_shell_octant(1.0, 2.0, 3, 3),
        af.MooneyRivlin(C10=0.5, kappa=1.0),
        1.0,
        incompressibility=1e3,
        gravity=(0, 0, 0),
    )
    symmetry_planes(body)
    load = body.add_pressure(0.5, where=lambda x: np.linalg.norm(x, axis=0) < 1 + 1e-9, closed=True)
    solver = LinearSolver(MPI.COMM_SELF, "mumps", body.V)
    solve_static(body, solver, load_steps=2)
    load.set(0.6)
    norms = newton_residuals(body, solver)
    above_floor = [r for r in norms if r > 1e-10 * norms[0]]
    ratios = [b / a**2 for a, b in zip(above_floor, above_floor[1:])]
    assert norms[-1] < 1e-10 * norms[0] and len(above_floor) <= 6, norms
    assert len(ratios) >= 3 and max(ratios[1:]) < 50.0, ratios


# ---- (c) tangent and potential against finite differences ----------------------------------


@pytest.mark.parametrize("cell", [dmesh.CellType.hexahedron, dmesh.CellType.tetrahedron])
def test_tangent_is_the_derivative_of_the_residual(cell, rng):
    """K d = (R(u + eps d) - R(u - eps d)) / (2 eps) at a deformed state, with a follower
    pressure and a dead traction on overlapping faces (relative error measured ~1e-9)."""
    body = af.FemBody(
        box((3, 2, 2), (1.0, 0.5, 0.5), cell),
        af.NeoHookean.from_young_poisson(1e3, 0.3),
        1.0,
        gravity=(0, 0, 0),
    )
    body.fix_nodes(body.find_nodes(lambda x: x[0] < 1e-12))
    body.add_pressure(80.0, where=lambda x: np.isclose(x[2], 0.5))
    body.add_traction((10.0, -20.0, 30.0), where=lambda x: x[2] > 0.25)  # top face again
    body.add_pressure(-40.0, where=lambda x: np.isclose(x[0], 1.0), name="suction")
    free = np.setdiff1d(np.arange(body.u.x.array.size), body.fixed_components)
    body.u.x.array[free] = 0.05 * rng.standard_normal(free.size)
    K = tangent(body)
    d = np.zeros(body.u.x.array.size)
    d[free] = rng.standard_normal(free.size)
    u0, eps = body.u.x.array.copy(), 1e-6
    R = []
    for s in (eps, -eps):
        body.u.x.array[:] = u0 + s * d
        R.append(residual(body))
    body.u.x.array[:] = u0
    fd = (R[0] - R[1]) / (2 * eps)
    assert np.linalg.norm((K @ d - fd)[free]) < 1e-7 * np.linalg.norm(fd[free])


def test_residual_is_the_sum_of_its_terms_assembled_alone(rng):
    """The FFCx pitfall of the design notes (integrals of different degrees in one form):
    R(body with loads) - R(body without) equals each load's virtual work assembled alone."""
    domain = box((3, 2, 2), (1.0, 0.5, 0.5))
    material = af.NeoHookean.from_young_poisson(1e3, 0.3)
    bare = af.FemBody(domain, material, 1.0, gravity=(0, 0, 0), incompressibility=1e4)
    loaded = af.FemBody(domain, material, 1.0, gravity=(0, 0, 0), incompressibility=1e4)
    p = loaded.add_pressure(80.0, where=lambda x: np.isclose(x[2], 0.5))
    t = loaded.add_traction((1.0, 2.0, 3.0), where=lambda x: np.isclose(x[1], 0.0))
    u = 0.05 * rng.standard_normal(bare.u.x.array.size)
    bare.u.x.array[:] = loaded.u.x.array[:] = u
    loaded.load_factor.value = 0.7
    alone = np.zeros_like(u)
    for load in (p, t):
        tags = dmesh.meshtags(domain, 2, load.facets, np.ones_like(load.facets))
        ds = ufl.Measure(
            "ds", domain=domain, subdomain_data=tags, metadata={"quadrature_degree": 2}
        )(1)
        form = fem.form(
            load.virtual_work(loaded.u, ufl.TestFunction(loaded.V), loaded.load_factor, ds)
        )
        alone += fem_petsc.assemble_vector(form).array
    assert np.abs(residual(loaded) - residual(bare) + alone).max() < 1e-12 * np.abs(alone).max()


def test_a_body_without_surface_loads_has_no_facet_integral():
    body = cantilever()
    body.compile()
    assert body._compiled["R"].integral_types == {fem.IntegralType.cell}
    body.add_traction((0, 0, -1.0), where=top)
    body.compile()
    assert fem.IntegralType.exterior_facet in body._compiled["R"].integral_types


# ---- (d) the bar in uniaxial tension ---------------------------------------------------------


def uniaxial(material, load):
    """(axial, lateral) stretches of a compressible neo-Hookean bar whose first
    Piola-Kirchhoff stress P11 equals ``load(lateral)``, P22 = P33 = 0:
    P = mu (F - F^-T) + lmbda ln J F^-T with F = diag(a, b, b)."""
    mu, lm = material.mu, material.lmbda

    def equations(z):
        a, b = z
        lnJ = np.log(a * b * b)
        return [mu * (a - 1 / a) + lm * lnJ / a - load(b), mu * (b - 1 / b) + lm * lnJ / b]

    return fsolve(equations, [1.2, 0.95], xtol=1e-13)


@pytest.mark.parametrize("kind", ["traction", "pressure"])
def test_bar_under_end_load_matches_the_uniaxial_solution(kind):
    """A bar with symmetry planes (u_k = 0 on X_k = 0, component-wise) pulled at X = L.
    The deformation is homogeneous, F = diag(a, b, b), so Q1 reproduces it exactly:
    a dead traction T gives P11 = T; a follower pressure -T on the end face acts on the
    deformed area (Nanson: J F^-T N = b^2 e1), P11 = T b^2. Both to 1e-9."""
    L, T = 2.0, 3e3
    material = af.NeoHookean.from_young_poisson(1e4, 0.3)
    body = af.FemBody(box(), material, 1000.0, gravity=(0, 0, 0))
    symmetry_planes(body)
    end = lambda x: np.isclose(x[0], L)  # noqa: E731
    if kind == "traction":
        body.add_traction((T, 0.0, 0.0), where=end)
        a, b = uniaxial(material, lambda b: T)
    else:
        body.add_pressure(-T, where=end)
        a, b = uniaxial(material, lambda b: T * b * b)
    counts = solve_static(body, LU(), load_steps=2)
    X = body.V.tabulate_dof_coordinates()
    expected = X * np.array([a - 1, b - 1, b - 1])
    assert np.abs(body.u.x.array.reshape(-1, 3) - expected).max() < 1e-9 * L
    assert max(counts) <= 5


def test_dead_traction_potential_is_consistent(rng):
    """potential_energy() includes -lambda int t . u dA: its derivative is R."""
    body = cantilever()
    body.add_traction((3.0, -5.0, -150.0), where=top)
    body.load_factor.value = 0.6
    assert body.conservative
    free = np.setdiff1d(np.arange(body.u.x.array.size), body.fixed_components)
    body.u.x.array[free] = 1e-3 * rng.standard_normal(free.size)
    R = residual(body)
    d = np.zeros_like(R)
    d[free] = rng.standard_normal(free.size)
    u0, eps = body.u.x.array.copy(), 1e-7
    energies = []
    for s in (eps, -eps):
        body.u.x.array[:] = u0 + s * d
        energies.append(body.potential_energy())
    assert abs((energies[0] - energies[1]) / (2 * eps) - R @ d) < 1e-6 * abs(R @ d)


# ---- setting loads between steps, and every solver sees them ---------------------------------


def test_a_load_is_set_between_steps_and_ramped_by_the_load_factor():
    beam = cantilever()
    load = beam.add_pressure(100.0, where=top)
    beam.compile()
    compiled = beam._compiled
    f100 = -residual(beam)
    load.set(250.0)
    assert beam._compiled is compiled  # no recompilation
    np.testing.assert_allclose(-residual(beam), 2.5 * f100, rtol=1e-12, atol=1e-14)
    beam.load_factor.value = 0.5
    np.testing.assert_allclose(-residual(beam), 1.25 * f100, rtol=1e-12, atol=1e-14)
    # total force at u = 0: p times the face's area, along -z
    assert abs(f100.reshape(-1, 3)[:, 2].sum() + 100.0 * 0.2) < 1e-10
    assert load.get() == 250.0 and load.name == "pressure0"


def test_the_scene_and_the_body_solver_agree_on_a_follower_pressure():
    """A FEM body's surface loads flow into the Scene: alone in a scene (stepped by the
    body's solver), and coupled (clamped by a NodeAttachment to a fixed rigid body: the
    scene's own assembly and LU), the static solution is the body-level Newton's."""
    alone, island = cantilever("alone"), cantilever("island")
    coupled = af.FemBody(alone.mesh, alone.material, 1000.0, name="coupled")
    for body in (alone, island, coupled):
        body.add_pressure(150.0, where=top)
    solve_static(alone, LU(), load_steps=6)
    scene = af.Scene(gravity=(0.0, 0.0, 0.0))
    base = af.RigidBody("base", 1.0, np.eye(3), motion="fixed")
    scene.add(
        island,
        coupled,
        base,
        af.NodeAttachment(coupled, coupled.find_nodes(lambda x: x[0] < 1e-12), base),
    )
    scene.solve_static(load_steps=6)
    for body in (island, coupled):
        assert np.abs(body.u.x.array - alone.u.x.array).max() < 1e-8, body.name


def test_a_controller_sets_the_pressure_during_a_simulation():
    beam = cantilever()
    load = beam.add_pressure(0.0, where=top)
    scene = af.Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(beam)
    seen = []
    scene.add_controller(lambda s, t0, t1: (load.set(1e3 * t1), seen.append(load.get())))
    run = af.simulate(
        scene,
        0.03,
        0.01,
        progress=False,
        record={"tip": lambda s: beam.u.x.array.reshape(-1, 3)[:, 2].min()},
    )
    assert seen == pytest.approx([10.0, 20.0, 30.0])
    assert np.all(np.diff(run.records["tip"]) < 0)


# ---- (e) choosing facets ---------------------------------------------------------------------


def top_surface(triangles: bool):
    """The cantilever's top face as a surface mesh: quads, or each quad split in two."""
    grid = np.array([[x, y, 0.2] for y in np.linspace(0, 0.2, 3) for x in np.linspace(0, 1, 11)])
    quads = np.array(
        [
            (j * 11 + i, j * 11 + i + 1, j * 11 + i + 12, j * 11 + i + 11)
            for j in range(2)
            for i in range(10)
        ]
    )
    if not triangles:
        return grid, quads
    return grid, np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])


def test_predicate_tags_and_surface_mesh_choose_the_same_facets():
    beam = cantilever()
    domain = beam.mesh
    domain.topology.create_connectivity(2, 3)
    facets = dmesh.locate_entities_boundary(domain, 2, top)
    boundary = dmesh.exterior_facet_indices(domain.topology)
    values = np.where(np.isin(boundary, facets), 7, 3).astype(np.int32)
    tags = dmesh.meshtags(domain, 2, boundary, values)
    loads = [
        beam.add_pressure(100.0, where=top, name="where"),
        beam.add_pressure(100.0, tags=tags, values=7, name="tags"),
        beam.add_pressure(100.0, surface=top_surface(False), name="quads"),
        beam.add_pressure(100.0, surface=top_surface(True), name="triangles"),
    ]
    for load in loads:
        np.testing.assert_array_equal(load.facets, np.sort(facets))
    f = []
    for load in loads:
        for other in loads:
            other.set(100.0 if other is load else 0.0)
        f.append(-residual(beam))
    for other in f[1:]:
        np.testing.assert_allclose(other, f[0], rtol=0, atol=1e-12)
    assert abs(f[0].reshape(-1, 3)[:, 2].sum() + 20.0) < 1e-10


def test_bad_surface_loads_are_clear_errors():
    beam = cantilever()
    domain = beam.mesh
    with pytest.raises(af.InputError, match="exactly one of where=, tags= or surface="):
        beam.add_pressure(1.0)
    with pytest.raises(af.InputError, match="exactly one of"):
        beam.add_pressure(1.0, where=top, surface=top_surface(False))
    with pytest.raises(af.InputError, match="selects no boundary facet"):
        beam.add_pressure(1.0, where=lambda x: x[2] > 5.0)
    with pytest.raises(af.InputError, match="pressure must be a finite number"):
        beam.add_pressure(np.nan, where=top)
    with pytest.raises(af.InputError, match="traction must be 3 finite numbers"):
        beam.add_traction(1.0, where=top)
    load = beam.add_pressure(1.0, where=top, name="p")
    with pytest.raises(af.InputError, match="'p': pressure must be a finite number"):
        load.set([1.0, 2.0])
    with pytest.raises(af.InputError, match="surface load 'p' already defined"):
        beam.add_pressure(1.0, where=top, name="p")
    # tags: interior facets, a missing value, values without tags
    domain.topology.create_connectivity(2, 3)
    interior = dmesh.locate_entities(domain, 2, lambda x: np.isclose(x[0], 0.5))
    tags = dmesh.meshtags(domain, 2, np.sort(interior), 5)
    with pytest.raises(af.InputError, match=r"not on the boundary .* at \[0\.5"):
        beam.add_pressure(1.0, tags=tags, values=5)
    with pytest.raises(af.InputError, match=r"no facet carries the tag value\(s\) \[6\]"):
        beam.add_pressure(1.0, tags=tags, values=[5, 6])
    with pytest.raises(af.InputError, match="values= selects tag values and needs tags="):
        beam.add_pressure(1.0, where=top, values=5)
    # surface meshes: faces off the body are named; a facet covered in part
    vertices, faces = top_surface(True)
    lifted = vertices.copy()
    lifted[0, 2] += 0.01  # a corner of faces 0 and 1
    with pytest.raises(
        af.InputError, match=r"2 of 40 surface face\(s\) match no boundary facet .* faces \[0, 1\]$"
    ):
        beam.add_pressure(1.0, surface=(lifted, faces))
    with pytest.raises(af.InputError, match="covers 1 boundary facet"):
        beam.add_pressure(1.0, surface=(vertices, faces[1:]))
    with pytest.raises(af.InputError, match=r"faces must be integers of shape \(m, 3\)"):
        beam.add_pressure(1.0, surface=(vertices, faces[:, :2]))
    with pytest.raises(af.InputError, match="center must be 3 finite numbers"):
        beam.add_pressure(1.0, where=top, closed=True, center=(0, 0))


# ---- component-wise fixed nodes --------------------------------------------------------------


def test_component_wise_fixes():
    """fix_nodes(..., components=): only those components are fixed (residual, tangent,
    velocity, the implicit step, the coupled Scene); callers of fixed_dofs (whole nodes)
    refuse them with a clear error instead of leaving them free."""
    body = af.FemBody(box(), af.NeoHookean.from_young_poisson(1e4, 0.3), 1000.0, gravity=(0, 0, 0))
    plane = body.find_nodes(lambda x: np.isclose(x[0], 0.0))
    body.fix_nodes(plane, components=(0,))
    dofs = body.local_dofs(plane)
    np.testing.assert_array_equal(body.fixed_components, np.sort(3 * dofs))
    vec = body.u.x.petsc_vec.duplicate()
    vec.set(1.0)
    body.zero_fixed(vec)
    arr = vec.array.reshape(-1, 3)
    assert np.all(arr[dofs, 0] == 0.0) and np.all(arr[dofs, 1:] == 1.0)
    assert arr.sum() == arr.size - dofs.size
    with pytest.raises(af.InputError, match="fixed in some components only"):
        _ = body.fixed_dofs
    # coupled (the layout takes fixed components): hung from a fixed base under gravity,
    # the plane nodes keep x and move in z
    scene = af.Scene(gravity=(0.0, 0.0, -9.81))
    base = af.RigidBody("base", 1.0, np.eye(3), motion="fixed")
    scene.add(
        body,
        base,
        af.NodeAttachment(
            body, body.find_nodes(lambda x: np.isclose(x[0], 2.0) & np.isclose(x[1], 0.0)), base
        ),
    )
    scene.solve_static()
    u = body.u.x.array.reshape(-1, 3)
    assert np.all(u[dofs, 0] == 0.0) and np.abs(u[dofs, 2]).max() > 1e-4
    body.u.x.array[:] = 0.0
    # the other planes too: a bar free to contract, pulled along x in one implicit step
    symmetry_planes(body, (1, 2))
    body.add_traction((1e3, 0.0, 0.0), where=lambda x: np.isclose(x[0], 2.0))
    ImplicitEuler().advance(body, 0.01, LU())
    u = body.u.x.array.reshape(-1, 3)
    X = body.V.tabulate_dof_coordinates()
    for k in range(3):
        on = np.isclose(X[:, k], 0.0)
        assert np.all(u[on, k] == 0.0) and np.abs(u[on]).max() > 0
    # whole-node fixes are unchanged, and their dofs are listed as before
    whole = af.FemBody(box(), af.NeoHookean.from_young_poisson(1e4, 0.3), 1.0)
    whole.fix_nodes(plane)
    np.testing.assert_array_equal(whole.fixed_dofs, np.sort(dofs))
    np.testing.assert_array_equal(
        whole.fixed_components, np.sort((3 * dofs[:, None] + np.arange(3)).ravel())
    )
    for bad in ((3,), (0, 0), (), ("x",), (True,)):
        with pytest.raises(af.InputError, match="components must be distinct indices"):
            whole.fix_nodes(plane, components=bad)


# ---- reduced bodies --------------------------------------------------------------------------


def basis(body, r=None, rng=None) -> np.ndarray:
    """The complete basis of the free dofs (r None), or r random columns; zero fixed rows."""
    n = 3 * body.V.dofmap.index_map.size_local
    free = np.setdiff1d(np.arange(n), body.fixed_components)
    if r is None:
        U = np.zeros((n, free.size))
        U[free, np.arange(free.size)] = 1.0
        return U
    U = np.zeros((n, r))
    U[free] = rng.standard_normal((free.size, r))
    return U


def full_force_and_tangent(body, u):
    n = u.size
    body.u.x.array[:n] = u
    body.assemble(tangent=True)
    return -body.R.array[:n].copy(), tangent(body)[:n, :n]


def test_reduced_body_feels_the_surface_loads_of_its_full_body(rng):
    """f~ = U^T f(u_bar + U q) and K~ = U^T K U (to 1e-13) for a random basis, with an
    open follower pressure (assembled on the 20 cells next to the top face, not the 40 of
    the mesh) and a dead traction, after the loads were set and the load factor changed;
    with the complete basis the static solution is the full one to 1e-10."""
    from artifem.integrators import solve_static_reduced
    from artifem.reduction.reduced_body import ReducedFemBody, all_points

    beam = cantilever()
    pressure = beam.add_pressure(100.0, where=top)
    traction = beam.add_traction((5.0, 0.0, -20.0), where=lambda x: np.isclose(x[0], 1.0))
    U = 0.1 * basis(beam, 7, rng)
    reduced = ReducedFemBody(beam, U, all_points(beam))
    assert reduced._patch.mesh.topology.index_map(3).size_local == 20
    pressure.set(150.0)
    traction.set((5.0, 2.0, -30.0))
    beam.load_factor.value = 0.7
    q = 0.1 * rng.standard_normal(7)
    reduced.set_q(q)
    f, K = full_force_and_tangent(beam, U @ q)
    np.testing.assert_allclose(reduced.force(), U.T @ f, rtol=0, atol=1e-13 * np.abs(U.T @ f).max())
    np.testing.assert_allclose(
        reduced.tangent(), U.T @ K @ U, rtol=0, atol=1e-13 * np.abs(U.T @ K @ U).max()
    )
    # the complete basis: the same static solution
    beam.u.x.array[:] = 0.0
    complete = ReducedFemBody(beam, basis(beam), all_points(beam))
    solve_static_reduced(complete, load_steps=12)
    solve_static(beam, LU(), load_steps=12)
    u = beam.u.x.array[: complete.U.shape[0]]
    assert np.abs(complete.nodal_displacement() - u).max() < 1e-10 * np.abs(u).max()


def test_reduced_body_keeps_the_closed_pressure_potential(rng):
    """The octant with component-wise symmetry planes and a closed pressure, complete
    basis: Pi~(q) is the full body's Pi(U q) (the same -p V), and f~ = U^T f."""
    from artifem.reduction.reduced_body import ReducedFemBody, all_points

    body = af.FemBody(
        af.spherical_shell_octant(1.0, 2.0, 2, 2),
        af.MooneyRivlin(C10=0.5, kappa=5.0),
        1.0,
        gravity=(0, 0, 0),
    )
    symmetry_planes(body)
    body.add_pressure(0.3, where=lambda x: np.linalg.norm(x, axis=0) < 1 + 1e-9, closed=True)
    U = basis(body)
    reduced = ReducedFemBody(body, U, all_points(body))
    q = 0.02 * rng.standard_normal(U.shape[1])
    reduced.set_q(q)
    body.u.x.array[: U.shape[0]] = U @ q
    assert abs(reduced.potential_energy() - body.potential_energy()) < 1e-12 * abs(
        body.potential_energy()
    )
    f, _ = full_force_and_tangent(body, U @ q)
    np.testing.assert_allclose(reduced.force(), U.T @ f, rtol=0, atol=1e-12 * np.abs(f).max())
