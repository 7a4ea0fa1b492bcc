"""Mesh convergence of static hyperelasticity by the method of manufactured solutions.

A smooth exact displacement u_e(X) (a few percent, not zero on the boundary) is
chosen on the unit cube; the body force that makes it an equilibrium,

    b = -Div P(F(u_e)),   P = dW/dF,   F = I + Grad u_e,

is built symbolically in UFL from the material's own strain energy (ufl.variable
+ ufl.diff), every boundary node is fixed at its exact displacement and the
static problem is solved by FemBody + Scene.solve_static. Errors are integrated
against the UFL expression of u_e with a degree-6 quadrature (far above the
discretization order, so the measured error is the discretization error).

Theory for degree-1 Lagrange elements (Q1 hexahedra, P1 tetrahedra):
||u - u_h||_L2 = O(h^2), |u - u_h|_H1 = O(h). We require observed rates of at
least 1.8 and 0.9 on the two finest pairs of the sequence N = 4, 8, 16.

Quadrature: the default energy degree on P1 tetrahedra is 1 (one point, exact
for the strain energy of a constant F) and it also integrates the load term
b . v. One-point quadrature is exact for polynomials of degree 1, which is the
degree Ciarlet's quadrature theory requires for optimal L2 rates of P1
(degree 2k - 1 with k = 1); the measured rates confirm it (see the tests), so
no explicit quadrature_degree is passed.

Measured on this machine (serial):
  Q1 hex, neo-Hookean:  L2 3.27e-3, 8.26e-4, 2.07e-4 (rates 1.98, 2.00);
                        H1 4.26e-2, 2.14e-2, 1.07e-2 (rates 0.99, 1.00)
  P1 tet, neo-Hookean:  L2 3.68e-3, 9.46e-4, 2.39e-4 (rates 1.96, 1.98);
                        H1 5.03e-2, 2.54e-2, 1.27e-2 (rates 0.99, 1.00)
  Q1 hex, Mooney-Rivlin (quadratic bulk): L2 rates 1.98, 1.99; H1 rates 0.99, 1.00
  P1 tet, Mooney-Rivlin (quadratic bulk): L2 rates 1.94, 1.97; H1 rates 0.99, 1.00
"""

import numpy as np
import pytest
import ufl

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import fem
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.fem_body import FemBody
from artifem.forms import MooneyRivlin, NeoHookean
from artifem.scene import Scene

AMPLITUDE = 0.05
MESHES = (4, 8, 16)
ERROR_DEGREE = 6

NEO = NeoHookean(mu=1.0, lmbda=1.5)
MOONEY_QUADRATIC = MooneyRivlin(0.3, C01=0.2, kappa=5.0, bulk="quadratic")

CELLS = {"hexahedron": dmesh.CellType.hexahedron, "tetrahedron": dmesh.CellType.tetrahedron}


def exact_displacement(x, m):
    """u_e(X) written once for numpy (m=np) and UFL (m=ufl): smooth, non-zero on the boundary."""
    s, c, pi = m.sin, m.cos, np.pi
    return [
        AMPLITUDE * s(pi * x[0]) * c(pi * x[1] / 2) + 0.02 * x[2] ** 2,
        AMPLITUDE * s(pi * x[1]) * (1 + x[0]) + 0.01 * x[0] * x[2],
        AMPLITUDE * c(pi * x[2] / 2) * x[1] - 0.03 * x[0] * x[1] * x[2],
    ]


def boundary_input_nodes(msh) -> np.ndarray:
    """Input indices of the nodes on the boundary of the unit cube."""
    x = msh.geometry.x
    on_boundary = np.any((x < 1e-12) | (x > 1.0 - 1e-12), axis=1)
    return np.asarray(msh.geometry.input_global_indices, dtype=np.int64)[on_boundary]


