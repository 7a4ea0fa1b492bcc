"""Muscles merged into layers (artifem/muscle_layers.py): the body's one integral per layer
is the sum of the muscles' own integrals, at any excitation.

Reference: each muscle's fiber energy assembled alone (its own cells, direction, constants
and excitation, as energy_terms() gives it), summed, against the body's residual and
tangent minus those of the same body without muscles.
"""

import numpy as np
import pytest
import ufl
from mpi4py import MPI
from scipy import sparse

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import fem, mesh
from dolfinx.fem import petsc as fem_petsc

from artifem.fem_body import FemBody
from artifem.forms import BlemkerFiber, NeoHookean

MATERIAL = NeoHookean.from_young_poisson(1e4, 0.3)


def _box():
    return mesh.create_box(
        MPI.COMM_WORLD, [[0, 0, 0], [1.0, 0.4, 0.4]], [5, 2, 2], mesh.CellType.hexahedron
    )


def _muscles(body, rng):
    """Four muscles on overlapping cell ranges (cells in up to three of them), with their
    own directions and max_stress; the fourth of another fiber kind (its own integral)."""
    n = body.mesh.topology.index_map(3).size_global
    spans = {"a": range(0, 12), "b": range(6, 18), "c": range(8, 20), "d": range(4, 14)}
    for k, (name, span) in enumerate(spans.items()):
        cells = np.array(list(span)) % n
        fiber = BlemkerFiber(max_stress=1e3 * (k + 1), P2=6.6 if name != "d" else 4.0)
        body.add_muscle(
            name, cells, rng.standard_normal((cells.size, 3)), fiber, excitation=0.2 * (k + 1)
        )


def _alone(body, term):
    """(R, K) of one energy term assembled on its own at the body's u."""
    F = body.kinematics()
    dx = ufl.Measure(
        "dx",
        domain=body.mesh,
        metadata={"quadrature_degree": term.degree},
        subdomain_data=[(1, term.cells)],
    )(1)
    Pi = term.density(F, term.direction) * dx
    v, du = ufl.TestFunction(body.V), ufl.TrialFunction(body.V)
    R = ufl.derivative(Pi, body.u, v)
    r = fem_petsc.assemble_vector(fem.form(R)).array.copy()
    K = fem_petsc.assemble_matrix(fem.form(ufl.derivative(R, body.u, du)))
    K.assemble()
    return r, _dense(K)


def _dense(A):
    """A copy of a PETSc AIJ matrix as a numpy array (Mat.convert would change A itself)."""
    indptr, indices, values = A.getValuesCSR()
    return sparse.csr_matrix((values, indices, indptr), shape=A.getSize()).toarray()


def _assembled(body):
    body.assemble(tangent=True)
    return body.R.array.copy(), _dense(body.K)


def test_the_layers_assemble_the_sum_of_the_muscles():
    rng = np.random.default_rng(7)
    body = FemBody(_box(), MATERIAL, 1000.0, gravity=(0, 0, 0))
    bare = FemBody(_box(), MATERIAL, 1000.0, gravity=(0, 0, 0))
    _muscles(body, rng)
    layers = body._muscle_layers().layers
    assert len(layers) == 3 + 1  # three deep for b, c, a; d alone
    u = 0.03 * rng.standard_normal(body.u.x.array.size)
    for excitations in ({}, {"a": 1.0, "b": 0.0, "c": 0.55, "d": 0.9}):
        for name, value in excitations.items():
            body.set_excitation(name, value)
        body.u.x.array[:] = bare.u.x.array[:] = u
        R, K = _assembled(body)
        R0, K0 = _assembled(bare)
        r_sum, k_sum = np.zeros_like(R), np.zeros_like(K)
        for term in body.energy_terms():
            if term.name.startswith("muscle:"):
                r, k = _alone(body, term)
                r_sum += r
                k_sum += k
        assert np.abs(r_sum).max() > 1.0
        np.testing.assert_allclose(R - R0, r_sum, atol=1e-11 * np.abs(r_sum).max())
        np.testing.assert_allclose(K - K0, k_sum, atol=1e-11 * np.abs(k_sum).max())


def test_the_layers_compile_one_kernel_per_layer():
    """Ten muscles of one fiber kind on disjoint cells, each with its own max_stress and
    direction: one layer, so the tangent has two cell integrals (material, layer), not 11."""
    rng = np.random.default_rng(1)
    body = FemBody(_box(), MATERIAL, 1000.0, gravity=(0, 0, 0))
    for k in range(10):
        body.add_muscle(
            f"m{k}",
            [2 * k, 2 * k + 1],
            rng.standard_normal(3),
            BlemkerFiber(max_stress=100.0 * (k + 1)),
        )
    assert len(body._muscle_layers().layers) == 1
    body.compile()
    assert body._compiled["K"].num_integrals(fem.IntegralType.cell, 0) == 2  # material, layer


@pytest.mark.parametrize("excitation", [0.0, 0.7])
def test_a_muscle_with_point_directions_merges_with_its_kind(excitation):
    """Directions per quadrature point (a quadrature space) are copied per cell like DG0 ones:
    the energy of two such muscles equals that of the body stepped with each alone."""
    energies = []
    for which in ("both", "p", "q"):
        body = FemBody(_box(), MATERIAL, 1000.0, gravity=(0, 0, 0))
        W = body.quadrature_space()
        for name, cells in (("p", np.arange(0, 10)), ("q", np.arange(5, 15))):
            if which not in ("both", name):
                continue
            a0 = fem.Function(W)
            d = np.random.default_rng(len(name) + ord(name)).standard_normal(
                (a0.x.array.size // 3, 3)
            )
            a0.x.array[:] = (d / np.linalg.norm(d, axis=1)[:, None]).ravel()
            body.add_muscle(name, cells, a0, BlemkerFiber(max_stress=2e3), excitation=excitation)
        body.u.x.array[:] = 0.05 * np.random.default_rng(11).standard_normal(body.u.x.array.size)
        energies.append(body.potential_energy())
    bare = FemBody(_box(), MATERIAL, 1000.0, gravity=(0, 0, 0))
    bare.u.x.array[:] = 0.05 * np.random.default_rng(11).standard_normal(bare.u.x.array.size)
    e0 = bare.potential_energy()
    both, p, q = energies
    assert abs(both - e0) > 1e-6
    assert abs((both - e0) - ((p - e0) + (q - e0))) < 1e-12 * abs(both - e0)
