"""Embedded (voxel) FEM: volume-fraction mass conservation and a static comparison with a
conforming gmsh tetrahedral mesh of the same cylinder."""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
import pyvista as pv
from mpi4py import MPI

from artifem.embedding import EmbeddedMesh
from artifem.embedding.voxel_fem import (
    VoxelFemBody,
    enclosed_volume,
    surface_area,
    voxelize,
    winding_number,
)
from artifem.fem_body import FemBody
from artifem.forms import NeoHookean
from artifem.integrators import solve_static
from artifem.linear_solver import LinearSolver

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="voxel FEM tests are serial")

RHO = 1000.0
MATERIAL = NeoHookean.from_young_poisson(5.0e6, 0.3)


def sphere_surface(radius=0.05, res=40):
    s = pv.Sphere(radius=radius, theta_resolution=res, phi_resolution=res).triangulate().clean()
    return np.asarray(s.points, dtype=float), s.faces.reshape(-1, 4)[:, 1:]


def test_inside_tests_agree_and_winding_number_is_one_inside():
    V, T = sphere_surface(res=16)
    rng = np.random.default_rng(0)
    P = (rng.random((400, 3)) - 0.5) * 0.12
    w = winding_number(P, V, T)
    r = np.linalg.norm(P, axis=1)
    clear = np.abs(r - 0.05) > 0.003  # away from the faceted sphere's surface
    np.testing.assert_allclose(w[clear], (r[clear] < 0.05).astype(float), atol=1e-9)
    a = voxelize(V, T, (5, 5, 5), inside="vtk")
    b = voxelize(V, T, (5, 5, 5), inside="winding")
    np.testing.assert_array_equal(a.ijk, b.ijk)
    np.testing.assert_allclose(a.fraction, b.fraction)


def test_weighted_mass_conserves_the_enclosed_volume():
    V, T = sphere_surface()
    volume, area = enclosed_volume(V, T), surface_area(V, T)
    errors = []
    for n in (4, 8, 16):
        body = VoxelFemBody(V, T, MATERIAL, RHO, (n, n, n), samples=4)
        vox = body.voxels
        assert np.all((vox.fraction > 0) & (vox.fraction <= 1))
        assert body.mesh.topology.index_map(3).size_local == vox.fraction.size <= n**3
        if n > 4:
            assert vox.fraction.size < n**3  # empty corner cells dropped
        mass = body.total_mass()  # assembled: int rho phi dX
        assert mass == pytest.approx(body.weighted_mass(), rel=1e-12)
        error = abs(mass - RHO * volume)
        assert error <= RHO * 2.0 * area * vox.sample_diagonal  # the band bound
        errors.append(error / (RHO * volume))
    # Measured: 1.9e-2, 4.3e-3, 1.5e-4 (the band bound: 1.3, 0.65, 0.33).
    assert errors[0] < 0.03 and errors[1] < 0.01 and errors[2] < 1e-3
    assert errors[0] > errors[1] > errors[2]


def test_energy_and_gravity_are_weighted_by_the_fraction():
    """A uniform stretch: Pi = sum_e phi_e V_e psi(F) exactly (F uniform, psi constant)."""
    V, T = sphere_surface(res=20)
    body = VoxelFemBody(V, T, MATERIAL, RHO, (6, 6, 6), samples=3)
    x = body.V.tabulate_dof_coordinates()
    A = np.diag([0.02, -0.01, 0.005])
    body.u.x.array[:] = (x @ A.T).ravel()
    ref = FemBody(body.mesh, MATERIAL, RHO)
    ref.u.x.array[:] = body.u.x.array
    full_volume = body.mesh.topology.index_map(3).size_local * body.voxels.cell_volume
    psi = ref.potential_energy() / full_volume
    assert body.potential_energy() == pytest.approx(psi * body.voxels.volume, rel=1e-10)


