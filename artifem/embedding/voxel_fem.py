"""Embedded (voxel) FEM with volume-fraction weighting (Nesme et al. 2009; Lloyd et al. 2019,
section 4, the masseter).

A closed triangle surface is embedded in a regular grid of hexahedra that covers
its bounding box. Each cell e gets the fraction phi_e in (0, 1] of its volume
inside the surface; empty cells are dropped, and the density and every energy
density of the remaining cells are multiplied by phi_e (a DG0 field):

    Pi(u) = sum_e phi_e int_e psi(F) dX  -  int rho phi g . u dX,
    M     = int rho phi N N^T dX,

so the model's mass is rho sum_e phi_e V_e ~ rho V(surface). The surface is
embedded in the grid (:class:`~artifem.embedding.embedded_mesh.EmbeddedMesh`)
for display and loads.

Volume fractions (:func:`voxelize`): a cell farther than half its diagonal
from the surface (exact unsigned distance, VTK's implicit poly-data distance)
is entirely inside or outside, decided by an inside test of its centre; its
fraction is exactly 1 or 0. A cell closer to the surface is sampled at the
centres of s^3 sub-cells (``samples`` = s), each classified by the inside test,
phi_e = (inside sub-cells) / s^3. The inside test is VTK's
vtkSelectEnclosedPoints (``inside="vtk"``, the default: ray casting from the
point with several rays and a vote, fast C++) or the generalized winding number
(``inside="winding"``: the sum of the triangles' solid angles, > 1/2 inside; no
rays, so no degenerate ray-edge hits, but O(points x triangles) in numpy, about
0.5 ms per point on a 3000-triangle surface). Only sub-cells that
the surface crosses can be misclassified, and those lie within delta = the
sub-cell diagonal of the surface, so the volume error is bounded by the
volume of that band, |sum phi_e V_e - V| <= 2 A delta for a surface of area A
(much less in practice: the errors of the crossed sub-cells partly cancel).
The error therefore falls like h / s.

FemBody takes a float density, but uses it only inside UFL forms, and takes
its internal energy from :meth:`~artifem.fem_body.FemBody.energy_terms`; so
:class:`VoxelFemBody` is a FemBody subclass that sets ``density`` to the UFL
field rho phi and multiplies every energy term's density (bulk material,
muscles' fiber energies, element incompressibility penalty) by phi. FemBody
itself is unchanged. Body forces passed to ``set_body_force`` are per unit of
*solid* volume and are weighted by phi too. A ReducedFemBody of a voxel body is
not supported yet: its point stress kernels would need phi as a per-point
weight (it is constant per cell, so it could be folded into the cubature
weights).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import basix.ufl
import numpy as np
from dolfinx import fem, mesh as dmesh
from mpi4py import MPI

from artifem.errors import InputError
from artifem.embedding.embedded_mesh import EmbeddedMesh
from artifem.fem_body import FemBody

__all__ = [
    "Voxelization",
    "voxelize",
    "voxel_mesh",
    "winding_number",
    "enclosed_volume",
    "surface_area",
    "VoxelFemBody",
]


def _check_surface(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    V = np.asarray(vertices, dtype=float)
    T = np.asarray(triangles, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or T.ndim != 2 or T.shape[1] != 3 or T.size == 0:
        raise InputError(
            f"a surface needs vertices (n, 3) and triangles (m, 3), got {V.shape} and {T.shape}"
        )
    if T.min() < 0 or T.max() >= V.shape[0]:
        raise InputError("triangle vertex indices out of range")
    return V, T


def enclosed_volume(vertices, triangles) -> float:
    """Signed volume enclosed by a closed triangle surface (divergence theorem; > 0 when the
    triangles are oriented outward)."""
    V, T = _check_surface(vertices, triangles)
    a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


def surface_area(vertices, triangles) -> float:
    V, T = _check_surface(vertices, triangles)
    a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


def winding_number(points, vertices, triangles, chunk: int = 4_000_000) -> np.ndarray:
    """Generalized winding number of a triangle surface at ``points`` (p, 3).

    Sum of the triangles' signed solid angles over 4 pi (Van Oosterom and Strackee):
    1 inside and 0 outside a closed surface oriented outward, whatever its shape.
    """
    V, T = _check_surface(vertices, triangles)
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.empty(P.shape[0])
    step = max(1, chunk // T.shape[0])
    A, B, C = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    for s in range(0, P.shape[0], step):
        p = P[s : s + step, None, :]
        a, b, c = A[None] - p, B[None] - p, C[None] - p
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        num = np.einsum("ptk,ptk->pt", a, np.cross(b, c))
        den = (
            la * lb * lc
            + np.einsum("ptk,ptk->pt", a, b) * lc
            + np.einsum("ptk,ptk->pt", b, c) * la
            + np.einsum("ptk,ptk->pt", c, a) * lb
        )
        out[s : s + step] = np.arctan2(num, den).sum(axis=1) / (2.0 * np.pi)
    return out


@dataclass(frozen=True)
class Voxelization:
    """Kept cells of a regular grid around a surface, with their inside volume fractions."""

    origin: np.ndarray  # (3,) lower corner of the grid
    spacing: np.ndarray  # (3,) cell edge lengths
    divisions: tuple  # (nx, ny, nz) cells of the full grid
    ijk: np.ndarray  # (c, 3) grid indices of the kept cells
    fraction: np.ndarray  # (c,) inside volume fraction, in (0, 1]
    samples: int  # s: s^3 sub-cell samples in cells near the surface
    sampled: int  # how many cells were sampled

    @property
    def cell_volume(self) -> float:
        return float(np.prod(self.spacing))

    @property
    def volume(self) -> float:
        """sum_e phi_e V_e: the voxelized volume of the surface."""
        return float(self.fraction.sum() * self.cell_volume)

    @property
    def sample_diagonal(self) -> float:
        """delta: the diagonal of a sub-cell (the error band's half width)."""
        return float(np.linalg.norm(self.spacing) / self.samples)


def voxelize(
    vertices,
    triangles,
    divisions=None,
    *,
    cell_size: float | None = None,
    bounds=None,
    samples: int = 4,
    inside: str = "vtk",
) -> Voxelization:
    """Inside volume fractions of the cells of a regular grid around a closed surface.

    Args:
        vertices, triangles: the closed surface (outward or inward orientation).
        divisions: (nx, ny, nz) cells over ``bounds``; or give ``cell_size`` instead
            (cubic cells, the grid then starts at the lower bound and may overhang).
        bounds: (lower, upper) corners of the grid (default: the surface's bounding box,
            so grid planes coincide with its extreme faces).
        samples: s, the sub-cells per edge in cells near the surface (see the module
            docstring for the error).
        inside: the inside test, "vtk" or "winding" (see the module docstring).
    """
    V, T = _check_surface(vertices, triangles)
    if inside not in ("vtk", "winding"):
        raise InputError(f"voxelize: inside must be 'vtk' or 'winding', got {inside!r}")
    if enclosed_volume(V, T) < 0:
        T = T[:, ::-1]
    lo, hi = (
        (V.min(axis=0), V.max(axis=0))
        if bounds is None
        else (np.asarray(bounds[0], float), np.asarray(bounds[1], float))
    )
    if (divisions is None) == (cell_size is None):
        raise InputError("voxelize: give exactly one of divisions and cell_size")
    if divisions is None:
        if not cell_size > 0:
            raise InputError(f"voxelize: cell_size must be > 0, got {cell_size}")
        n = np.maximum(np.ceil((hi - lo) / cell_size - 1e-9).astype(int), 1)
        h = np.full(3, float(cell_size))
    else:
        n = np.asarray(divisions, dtype=int).reshape(3)
        if np.any(n < 1):
            raise InputError(f"voxelize: divisions must be >= 1, got {n.tolist()}")
        h = (hi - lo) / n
    if samples < 1:
        raise InputError(f"voxelize: samples must be >= 1, got {samples}")
    import pyvista as pv

    ijk = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij"), -1).reshape(-1, 3)
    centres = lo + (ijk + 0.5) * h
    surface = pv.PolyData(V, np.c_[np.full(len(T), 3), T].ravel())
    dist = np.abs(
        np.asarray(pv.PolyData(centres).compute_implicit_distance(surface)["implicit_distance"])
    )
    near = dist <= 0.5 * np.linalg.norm(h) * (1.0 + 1e-9)
    fraction = np.zeros(len(ijk))
    far = ~near

    def is_inside(points):
        if inside == "winding":
            return winding_number(points, V, T) > 0.5
        selected = pv.PolyData(points).select_interior_points(
            surface, method="cell_locator", check_surface=False
        )
        return np.asarray(selected["selected_points"], dtype=bool)

    fraction[far] = is_inside(centres[far]).astype(float)
    if np.any(near):
        g = (np.arange(samples) + 0.5) / samples
        sub = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)  # (s^3, 3)
        pts = lo + (ijk[near][:, None, :] + sub[None]) * h
        fraction[near] = is_inside(pts.reshape(-1, 3)).reshape(-1, sub.shape[0]).mean(axis=1)
    keep = fraction > 0
    return Voxelization(
        lo, h, tuple(int(k) for k in n), ijk[keep], fraction[keep], samples, int(near.sum())
    )


