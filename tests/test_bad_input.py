"""Clear errors for bad input at the FEM level (FemBody, Scene).

Mesh files are tested in test_io.py and material parameters in test_forms.py.
Each error must be a ValueError/KeyError that says what is wrong and where,
raised before any computation, and must leave the model unchanged.
"""

import math

import numpy as np
import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.errors import InputError
from artifem.fem_body import FemBody
from artifem.forms import BlemkerFiber, NeoHookean
from artifem.linear_solver import LinearSolver
from artifem.scene import Scene

MATERIAL = NeoHookean.from_young_poisson(1.0e4, 0.3)
N_NODES = 3 * 3 * 3  # a 2 x 2 x 2 hexahedral box
N_CELLS = 8


@pytest.fixture
def msh():
    return dmesh.create_box(
        MPI.COMM_WORLD, [np.zeros(3), np.ones(3)], [2, 2, 2], dmesh.CellType.hexahedron
    )


@pytest.fixture
def body(msh):
    return FemBody(msh, MATERIAL, 1000.0, name="cube")


# ---- FemBody construction -------------------------------------------------------------------


@pytest.mark.parametrize("density", [-1000.0, 0.0, math.nan, math.inf])
def test_density_must_be_positive_and_finite(msh, density):
    with pytest.raises(ValueError, match=r"'cube'.*density must be > 0, got"):
        FemBody(msh, MATERIAL, density, name="cube")


@pytest.mark.parametrize("rayleigh", [(-0.1, 0.0), (0.0, -1e-3), (math.nan, 0.0), (0.0, math.inf)])
def test_rayleigh_coefficients_must_be_finite_and_nonnegative(msh, rayleigh):
    with pytest.raises(ValueError, match=r"Rayleigh coefficients must be finite and >= 0"):
        FemBody(msh, MATERIAL, 1000.0, rayleigh=rayleigh)


def test_unknown_mass_kind(msh):
    with pytest.raises(ValueError, match=r"mass must be 'lumped' or 'consistent', got 'diagonal'"):
        FemBody(msh, MATERIAL, 1000.0, mass="diagonal")


def test_unsupported_cell_type_is_named():
    triangles = dmesh.create_unit_square(MPI.COMM_WORLD, 2, 2, dmesh.CellType.triangle)
    with pytest.raises(
        ValueError, match=r"unsupported cell type 'triangle'.*hexahedron.*tetrahedron"
    ):
        FemBody(triangles, MATERIAL, 1000.0)


# ---- nodes and loads ------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["fix_nodes", "add_nodal_load", "displacement_at"])
@pytest.mark.parametrize("bad", [N_NODES, -1, 10**6])
def test_node_indices_out_of_range_say_which(body, method, bad):
    nodes = [0, 5, bad]
    args = (nodes, [0.0, 0.0, 1.0]) if method == "add_nodal_load" else (nodes,)
    with pytest.raises(ValueError) as info:
        getattr(body, method)(*args)
    message = str(info.value)
    assert method in message and "'cube'" in message
    assert f"[0, {N_NODES})" in message and f"[{bad}]" in message
    # Nothing was applied.
    assert body.fixed_dofs.size == 0
    assert body.nodal_load.norm() == 0.0


# ---- muscles --------------------------------------------------------------------------------


def test_muscle_with_a_zero_direction_names_the_element(body):
    directions = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    with pytest.raises(ValueError, match=r"muscle 'm'.*zero or non-finite fiber direction.*\[4\]"):
        body.add_muscle("m", [2, 4, 6], directions, BlemkerFiber(1.0e4))
    assert "m" not in body.muscles


def test_muscle_with_a_nan_direction(body):
    with pytest.raises(ValueError, match=r"non-finite fiber direction"):
        body.add_muscle("m", [1], [math.nan, 0.0, 1.0], BlemkerFiber(1.0e4))


@pytest.mark.parametrize("cells", [[], [0, N_CELLS], [-1]])
def test_muscle_cells_out_of_range(body, cells):
    with pytest.raises(
        ValueError, match=rf"cell indices must be a non-empty subset of \[0, {N_CELLS}\)"
    ):
        body.add_muscle("m", cells, [1.0, 0.0, 0.0], BlemkerFiber(1.0e4))


