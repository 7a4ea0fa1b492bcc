"""Patch tests and mass consistency of the full-order FEM body.

Patch test: on a mesh whose interior nodes are moved randomly (distorted,
non-parallelepiped hexahedra; irregular tetrahedra), prescribe an affine
displacement u = A X + c on every boundary node and solve the static problem
with no load. A homogeneous deformation F = I + A has a constant stress, so
Div P = 0 and it is the exact solution; degree-1 isoparametric elements contain
every affine field, so the discrete solution must equal it at every interior
node to round-off. This fails for a wrong residual, a wrong element mapping or
a quadrature that is not consistent.

Mass: the lumped mass sums to rho * volume, and the consistent mass matrix
applied to a constant velocity gives the same total momentum as the lumped one.
"""

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.fem_body import FemBody
from artifem.forms import LinearElastic, MooneyRivlin, NeoHookean, StVenantKirchhoff
from artifem.scene import Scene

BOX = np.array([1.0, 0.6, 0.8])
N = (4, 3, 3)
CELLS = {"hexahedron": dmesh.CellType.hexahedron, "tetrahedron": dmesh.CellType.tetrahedron}

# A general (non-symmetric) affine map with det(I + A) > 0: stretch, shear, rotation.
A_AFFINE = np.array([[0.08, -0.05, 0.03], [0.04, -0.06, 0.07], [-0.02, 0.05, 0.10]])
C_AFFINE = np.array([0.01, -0.02, 0.015])

MATERIALS = {
    "neo-hookean": NeoHookean.from_young_poisson(1.0e4, 0.3),
    "mooney-rivlin": MooneyRivlin(1037.0, C01=200.0, C20=486.0, kappa=2.0e4),
    "st-venant-kirchhoff": StVenantKirchhoff.from_young_poisson(1.0e4, 0.3),
    "linear-elastic": LinearElastic.from_young_poisson(1.0e4, 0.3),
}


def distorted_box(cell: str, seed: int = 7):
    """A box mesh whose interior nodes are displaced randomly by up to 25% of the spacing."""
    msh = dmesh.create_box(MPI.COMM_WORLD, [np.zeros(3), BOX], list(N), CELLS[cell])
    x = msh.geometry.x
    h = BOX / np.array(N)
    interior = np.all((x > 1e-12) & (x < BOX - 1e-12), axis=1)
    rng = np.random.default_rng(seed)
    # Draw by input index so every rank moves a shared node the same way.
    inputs = np.asarray(msh.geometry.input_global_indices)
    n_input = msh.geometry.index_map().size_global
    shift = rng.uniform(-0.25, 0.25, size=(n_input, 3)) * h
    x[interior] += shift[inputs[interior]]
    return msh, interior


def affine(x):
    """u = A X + c for points x of shape (3, n)."""
    return A_AFFINE @ x + C_AFFINE[:, None]


@pytest.mark.parametrize("cell", ["hexahedron", "tetrahedron"])
@pytest.mark.parametrize("material", sorted(MATERIALS))
def test_affine_patch_is_reproduced_to_round_off(cell, material):
    msh, interior = distorted_box(cell)
    body = FemBody(msh, MATERIALS[material], density=1000.0)
    inputs = np.asarray(msh.geometry.input_global_indices)
    body.fix_nodes(inputs[~interior], displacement=affine)
    scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
    scene.add(body)
    scene.solve_static(rtol=1e-13)

    x = msh.geometry.x
    dofs = body.local_dofs(inputs[interior])
    assert dofs.size > 0
    u = body.u.x.array.reshape(-1, 3)[dofs]
    exact = affine(x[interior].T).T
    # The interior started at u = 0, a deformation of the size of A (~0.1):
    # the solver moved it all the way to the affine field.
    assert np.abs(exact).max() > 0.05
    error = np.abs(u - exact).max()
    print(f"{cell}/{material}: max nodal error {error:.3e}")
    assert error < 1e-11, f"{cell}/{material}: max nodal error {error:.3e}"
    # The interior is really distorted (not a trivially regular grid).
    h = BOX / np.array(N)
    spacing = x[interior] / h
    assert np.abs(spacing - np.round(spacing)).max() > 0.1