def manufactured_errors(cell: str, n: int, material) -> tuple[float, float]:
    """(L2 error, H1-seminorm error) of the static FE solution on an n^3 unit cube."""
    msh = dmesh.create_unit_cube(MPI.COMM_WORLD, n, n, n, CELLS[cell])
    body = FemBody(msh, material, density=1.0)
    X = ufl.SpatialCoordinate(msh)
    u_e = ufl.as_vector(exact_displacement(X, ufl))
    F_e = ufl.variable(ufl.Identity(3) + ufl.grad(u_e))
    P_e = ufl.diff(material.strain_energy(F_e), F_e)
    body.set_body_force(-ufl.div(P_e))
    body.fix_nodes(
        boundary_input_nodes(msh), displacement=lambda x: np.array(exact_displacement(x, np))
    )
    scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
    scene.add(body)
    scene.solve_static()

    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": ERROR_DEGREE})
    e = body.u - u_e

    def norm(integrand):
        return np.sqrt(msh.comm.allreduce(fem.assemble_scalar(fem.form(integrand * dx))))

    return norm(ufl.inner(e, e)), norm(ufl.inner(ufl.grad(e), ufl.grad(e)))


def observed_rates(errors) -> np.ndarray:
    """log2 of successive error ratios (the mesh size halves each time)."""
    errors = np.asarray(errors)
    return np.log2(errors[:-1] / errors[1:])


def check_rates(cell: str, material):
    results = [manufactured_errors(cell, n, material) for n in MESHES]
    l2 = [r[0] for r in results]
    h1 = [r[1] for r in results]
    l2_rates, h1_rates = observed_rates(l2), observed_rates(h1)
    print(
        f"{cell} {type(material).__name__}: L2 {np.round(l2, 8)} rates {np.round(l2_rates, 3)}; "
        f"H1 {np.round(h1, 6)} rates {np.round(h1_rates, 3)}"
    )
    # The discretization error must actually be visible (the test can fail on a
    # solution that is exact or wrong by a constant): the coarse L2 error is a
    # fraction of the displacement amplitude, and errors decrease monotonically.
    assert 1e-4 < l2[0] < AMPLITUDE
    assert np.all(np.diff(l2) < 0) and np.all(np.diff(h1) < 0)
    # Theory: L2 rate 2, H1-seminorm rate 1.
    assert np.all(l2_rates >= 1.8), f"L2 rates {l2_rates} (theory: 2)"
    assert np.all(h1_rates >= 0.9), f"H1 rates {h1_rates} (theory: 1)"
    assert np.all(l2_rates <= 2.3) and np.all(h1_rates <= 1.3), "super-convergence: suspicious"


@pytest.mark.parametrize("cell", ["hexahedron", "tetrahedron"])
def test_neo_hookean_manufactured_rates(cell):
    check_rates(cell, NEO)


@pytest.mark.slow
@pytest.mark.parametrize("cell", ["hexahedron", "tetrahedron"])
def test_mooney_rivlin_quadratic_bulk_manufactured_rates(cell):
    check_rates(cell, MOONEY_QUADRATIC)


def test_manufactured_solution_is_not_trivially_satisfied():
    """Guard: without the body force the solver must NOT find u_e (error stays O(amplitude))."""
    msh = dmesh.create_unit_cube(MPI.COMM_WORLD, 4, 4, 4, dmesh.CellType.hexahedron)
    body = FemBody(msh, NEO, density=1.0)
    body.fix_nodes(
        boundary_input_nodes(msh), displacement=lambda x: np.array(exact_displacement(x, np))
    )
    scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
    scene.add(body)
    scene.solve_static()
    X = ufl.SpatialCoordinate(msh)
    e = body.u - ufl.as_vector(exact_displacement(X, ufl))
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": ERROR_DEGREE})
    l2 = np.sqrt(fem.assemble_scalar(fem.form(ufl.inner(e, e) * dx)))
    with_force, _ = manufactured_errors("hexahedron", 4, NEO)
    assert l2 > 3 * with_force
