"""Contact pressure (artifem.multibody.contact_pressure) and the Hertz check (issue 29):
an FEM sphere (R = 10 mm, E = 100 kPa, nu = 0.45, neo-Hookean) pressed on a rigid plane
with 0.05 N against the closed form a = 1.4407 mm, p0 = 11.501 kPa
(artifem.models.hertz_sphere: a hemisphere, its flat face clamped and moved down until
the plane's reaction is 0.05 N; P1 tetrahedra refined near the pole).

(1) the nodal areas A_i = int N_i dA: a cube's corner and edge nodes, their sum;
(2) the Hertz hemisphere on three meshes (h = 0.5, 0.35, 0.25 mm at the pole): the
    reaction is the target force, sum p_i A_i = sum f_n, no node below the plane, the
    contact radius (second moment of the forces, and the fit of the Hertz profile to
    f_n / A) and the fitted peak pressure approach the closed form with every refinement
    (measured: radius -6.4, -4.2, -2.7 %; fitted p0 +14.9, +9.2, +5.9 %), and every
    figure is the first three rows of docs/benchmarks/contact_hertz.json (the same runs by
    scripts/hertz_contact.py, which has finer meshes too).
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

import artifem as af  # (must precede dolfinx / petsc4py)
from dolfinx import fem
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.errors import InputError
from artifem.models import hertz_sphere as hs
from artifem.multibody.contact_pressure import boundary_areas, contact_pressure

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="coupled scenes are serial")


# ---- (1) nodal areas ------------------------------------------------------------------------


def test_boundary_areas_are_the_lumped_facet_integrals_of_the_shape_functions():
    """A unit cube of 2 x 2 x 2 hexahedra (h = 0.5): a node gets h^2 / 4 from each boundary
    quadrilateral around it: a corner 3 h^2 / 4, an edge midpoint and a face centre h^2
    (4 quadrilaterals), the interior node 0; the areas sum to 6. The current configuration after a
    uniform stretch
    by 2 in x: the x faces keep their area, the others double."""
    msh = dmesh.create_box(
        MPI.COMM_SELF, [np.zeros(3), np.ones(3)], [2, 2, 2], dmesh.CellType.hexahedron
    )
    body = af.FemBody(msh, af.NeoHookean.from_young_poisson(1e5, 0.3), 1000.0)
    areas = boundary_areas(body)
    x = body.V.tabulate_dof_coordinates()
    on_face = np.isclose(x, 0.0) | np.isclose(x, 1.0)
    faces = on_face.sum(axis=1)
    expected = {3: 3 * 0.0625, 2: 4 * 0.0625, 1: 0.25, 0: 0.0}
    for k, a in expected.items():
        assert np.allclose(areas[faces == k], a, rtol=1e-12, atol=1e-15)
    assert math.isclose(areas.sum(), 6.0, rel_tol=1e-12)
    body.u.interpolate(lambda x: np.vstack([x[0], 0 * x[1], 0 * x[2]]))
    current = boundary_areas(body, configuration="current")
    assert math.isclose(current.sum(), 2 * 1.0 + 4 * 2.0, rel_tol=1e-12)
    with pytest.raises(InputError, match="configuration"):
        boundary_areas(body, configuration="deformed")


# ---- (2) Hertz -----------------------------------------------------------------------------

SIZES = (0.5e-3, 0.35e-3, 0.25e-3)
#: scripts/hertz_contact.py's runs of the same models (its first three meshes are SIZES)
BENCHMARK = json.loads(
    (Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "contact_hertz.json").read_text()
)["meshes"][: len(SIZES)]


@pytest.fixture(scope="module")
def hertz_runs():
    models = []
    for h in SIZES:
        model = hs.HertzModel(h)
        model.measure_result = model.measure(model.solve())
        models.append(model)
    return models


def test_the_closed_form():
    a, p0, delta = hs.hertz()
    assert math.isclose(a, 1.4407e-3, rel_tol=1e-4)
    assert math.isclose(p0, 11501.0, rel_tol=1e-4)
    assert math.isclose(p0, 1.5 * hs.FORCE / (math.pi * a * a), rel_tol=1e-14)
    assert math.isclose(delta, a * a / hs.R, rel_tol=1e-14)


def test_hertz_hemisphere_is_pressed_with_the_target_force_on_the_plane(hertz_runs):
    """The secant finds the flat face's displacement whose reaction is 0.05 N (it stops
    within 1e-4): the displacement and the reaction it lands on are contact_hertz.json's
    (measured to 2e-16; rel 1e-6); the pressures times the areas give the forces back; no
    node below the plane (measured: 3e-28 m at most, the bound 1e-12 m; the contact's
    tolerance is 1e-9 m); only nodes on the plane press; the pressure field goes into a
    dolfinx Function."""
    assert [row["h_pole_mm"] * 1e-3 for row in BENCHMARK] == pytest.approx(SIZES, rel=1e-12)
    for model, row in zip(hertz_runs, BENCHMARK):
        result = model.measure_result
        assert result.force == pytest.approx(row["force_N"], rel=1e-6)
        assert result.delta * 1e3 == pytest.approx(row["delta_mm"], rel=1e-6)
        forces = model.scene.contact_forces(model.contact)
        cp = model.scene.contact_pressure(model.contact)[model.body.name]
        assert set(forces.points.tolist()) <= set(cp.points.tolist())
        assert math.isclose((cp.pressure * cp.area).sum(), forces.normal.sum(), rel_tol=1e-12)
        phi = model.contact.distances()
        assert phi.min() >= -1e-12
        pressing = set(forces.points[forces.normal > 1e-12 * forces.normal.max()].tolist())
        assert pressing <= set(model.contact.labels[phi < 1e-9].tolist())
        S = fem.functionspace(model.body.mesh, ("Lagrange", 1))
        p = fem.Function(S, name="contact_pressure")
        p.x.array[:] = cp.nodal
        assert math.isclose(p.x.array.max(), cp.pressure.max(), rel_tol=1e-14)
        assert np.count_nonzero(p.x.array) == len(pressing)
        # the boundary area is the hemisphere's (3 pi R^2) up to its facets' chords
        areas = boundary_areas(model.body)
        assert -0.02 < areas.sum() / (3 * math.pi * hs.R**2) - 1.0 < 0.0


def test_hertz_radius_and_peak_pressure_converge_to_the_closed_form(hertz_runs):
    """Each refinement brings the contact radius (second moment of the forces, sum f r^2 /
    sum f = 2 a^2 / 5, and the fit of the Hertz profile to f_n / A) and the fitted peak
    pressure nearer to the closed form (the finest here: -2.7, -2.9 and +5.9 %); each mesh's
    radii, fitted pressure, scatter, largest nodal pressure and numbers of nodes are
    contact_hertz.json's (measured to 3e-10, the fits; rel 1e-6, the counts exactly).
    Hertz is a small-strain theory, here a / R = 0.144 and p0 / E = 0.115. The nodal
    pressures scatter about the fitted profile by about 5 % of p0 (node-on-plane contact
    on an unstructured mesh), so their maximum is no estimate of p0 (measured +24 to +38 %,
    not converging)."""
    a0, p0, _ = hs.hertz()
    results = [m.measure_result for m in hertz_runs]
    for name, exact in (("radius_moment", a0), ("fit_radius", a0), ("fit_pressure", p0)):
        errors = [abs(getattr(r, name) / exact - 1.0) for r in results]
        assert all(e1 < e0 for e0, e1 in zip(errors, errors[1:])), (name, errors)
    for r, row in zip(results, BENCHMARK):
        assert (r.nodes, r.pressing) == (row["nodes"], row["pressing_nodes"])
        for name, key, scale in (
            ("radius_moment", "radius_moment_mm", 1e3),
            ("fit_radius", "radius_fit_mm", 1e3),
            ("radius_outer", "radius_outer_node_mm", 1e3),
            ("fit_pressure", "pressure_fit_kPa", 1e-3),
            ("fit_scatter", "pressure_scatter_about_fit", 1.0),
            ("peak_pressure", "pressure_max_node_kPa", 1e-3),
        ):
            assert getattr(r, name) * scale == pytest.approx(row[key], rel=1e-6), (name, row)
    # the outermost pressing node lies within a node spacing of the closed form's radius
    for h, r in zip(SIZES, results):
        assert abs(r.radius_outer - a0) < h


def test_contact_pressure_is_for_fem_nodes_only():
    """A rigid body's points have no FEM mesh: no pressure in the scene's dict, and an
    InputError from contact_pressure itself."""
    body = af.RigidBody("box", 1.0, np.eye(3))
    contact = af.PlaneContact(body, (0, 0, -1.0), (0, 0, 1.0), points=np.zeros((1, 3)))
    scene = af.Scene()
    scene.add(body, contact)
    scene.step(0.01)
    assert scene.contact_pressure(contact) == {}
    with pytest.raises(InputError, match="FEM bodies' nodes"):
        contact_pressure(body.contact_points(np.zeros((1, 3))), np.zeros(1))


def test_the_hertz_table_on_the_contact_page_is_the_benchmark_json():
    """docs/contact.md's Hertz section: its table is scripts/hertz_contact.py's rendering of
    docs/benchmarks/contact_hertz.json, and the errors there fall with every refinement."""
    import importlib.util
    import json
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location(
        "hertz_contact", root / "scripts" / "hertz_contact.py"
    )
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    page = (root / "docs" / "contact.md").read_text()
    section = page[page.index("## Hertz") :]
    section = section[: section.index("\n## ", 1)] if "\n## " in section[1:] else section
    rows = json.loads((root / "docs" / "benchmarks" / "contact_hertz.json").read_text())["meshes"]
    assert script.HEADER in section
    for row in rows:
        assert script.render(row) in section, row["h_pole_mm"]
    for key in ("radius_moment_error", "pressure_fit_error"):
        errors = [abs(row[key]) for row in rows]
        assert all(e1 < e0 for e0, e1 in zip(errors, errors[1:])), key


def test_a_reduced_hemisphere_with_the_complete_basis_is_the_full_one():
    """A coarse hemisphere (1 mm at the pole) pressed by the closed form's delta, full and
    reduced with the complete basis (identity on the free dofs, every integration point;
    its contact by ``PlaneContact.onto_reduced``): the static solves give the same contact
    forces to round-off."""
    from artifem.reduction.reduced_body import ReducedFemBody, all_points

    delta = hs.hertz()[2]
    full = hs.HertzModel(1e-3, h_far=4e-3)
    assert full.press(delta) > 0.01
    reference = full.scene.contact_forces(full.contact)
    twin = hs.HertzModel(1e-3, h_far=4e-3)
    twin.body.fix_nodes(
        twin.top,
        displacement=lambda x: np.vstack(
            [np.zeros(x.shape[1]), np.zeros(x.shape[1]), np.full(x.shape[1], -delta)]
        ),
    )
    n = 3 * twin.body.V.dofmap.index_map.size_local
    fixed = (3 * twin.body.fixed_dofs[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(n), fixed)
    U = np.zeros((n, free.size))
    U[free, np.arange(free.size)] = 1.0
    reduced = ReducedFemBody(twin.body, U, all_points(twin.body), name="reduced hemisphere")
    contact = twin.contact.onto_reduced(reduced)
    scene = af.Scene()
    scene.add(reduced, contact)
    scene.solve_static()
    forces = scene.contact_forces(contact)
    order, ref_order = np.argsort(forces.points), np.argsort(reference.points)
    np.testing.assert_array_equal(forces.points[order], reference.points[ref_order])
    np.testing.assert_allclose(
        forces.normal[order], reference.normal[ref_order], rtol=0, atol=1e-9 * hs.FORCE
    )