def test_energy_terms_of_a_muscled_voxel_body_are_those_of_its_fem_body():
    """Like any FemBody, a voxel body lists one energy term per muscle by default and one
    per layer of muscles when merged (its own forms)."""
    from artifem.forms import BlemkerFiber

    V, T = sphere_surface(res=16)
    body = VoxelFemBody(V, T, MATERIAL, RHO, (4, 4, 4), samples=2)
    ref = FemBody(body.mesh, MATERIAL, RHO)
    n = body.mesh.topology.index_map(3).size_local
    for b in (body, ref):
        b.add_muscle("a", np.arange(n // 2), (1.0, 0.0, 0.0), BlemkerFiber(2.0e4), 0.5)
        b.add_muscle("b", np.arange(n // 2, n), (0.0, 1.0, 0.0), BlemkerFiber(1.0e4), 0.2)
    names = [t.name for t in ref.energy_terms()]
    assert names == ["material", "muscle:a", "muscle:b"]
    assert [t.name for t in body.energy_terms()] == names
    merged = [t.name for t in body.energy_terms(merged=True)]
    assert merged == [t.name for t in ref.energy_terms(merged=True)] != names


# ---- static comparison with a conforming tetrahedral mesh --------------------------------

L, R = 0.3, 0.05


def gmsh_cylinder(size):
    import gmsh
    from dolfinx.io import gmsh as dgmsh

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("cylinder")
        gmsh.model.occ.addCylinder(0, 0, 0, L, 0, 0, R)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [1], 1)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.model.mesh.generate(3)
        return dgmsh.model_to_mesh(gmsh.model, MPI.COMM_WORLD, 0, gdim=3).mesh
    finally:
        gmsh.finalize()


def boundary_surface(msh):
    """The boundary triangles of a tetrahedral mesh, oriented outward (vertices, triangles)."""
    c, x = msh.geometry.dofmaps[0], msh.geometry.x
    faces = np.concatenate([c[:, [1, 2, 3]], c[:, [0, 3, 2]], c[:, [0, 1, 3]], c[:, [0, 2, 1]]])
    opposite = np.concatenate([c[:, 0], c[:, 1], c[:, 2], c[:, 3]])
    _, idx, count = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
    F, d = faces[idx[count == 1]], opposite[idx[count == 1]]
    normal = np.cross(x[F[:, 1]] - x[F[:, 0]], x[F[:, 2]] - x[F[:, 0]])
    inward = np.einsum("ij,ij->i", normal, x[d] - x[F[:, 0]]) > 0
    F[inward] = F[inward][:, ::-1]
    used, inverse = np.unique(F, return_inverse=True)
    return x[used].copy(), inverse.reshape(-1, 3)


def tip_deflection(body, tip_points):
    """Clamp x = 0, solve under gravity, mean z displacement of the embedded end-face vertices."""
    x = body.mesh.geometry.x
    inputs = np.asarray(body.mesh.geometry.input_global_indices)
    body.fix_nodes(inputs[x[:, 0] < 1e-9])
    tip = EmbeddedMesh(body, tip_points, snap=True)
    solve_static(body, LinearSolver(body.mesh.comm, "mumps"))
    return float((tip.positions() - tip.rest_positions)[:, 2].mean())


def test_cylinder_under_gravity_matches_conforming_tets():
    msh = gmsh_cylinder(0.01)
    S, T = boundary_surface(msh)
    assert enclosed_volume(S, T) == pytest.approx(np.pi * R * R * L, rel=1e-2)
    tip_points = S[np.abs(S[:, 0] - L) < 1e-9]
    reference = tip_deflection(FemBody(msh, MATERIAL, RHO, gravity=(0, 0, -9.81)), tip_points)
    euler_bernoulli = -RHO * 9.81 * L**4 / (2 * 5.0e6 * R * R)
    assert reference == pytest.approx(euler_bernoulli, rel=0.03)  # measured 1.2 %
    errors = []
    for n in (4, 8):  # cubic cells: (3n, n, n) over the bounding box, 192 and 1440 cells
        body = VoxelFemBody(S, T, MATERIAL, RHO, (3 * n, n, n), gravity=(0, 0, -9.81))
        errors.append(abs(tip_deflection(body, tip_points) / reference - 1.0))
    # Measured: 12.5 % (n = 4), 0.9 % (n = 8); n = 2: 31 %, n = 6: 2.7 %.
    assert errors[0] > errors[1]
    assert errors[1] < 0.02