@pytest.mark.parametrize("cell", ["hexahedron", "tetrahedron"])
def test_patch_test_detects_a_wrong_boundary_value(cell):
    """Guard: a non-affine boundary displacement does not give the affine interior."""
    msh, interior = distorted_box(cell)
    body = FemBody(msh, MATERIALS["neo-hookean"], density=1000.0)
    inputs = np.asarray(msh.geometry.input_global_indices)
    body.fix_nodes(
        inputs[~interior], displacement=lambda x: affine(x) + 0.02 * np.sin(3 * x[[1, 2, 0]])
    )
    scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
    scene.add(body)
    scene.solve_static()
    u = body.u.x.array.reshape(-1, 3)[body.local_dofs(inputs[interior])]
    assert np.abs(u - affine(msh.geometry.x[interior].T).T).max() > 1e-4


@pytest.mark.parametrize("cell", ["hexahedron", "tetrahedron"])
def test_lumped_mass_sums_to_density_times_volume(cell):
    msh, _ = distorted_box(cell)
    rho = 1070.0
    body = FemBody(msh, MATERIALS["neo-hookean"], density=rho)
    expected = rho * np.prod(BOX)
    assert body.total_mass() == pytest.approx(expected, rel=1e-12)
    # Every lumped entry is positive (row sums of a P1/Q1 mass are positive).
    body.compile()
    assert body.M_lumped.array.min() > 0


@pytest.mark.parametrize("cell", ["hexahedron", "tetrahedron"])
def test_consistent_and_lumped_mass_give_the_same_momentum(cell):
    msh, _ = distorted_box(cell)
    rho = 1070.0
    velocity = np.array([0.3, -1.2, 0.7])
    momenta = {}
    for kind in ("lumped", "consistent"):
        body = FemBody(msh, MATERIALS["neo-hookean"], density=rho, mass=kind, name=kind)
        body.compile()
        body.v.x.array.reshape(-1, 3)[:] = velocity
        Mv = body.v.x.petsc_vec.duplicate()
        body.mass_mult(body.v.x.petsc_vec, Mv)
        local = Mv.array.reshape(-1, 3).sum(axis=0)
        momenta[kind] = msh.comm.allreduce(local)
        # Kinetic energy of a rigid translation: 1/2 m |v|^2 for both mass kinds.
        assert body.kinetic_energy() == pytest.approx(
            0.5 * rho * np.prod(BOX) * velocity @ velocity, rel=1e-12
        )
        Mv.destroy()
    expected = rho * np.prod(BOX) * velocity
    np.testing.assert_allclose(momenta["lumped"], expected, rtol=1e-12)
    np.testing.assert_allclose(momenta["consistent"], momenta["lumped"], rtol=1e-12)


def test_material_parameters_are_run_time_constants():
    """Bodies that differ only in kappa and density share their compiled kernels (no new
    JIT compilation per value), and each still gets its own values: at u = 0 the tangent
    is K_shear + kappa K_vol, linear in kappa, and the lumped mass scales with rho."""
    msh, _ = distorted_box("hexahedron")
    tangents, masses, signatures = [], [], []
    for k, (kappa, rho) in enumerate([(1.0e4, 900.0), (2.0e4, 1000.0), (3.0e4, 1100.0)]):
        body = FemBody(
            msh,
            MooneyRivlin(1037.0, C20=486.0, kappa=kappa),
            density=rho,
            incompressibility=100.0 * (k + 1),
        )
        body.compile()
        body.assemble(tangent=True)
        form = body._compiled["K"]
        signatures.append(form.module.ffi.string(form.ufcx_form.signature))
        tangents.append(body.K.copy().convert("dense").getDenseArray().copy())
        masses.append(body.M_lumped.array.sum())
    assert signatures[0] == signatures[1] == signatures[2]
    step1, step2 = tangents[1] - tangents[0], tangents[2] - tangents[1]
    assert np.abs(step1).max() > 1e-3 * np.abs(tangents[0]).max()
    np.testing.assert_allclose(step2, step1, atol=1e-9 * np.abs(tangents[2]).max())
    np.testing.assert_allclose(np.array(masses) / masses[0], [1.0, 10 / 9, 11 / 9], rtol=1e-12)