def voxel_mesh(vox: Voxelization, comm: MPI.Comm = MPI.COMM_WORLD) -> dmesh.Mesh:
    """The kept cells as a DOLFINx hexahedral mesh (input cell c is ``vox.ijk[c]``)."""
    corners = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]]
    )  # basix order
    nx, ny, nz = vox.divisions
    node_ijk = vox.ijk[:, None, :] + corners[None]  # (c, 8, 3)
    node_id = (node_ijk[..., 0] * (ny + 1) + node_ijk[..., 1]) * (nz + 1) + node_ijk[..., 2]
    used, cells = np.unique(node_id, return_inverse=True)
    cells = cells.reshape(-1, 8).astype(np.int64)
    k = used % (nz + 1)
    j = (used // (nz + 1)) % (ny + 1)
    i = used // ((nz + 1) * (ny + 1))
    points = vox.origin + np.c_[i, j, k] * vox.spacing
    element = basix.ufl.element("Lagrange", "hexahedron", 1, shape=(3,))
    if comm.rank != 0:
        cells, points = np.empty((0, 8), dtype=np.int64), np.empty((0, 3))
    return dmesh.create_mesh(comm, cells, element, points)


class VoxelFemBody(FemBody):
    """An embedded-FEM body: a voxel grid around a closed surface, weighted by volume fraction.

    Args:
        vertices, triangles: the closed surface.
        divisions / cell_size / bounds / samples / inside: the grid (see :func:`voxelize`).
        material, density and keyword arguments: as for :class:`~artifem.fem_body.FemBody`
            (density is the solid's rho; the model uses rho phi).

    Attributes:
        voxels: the :class:`Voxelization`.
        fraction: the DG0 volume-fraction field phi.
        surface: the surface embedded in the grid (snapped: a surface vertex in a cell
            whose samples all fell outside lies in a dropped cell; see ``surface.distance``).
    """

    def __init__(
        self,
        vertices,
        triangles,
        material,
        density: float,
        divisions=None,
        *,
        cell_size: float | None = None,
        bounds=None,
        samples: int = 4,
        inside: str = "vtk",
        comm: MPI.Comm = MPI.COMM_WORLD,
        **kwargs,
    ):
        vox = voxelize(
            vertices,
            triangles,
            divisions,
            cell_size=cell_size,
            bounds=bounds,
            samples=samples,
            inside=inside,
        )
        msh = voxel_mesh(vox, comm)
        super().__init__(msh, material, density, **kwargs)
        self.voxels, self.solid_density = vox, float(density)
        W = fem.functionspace(msh, ("DG", 0))
        self.fraction = fem.Function(W, name="volume_fraction")
        tdim = msh.topology.dim
        imap = msh.topology.index_map(tdim)
        n_local = imap.size_local + imap.num_ghosts
        original = np.asarray(msh.topology.original_cell_index[:n_local])
        self.fraction.x.array[W.dofmap.list[:n_local, 0]] = vox.fraction[original]
        self.density = self.solid_density * self.fraction  # UFL: rho phi
        V, T = _check_surface(vertices, triangles)
        self.surface = (
            EmbeddedMesh(self, V, T, "triangle", snap=True, name="surface")
            if comm.size == 1
            else None
        )

    def energy_terms(self, merged: bool = False):
        phi = self.fraction
        return [
            dataclasses.replace(t, density=lambda F, a0, d=t.density: phi * d(F, a0))
            for t in super().energy_terms(merged)
        ]

    def set_body_force(self, b) -> None:
        """Body force per unit solid volume (weighted by phi here)."""
        super().set_body_force(self.fraction * b)

    def weighted_mass(self) -> float:
        """rho sum_e phi_e V_e (from the voxelization; equals ``total_mass()``)."""
        return self.solid_density * self.voxels.volume