def test_duplicate_muscle_name(body):
    body.add_muscle("m", [0], [1.0, 0.0, 0.0], BlemkerFiber(1.0e4))
    with pytest.raises(ValueError, match=r"muscle 'm' already defined"):
        body.add_muscle("m", [1], [1.0, 0.0, 0.0], BlemkerFiber(1.0e4))


@pytest.mark.parametrize("value", [-0.1, 1.5, math.nan])
def test_excitation_outside_unit_interval(body, value):
    body.add_muscle("m", [0, 1], [1.0, 0.0, 0.0], BlemkerFiber(1.0e4), excitation=0.2)
    with pytest.raises(ValueError, match=r"excitation of 'm' must be in \[0, 1\]"):
        body.set_excitation("m", value)
    assert body.muscles["m"].excitation.value == pytest.approx(0.2)


@pytest.mark.parametrize("value", [-0.1, 1.5])
def test_initial_excitation_outside_unit_interval(body, value):
    with pytest.raises(ValueError, match=r"excitation"):
        body.add_muscle("m", [0, 1], [1.0, 0.0, 0.0], BlemkerFiber(1.0e4), excitation=value)


def test_unknown_muscle_name(body):
    body.add_muscle("m", [0], [1.0, 0.0, 0.0], BlemkerFiber(1.0e4))
    with pytest.raises(KeyError, match=r"unknown muscle 'x'; defined: \['m'\]"):
        body.set_excitation("x", 0.5)


# ---- scene ----------------------------------------------------------------------------------


def test_unknown_integrator():
    with pytest.raises(InputError, match=r"unknown integrator 'rk4'.*implicit.*semi-implicit"):
        Scene(integrator="rk4")


def test_unknown_fallback_integrator():
    with pytest.raises(InputError, match=r"fallback must be 'implicit' or None, got 'rk4'"):
        Scene(fallback="rk4")


def test_a_step_tolerance_below_the_constraint_tolerance():
    from artifem.incompressibility import Incompressible

    with pytest.raises(InputError, match=r"step_tol must be >= tol \(0\.001\), got 0\.0001"):
        Incompressible(kappa=1e4, tol=1e-3, step_tol=1e-4)


def test_unknown_linear_solver_in_the_solver():
    with pytest.raises(ValueError, match=r"unknown linear solver 'umfpack'; choose one of .*mumps"):
        LinearSolver(MPI.COMM_WORLD, "umfpack")


def test_unknown_linear_solver_fails_before_the_first_step_changes_anything(body):
    body.fix_nodes([0, 1, 2])
    body.gravity.value[:] = (0.0, 0.0, -9.81)
    # Refused at construction, before any body is added or stepped.
    with pytest.raises(InputError, match=r"unknown linear solver 'umfpack'; choose one of .*mumps"):
        Scene(gravity=(0.0, 0.0, -9.81), linear_solver="umfpack")
    assert np.abs(body.u.x.array).max() == 0.0


@pytest.mark.parametrize("dt", [0.0, -0.01, math.nan, math.inf])
def test_time_step_must_be_positive_and_finite(body, dt):
    scene = Scene(gravity=(0.0, 0.0, 0.0), linear_solver="mumps")
    scene.add(body)
    with pytest.raises(InputError, match=r"time step must be positive and finite"):
        scene.step(dt)
    assert scene.t == 0.0


def test_the_same_body_added_twice(body):
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(body)
    with pytest.raises(InputError, match=r"a body named 'cube' is already in the scene"):
        scene.add(body)
    assert scene.bodies == [body]


def test_duplicate_body_name(msh, body):
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(body)
    with pytest.raises(InputError, match=r"'cube' is already in the scene"):
        scene.add(FemBody(msh, MATERIAL, 1000.0, name="cube"))


@pytest.mark.parametrize("projections", [-1, 1.5])
def test_a_projection_count_that_is_not_a_count(projections):
    from artifem.incompressibility import Incompressible

    with pytest.raises(InputError, match=r"projections must be an integer >= 0, got "):
        Incompressible(kappa=1e4, projections=projections)
