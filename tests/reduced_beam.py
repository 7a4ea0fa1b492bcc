"""The small muscle-driven beam the reduced-body tests share, basis helpers, and a
counting scene builder."""

import numpy as np
import ufl

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from dolfinx import mesh as dmesh
from mpi4py import MPI

from artifem.fem_body import FemBody
from artifem.forms import BlemkerFiber, NeoHookean


def make_body(
    *,
    mass="lumped",
    excitation=0.5,
    young=1.0e5,
    gravity=(0.0, 0.0, -9.81),
    loads=True,
    rayleigh=(0.5, 0.01),
    incompressibility=2.0e5,
    comm=MPI.COMM_WORLD,
):
    """A 4x2x2 hex beam clamped at x = 0: gravity, (body force, tip load), a muscle on top."""
    msh = dmesh.create_box(
        comm, [np.zeros(3), np.array([1.0, 0.3, 0.2])], [4, 2, 2], dmesh.CellType.hexahedron
    )
    body = FemBody(
        msh,
        NeoHookean.from_young_poisson(young, 0.3),
        1000.0,
        mass=mass,
        rayleigh=rayleigh,
        gravity=gravity,
        incompressibility=incompressibility,
    )
    x = msh.geometry.x
    inputs = np.asarray(msh.geometry.input_global_indices, dtype=np.int64)
    body.fix_nodes(inputs[x[:, 0] < 1e-12])
    if loads:
        body.add_nodal_load(inputs[np.abs(x[:, 0] - 1.0) < 1e-12], [0.0, 0.5, 0.0])
        X = ufl.SpatialCoordinate(msh)
        body.set_body_force(ufl.as_vector([0.0, 100.0 * X[0], 0.0]))
    n = msh.topology.index_map(3).size_local
    centroids = x[msh.geometry.dofmaps[0][:n]].mean(axis=1)
    cells = np.asarray(msh.topology.original_cell_index[:n])[centroids[:, 2] > 0.1]
    rng = np.random.default_rng(1)
    directions = np.array([1.0, 0.0, 0.0]) + 0.3 * rng.standard_normal((cells.size, 3))
    body.add_muscle("top", cells, directions, BlemkerFiber(2.0e4), excitation=excitation)
    return body


def ndofs(body):
    return 3 * body.V.dofmap.index_map.size_local


def free_rows(body):
    fixed = (3 * body.fixed_dofs[:, None] + np.arange(3)).ravel()
    return np.setdiff1d(np.arange(ndofs(body)), fixed)


def full_basis(body):
    """The identity on the free dofs."""
    free = free_rows(body)
    U = np.zeros((ndofs(body), free.size))
    U[free, np.arange(free.size)] = 1.0
    return U


def random_basis(body, r, seed=0, scale=1.0):
    rng = np.random.default_rng(seed)
    U = np.zeros((ndofs(body), r))
    U[free_rows(body)] = scale * rng.standard_normal((free_rows(body).size, r))
    return U


class Builds:
    """A model's build() that counts its calls."""

    def __init__(self, make):
        self.make, self.count = make, 0

    def __call__(self):
        self.count += 1
        return self.make()
