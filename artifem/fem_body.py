"""Full-order FEM body: nodal displacements on a DOLFINx mesh.

The body's potential energy is

    Pi(u) = int psi(F) dX + sum_m int_{Omega_m} psi_m(F; a0_m, lambda_a a_m) dX
            + sum_e V_e kappa_inc/2 (J(X_e) - 1)^2
            - lambda * (int rho g . u dX + int b . u dX + f_nodal . u + int t . u dA),

with F = I + grad u, psi the bulk material, psi_m the fiber energy of muscle m
(direction field a0_m, excitation a_m), t the dead tractions on boundary facets
and lambda a load factor; lambda_a scales the activation. Both are 1 but in a static
solve, which ramps them together from 0 to 1 (:meth:`FemBody.set_load_factor`).
A follower pressure p (:mod:`artifem.surface_loads`) adds its virtual work to the
residual, R += lambda int p cof(F) N . v dA; it has no potential in general, so
``potential_energy()`` leaves it out (``conservative`` is then False), unless it is
declared closed: then its potential -lambda p V (V the enclosed volume) is part of Pi. The optional
kappa_inc term is an element-wise incompressibility penalty: J at the element
centre (one-point rule), which for hexahedra approximates the element's mean
dilatation, so it penalizes volume change per element without locking the
bending modes (ArtiSynth's soft "element" incompressibility). The hard
alternative, ``incompressibility=Incompressible(...)``, keeps every element's
volume (:mod:`artifem.incompressibility`: an augmented Lagrangian with its
pressure field; its -G^T pi and geometric tangent join R and K, the rank-one
element blocks G^T D G are added to K after assembly). The
internal-plus-external force is f = -dPi/du, the tangent K = d^2 Pi/du^2,
both derived by ``ufl.derivative`` from the UFL energies of ``artifem.forms``.
Mass is lumped (row sums of the consistent mass, ArtiSynth's default) or
consistent; damping is Rayleigh, D = alpha M + beta K_0, with K_0 the tangent of the
body's material at rest (:meth:`FemBody.rest_stiffness`). K_0 is positive semi-definite, so
the damping always dissipates. The current tangent K(u) would not: it loses definiteness
where active fibers or large pressures destabilize the tissue (the tongue under a fast full
co-activation: hundreds of negative eigenvalues down to -8e6 s^-2 in M's metric). beta K(u)
would then be a negative damping that feeds exactly those modes, at a rate that grows as
the step shrinks. The step matrix (1 + h alpha) M + h beta K(u) + h^2 K(u) would stay
indefinite however small h is, and no step halving or Newton iteration would recover.

Node and cell arguments are *input* indices (the order of the mesh file), so
the same script runs in serial and under ``mpiexec``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Callable

import basix
import basix.ufl
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from dolfinx import fem, mesh as dmesh
from dolfinx.fem import petsc as fem_petsc

import artifem.jit  # noqa: F401  (waits for another process's compile of a form)
from artifem.contact_points import FemNodes
from artifem.errors import InputError, UnknownNameError
from artifem.incompressibility import Incompressible, VolumeConstraint
from artifem.muscle_layers import MuscleLayers
from artifem.surface_loads import (
    SurfaceLoad,
    check_closed,
    make_load,
    select_facets,
    surface_measure,
)

#: Default quadrature degree of the energy per cell type: 2x2x2 Gauss for Q1
#: hexahedra (UFL's automatic degree is 14-20 for Mooney-Rivlin on Q1: over a thousand
#: points per cell, one tangent 3.7 s instead of 25 ms);
#: F is constant on a P1 tetrahedron, so one point is exact; degree 2 (2 x 2 x 2
#: Gauss-Jacobi points) on P1 prisms (wedges: linear triangle x linear segment).
ENERGY_DEGREE = {"hexahedron": 2, "tetrahedron": 1, "prism": 2}
#: Mass needs products of two shape functions.
MASS_DEGREE = {"hexahedron": 2, "tetrahedron": 2, "prism": 2}


@dataclass
class Muscle:
    """A fiber-activated region of an FEM body."""

    name: str
    cells: np.ndarray  # owned local cell indices
    direction: fem.Function  # unit fiber direction a0: DG0, or per quadrature point
    fiber: object  # fiber material: strain_energy(F, a0, excitation)
    excitation: fem.Constant  # a in [0, 1], changed between steps without recompiling


@dataclass(frozen=True, eq=False)
class EnergyTerm:
    """One integral of a body's internal energy, int_{cells} density(F, a0) dX.

    ``density(F, a0)`` is the UFL energy density (``a0`` the direction field
    of fiber terms, DG0 or a quadrature function, None otherwise), integrated with a quadrature rule
    of ``degree`` over ``cells`` (owned local cells; None means all). The
    full body assembles the sum of its terms; a reduced body evaluates the
    same densities at its integration points. ``fields_at(cells)``: for a density that
    reads cell-wise fields (a muscle layer's excitations and constants), their values at
    given cells without the full mesh ((static, live()) as in
    :meth:`artifem.muscle_layers._Layer.fields_at`); None when it reads none.
    """

    name: str
    density: Callable
    degree: int
    cells: np.ndarray | None = None
    direction: fem.Function | None = None
    fields_at: Callable | None = None


@dataclass
class PrescribedRamp:
    """Prescribed displacements ramped by a static solve with its load factor f,
    u_d(f) = before + f (after - before) on the local dofs ``dofs``, so that its load
    increments cut a large prescribed stretch as they cut a load (:meth:`FemBody.
    take_prescribed_ramp`; :func:`artifem.integrators.solve_static`)."""

    body: FemBody
    dofs: np.ndarray
    before: np.ndarray
    after: np.ndarray

    def apply(self, factor: float, fraction: float = 1.0, base=None) -> None:
        """u_d = before + factor (after - before); ``fraction`` of the way there from
        ``base`` (:meth:`current`)."""
        u = self.body.u.x
        target = self.before + factor * (self.after - self.before)
        u.array[self.dofs] = target if base is None else base + fraction * (target - base)
        u.scatter_forward()

    def current(self) -> np.ndarray:
        """The prescribed dofs' displacement now."""
        return self.body.u.x.array[self.dofs].copy()

    def give_back(self) -> None:
        """After a solve that failed (the state at its last converged increment): the
        prescribed values written again, the rest of the state where it is, and the ramp
        kept from there for the next solve."""
        u = self.body.u.x
        start = u.array.copy()
        self.apply(1.0)
        self.body._unsettled = (start, u.array.copy())


class FemBody:
    """A deformable body discretized by vector Lagrange elements of degree 1.

    Args:
        domain: DOLFINx mesh (Q1 hexahedra or P1 tetrahedra).
        material: bulk material from ``artifem.forms`` (``strain_energy(F)``).
        density: rho in kg/m^3 (> 0).
        mass: ``"lumped"`` (default) or ``"consistent"``.
        rayleigh: (alpha, beta) of D = alpha M + beta K_0 (K_0: :meth:`rest_stiffness`).
        gravity: acceleration vector (m/s^2).
        quadrature_degree: degree of the energy integrals (default per cell type).
        incompressibility: kappa_inc (Pa) of the soft element-wise volume penalty, or
            :class:`~artifem.incompressibility.Incompressible` for the hard constraint
            (every element keeps its volume), or None.
        name: component name in a system.
    """

    #: the list of :class:`~artifem.scene.Scene` that holds it (``Scene.add``)
    scene_group = "fem_bodies"

    def __init__(
        self,
        domain: dmesh.Mesh,
        material,
        density: float,
        *,
        mass: str = "lumped",
        rayleigh: tuple[float, float] = (0.0, 0.0),
        gravity=(0.0, 0.0, 0.0),
        quadrature_degree: int | None = None,
        incompressibility: float | Incompressible | None = None,
        name: str = "fem",
    ):
        cell_name = domain.topology.cell_name()
        if cell_name not in ENERGY_DEGREE:
            raise InputError(
                f"FemBody {name!r}: unsupported cell type {cell_name!r}; "
                f"supported: {sorted(ENERGY_DEGREE)}"
            )
        if not np.isfinite(density) or density <= 0:
            raise InputError(f"FemBody {name!r}: density must be > 0, got {density}")
        if mass not in ("lumped", "consistent"):
            raise InputError(
                f"FemBody {name!r}: mass must be 'lumped' or 'consistent', got {mass!r}"
            )
        hard = isinstance(incompressibility, Incompressible)
        if (
            incompressibility is not None
            and not hard
            and not (np.isfinite(incompressibility) and incompressibility > 0)
        ):
            raise InputError(
                f"FemBody {name!r}: incompressibility (kappa_inc) must be > 0 or "
                f"None, got {incompressibility}"
            )
        alpha, beta = rayleigh
        if not (np.isfinite(alpha) and np.isfinite(beta)) or alpha < 0 or beta < 0:
            raise InputError(
                f"FemBody {name!r}: Rayleigh coefficients must be finite and >= 0, got {rayleigh}"
            )
        self.name, self.mesh, self.material = name, domain, material
        self.density, self.mass_kind = float(density), mass
        self.alpha, self.beta = float(alpha), float(beta)
        self.cell_name = cell_name
        self.quadrature_degree = quadrature_degree or ENERGY_DEGREE[cell_name]
        #: kappa_inc of the soft penalty (an energy term), or None
        self.incompressibility = None if hard else incompressibility

        self.V = fem.functionspace(domain, ("Lagrange", 1, (3,)))
        self.u = fem.Function(self.V, name="displacement")
        self.v = fem.Function(self.V, name="velocity")
        self.gravity = fem.Constant(domain, np.asarray(gravity, dtype=PETSc.ScalarType))
        #: lambda of the module docstring: scales the external loads
        self.load_factor = fem.Constant(domain, PETSc.ScalarType(1.0))
        #: lambda_a of the module docstring: scales the muscles' excitations
        self.activation_factor = fem.Constant(domain, PETSc.ScalarType(1.0))
        self.body_force = None  # UFL vector expression per reference volume
        self.muscles: dict[str, Muscle] = {}
        self._layers = None  # the muscles' MuscleLayers, built with the forms
        self.surface_loads: dict[str, SurfaceLoad] = {}
        self._surface_ds = (None,)  # (loads, ds measure, subdomain ids) of _surface_terms
        n_blocks = self.V.dofmap.index_map.size_local + self.V.dofmap.index_map.num_ghosts
        self._fixed_mask = np.zeros((n_blocks, 3), dtype=bool)  # fixed components per node
        self._fixed_dofs = np.zeros(0, dtype=np.int32)
        self._partial = False  # some node fixed in some components only
        self._fixed_values = fem.Function(self.V)  # prescribed displacement of fixed dofs
        # (u before, u after) of prescribed displacements written since the state last
        # moved: a static solve ramps them (:meth:`take_prescribed_ramp`)
        self._unsettled = None
        self.nodal_load = fem_petsc.create_vector(self.V)
        self.nodal_load.zeroEntries()
        #: counts the changes of the nodal loads and the body force (a reduced body of this
        #: one projects them again when it changes)
        self.loads_version = 0
        self._node_to_dof = self._input_node_to_dof()
        #: the hard incompressibility (pressure field, multipliers), or None
        self.volume_constraint = VolumeConstraint(self, incompressibility) if hard else None
        self._compiled = None
        self._contact_surface = None  # (boundary dofs, triangles into them)

    # ---- model definition -------------------------------------------------

    def _geometry_node_dofs(self) -> np.ndarray:
        """Local block dof of every local geometry node."""
        node_dofs = np.empty(self.mesh.geometry.x.shape[0], dtype=np.int32)
        node_dofs[self.mesh.geometry.dofmaps[0].reshape(-1)] = self.V.dofmap.list.reshape(-1)
        return node_dofs

    def _input_node_to_dof(self) -> dict[int, int]:
        """Map input node index -> local block dof (owned and ghost)."""
        inputs = self.mesh.geometry.input_global_indices
        return dict(zip(inputs.tolist(), self._geometry_node_dofs().tolist()))

    def local_dofs(self, nodes) -> np.ndarray:
        """Local block dofs of the given input node indices present on this rank."""
        return np.array(
            [
                self._node_to_dof[n]
                for n in np.asarray(nodes).ravel().tolist()
                if n in self._node_to_dof
            ],
            dtype=np.int32,
        )

    def _surface(self) -> tuple[np.ndarray, np.ndarray]:
        """(dofs, triangles): the local blocked dofs of the boundary nodes (sorted) and the
        exterior facets as outward triangles into them (a quadrilateral facet split along
        its 0-3 diagonal); cached, the topology is fixed."""
        if self._contact_surface is None:
            domain = self.mesh
            tdim = domain.topology.dim
            domain.topology.create_connectivity(tdim - 1, tdim)
            facets = dmesh.exterior_facet_indices(domain.topology)
            nodes = dmesh.entities_to_geometry(domain, tdim - 1, facets)
            split = [[0, 1, 2]] if nodes.shape[1] == 3 else [[0, 1, 3], [0, 3, 2]]
            tris = np.vstack([nodes[:, s] for s in split])
            cells = domain.topology.connectivity(tdim - 1, tdim)
            owner = np.array([cells.links(f)[0] for f in facets])
            x = domain.geometry.x
            inside = x[domain.geometry.dofmaps[0][owner]].mean(axis=1)
            inside = np.tile(inside, (len(split), 1))
            a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
            flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), (a + b + c) / 3 - inside) < 0
            tris[flip] = tris[flip][:, ::-1]
            dofs, inverse = np.unique(self._geometry_node_dofs()[tris], return_inverse=True)
            self._contact_surface = (dofs, inverse.reshape(-1, 3))
        return self._contact_surface

    def contact_node_dofs(self, nodes=None) -> tuple[np.ndarray, np.ndarray]:
        """(local blocked dofs, input node indices) of the given input nodes, or of every
        boundary node (None); an InputError for nodes the body does not have."""
        inverse = {d: n for n, d in self._node_to_dof.items()}
        if nodes is None:
            dofs = self._surface()[0]
        else:
            nodes = np.asarray(nodes).ravel()
            if not np.issubdtype(nodes.dtype, np.integer) or not nodes.size:
                raise InputError(
                    f"FEM body {self.name!r}: contact nodes must be input node indices"
                )
            missing = [int(n) for n in nodes if int(n) not in self._node_to_dof]
            if missing:
                raise InputError(f"FEM body {self.name!r} has no nodes {missing[:10]}")
            dofs = self.local_dofs(nodes)
        return dofs, np.array([inverse[int(d)] for d in dofs], dtype=int)

    def contact_points(self, nodes=None) -> FemNodes:
        """The nodes contact may push (:mod:`artifem.contact_points`): the given input
        nodes, or every boundary node."""
        return FemNodes(self, *self.contact_node_dofs(nodes))

    def contact_surface(self) -> tuple[FemNodes, np.ndarray]:
        """(the boundary nodes, the exterior facets as outward triangles into them)."""
        return self.contact_points(None), self._surface()[1]

    def find_nodes(self, marker) -> np.ndarray:
        """Input indices of the nodes whose reference position satisfies ``marker``.

        ``marker(x)`` takes x of shape (3, n) and returns n booleans; the result
        is gathered from every rank (sorted, unique).
        """
        x = self.mesh.geometry.x
        local = self.mesh.geometry.input_global_indices[np.asarray(marker(x.T), dtype=bool)]
        return np.unique(np.concatenate(self.mesh.comm.allgather(np.asarray(local, np.int64))))

    def nearest_node(self, point) -> int:
        """Input index of the node nearest to ``point`` in the reference configuration."""
        x = self.mesh.geometry.x
        d = np.linalg.norm(x - np.asarray(point, dtype=float), axis=1)
        k = int(np.argmin(d)) if d.size else -1
        candidates = self.mesh.comm.allgather(
            (
                float(d[k]) if k >= 0 else np.inf,
                int(self.mesh.geometry.input_global_indices[k]) if k >= 0 else -1,
            )
        )
        return min(candidates)[1]

    def find_cells(self, marker) -> np.ndarray:
        """Input indices of the cells whose reference midpoint satisfies ``marker``."""
        tdim = self.mesh.topology.dim
        owned = np.arange(self.mesh.topology.index_map(tdim).size_local, dtype=np.int32)
        mid = self.mesh.geometry.x[self.mesh.geometry.dofmaps[0][owned]].mean(axis=1)
        local = self.input_cell_index(owned[np.asarray(marker(mid.T), dtype=bool)])
        return np.unique(np.concatenate(self.mesh.comm.allgather(np.asarray(local, np.int64))))

    def _check_nodes(self, nodes, what: str) -> np.ndarray:
        nodes = np.asarray(nodes, dtype=np.int64).ravel()
        n_total = self.mesh.geometry.index_map().size_global
        bad = nodes[(nodes < 0) | (nodes >= n_total)]
        if bad.size:
            raise InputError(
                f"FemBody {self.name!r}: {what}: node indices out of range "
                f"[0, {n_total}): {bad[:10].tolist()}"
            )
        return nodes

    def fix_nodes(self, nodes, displacement=None, components=None) -> None:
        """Fix input nodes (zero velocity); optionally prescribe their displacement.

        ``displacement`` is None (keep 0) or a callable x -> u(x) evaluated at the
        nodes' reference coordinates, x of shape (3, npoints), written into the state at
        once (a static solve that follows ramps it with its load factor:
        :meth:`take_prescribed_ramp`). ``components``
        (e.g. ``(0,)`` for a symmetry plane x = const) fixes only those
        displacement components, the others stay free; None fixes all three.
        Nodes fixed in some components only are handled by the body's own
        solvers (:mod:`artifem.integrators`) and reduced bodies, through
        :attr:`fixed_components`; callers that take whole fixed nodes
        (:attr:`fixed_dofs`: the Scene today) refuse them.
        """
        nodes = self._check_nodes(nodes, "fix_nodes")
        comps = [0, 1, 2]
        if components is not None:
            raw = np.atleast_1d(np.asarray(components, dtype=object)).ravel().tolist()
            if (
                not raw
                or any(
                    isinstance(c, bool) or not isinstance(c, (int, np.integer)) or not 0 <= c <= 2
                    for c in raw
                )
                or len(set(raw)) != len(raw)
            ):
                raise InputError(
                    f"FemBody {self.name!r}: fix_nodes: components must be "
                    f"distinct indices in {{0, 1, 2}} (x, y, z), got {components!r}"
                )
            comps = sorted(int(c) for c in raw)
        dofs = self.local_dofs(nodes)
        for c in comps:
            self._fixed_mask[dofs, c] = True
        self._fixed_dofs = np.flatnonzero(self._fixed_mask.all(axis=1)).astype(np.int32)
        self._partial = bool(np.any(self._fixed_mask.any(axis=1) & ~self._fixed_mask.all(axis=1)))
        if displacement is not None:
            x = self.V.tabulate_dof_coordinates()[dofs]
            vals = np.asarray(displacement(x.T), dtype=float).reshape(3, -1).T
            arr = self._fixed_values.x.array.reshape(-1, 3)
            arr[np.ix_(dofs, comps)] = vals[:, comps]
            before = self.u.x.array.copy()
            if self._unsettled is not None and np.array_equal(before, self._unsettled[1]):
                before = self._unsettled[0]  # still unmoved since the last one
            self.u.x.array.reshape(-1, 3)[np.ix_(dofs, comps)] = vals[:, comps]
            self._unsettled = (before, self.u.x.array.copy())
        self.v.x.array.reshape(-1, 3)[np.ix_(dofs, comps)] = 0.0
        self._compiled = None

    def take_prescribed_ramp(self) -> PrescribedRamp | None:
        """The prescribed displacements that :meth:`fix_nodes` wrote while the state has not
        moved since (a :class:`PrescribedRamp`), or None; taking them forgets them
        (collective)."""
        record, self._unsettled = self._unsettled, None
        unmoved = record is not None and np.array_equal(self.u.x.array, record[1])
        if not self.mesh.comm.allreduce(unmoved, op=MPI.LAND):
            return None
        dofs = np.flatnonzero(record[0] != record[1])
        if not self.mesh.comm.allreduce(dofs.size):  # prescribed where they already were
            return None
        return PrescribedRamp(self, dofs, record[0][dofs], record[1][dofs])

    def _partly_fixed(self) -> bool:
        """True when some node is fixed in some components only."""
        return self._partial

    @property
    def fixed_dofs(self) -> np.ndarray:
        """Local block dofs (nodes) fixed in all three components.

        Raises InputError when some node is fixed in some components only: the
        caller would take it as free (use :attr:`fixed_components`).
        """
        if self._partly_fixed():
            partial = np.flatnonzero(self._fixed_mask.any(axis=1) & ~self._fixed_mask.all(axis=1))
            raise InputError(
                f"FemBody {self.name!r}: {partial.size} node(s) are fixed in some components "
                "only (fix_nodes(..., components=...)); this caller takes whole fixed nodes "
                "(fixed_dofs) and would leave them free. The body's own solvers "
                "(artifem.integrators) and reduced bodies support them (fixed_components); "
                "the Scene does not yet"
            )
        return self._fixed_dofs

    @property
    def fixed_components(self) -> np.ndarray:
        """Local scalar dofs fixed, 3 * node + component (sorted): every fixed component."""
        return np.flatnonzero(self._fixed_mask.ravel()).astype(np.int32)

    def add_nodal_load(self, nodes, force) -> None:
        """Add a constant force (N, shape (3,) or (len(nodes), 3)) at input nodes."""
        nodes = self._check_nodes(nodes, "add_nodal_load")
        force = np.broadcast_to(np.asarray(force, dtype=float), (len(nodes), 3))
        n_owned = self.V.dofmap.index_map.size_local
        with self.nodal_load.localForm() as loc:
            arr = loc.array.reshape(-1, 3)
            for n, f in zip(nodes.tolist(), force):
                d = self._node_to_dof.get(n)
                if d is not None and d < n_owned:  # owned copy only: no double count
                    arr[d] += f
        self.loads_version += 1

    def add_pressure(
        self,
        pressure: float,
        *,
        where=None,
        tags=None,
        values=None,
        surface=None,
        tol: float | None = None,
        name: str | None = None,
        quadrature_degree: int | None = None,
        closed: bool = False,
        center=(0.0, 0.0, 0.0),
    ) -> SurfaceLoad:
        """A follower pressure p (Pa; > 0 pushes into the body) on boundary facets.

        It acts on the deformed faces (virtual work -lambda int p J F^-T N . v dA),
        with its consistent tangent; it has no potential in general (module
        docstring of :mod:`artifem.surface_loads`). ``closed=True`` declares that
        the faces bound a volume (closed, or their border fixed or in symmetry
        planes x_k = center_k with u_k fixed; checked when the body compiles):
        then its potential -lambda p V enters ``potential_energy()``.
        Facets by exactly one of ``where`` (predicate on x of shape (3, n)),
        ``tags`` + ``values`` (facet MeshTags) or ``surface`` ((vertices, faces),
        matched to boundary facets within ``tol``): see
        :func:`artifem.surface_loads.select_facets`. Set it later with
        ``load.set(p)``; it is multiplied by the load factor.
        """
        return self._add_surface_load(
            "pressure",
            pressure,
            where,
            tags,
            values,
            surface,
            tol,
            name,
            quadrature_degree,
            closed,
            center,
        )

    def add_traction(
        self,
        traction,
        *,
        where=None,
        tags=None,
        values=None,
        surface=None,
        tol: float | None = None,
        name: str | None = None,
        quadrature_degree: int | None = None,
    ) -> SurfaceLoad:
        """A dead traction t (3 numbers, Pa per reference area, fixed direction) on
        boundary facets: potential -lambda int t . u dA. Facets and ``set`` as in
        :meth:`add_pressure`."""
        return self._add_surface_load(
            "traction", traction, where, tags, values, surface, tol, name, quadrature_degree
        )

    def _add_surface_load(
        self,
        kind,
        value,
        where,
        tags,
        values,
        surface,
        tol,
        name,
        degree,
        closed=False,
        center=(0.0, 0.0, 0.0),
    ) -> SurfaceLoad:
        if name is None:
            name = f"{kind}{sum(1 for s in self.surface_loads.values() if s.kind == kind)}"
        if name in self.surface_loads:
            raise InputError(f"FemBody {self.name!r}: surface load {name!r} already defined")
        what = f"FemBody {self.name!r}: surface load {name!r}"
        facets = select_facets(
            self.mesh, where=where, tags=tags, values=values, surface=surface, tol=tol, what=what
        )
        load = make_load(self.mesh, kind, name, facets, value, degree, self.name, closed, center)
        self.surface_loads[name] = load
        self._compiled = None
        return load

    @property
    def conservative(self) -> bool:
        """True when ``potential_energy()`` is the whole potential of the body's forces
        (no follower pressure other than closed ones)."""
        return all(load.conservative for load in self.surface_loads.values())

    def _surface_terms(self):
        """(dead traction potential, closed pressures' potential, follower virtual work)
        as UFL forms (None when absent)."""
        loads = list(self.surface_loads.values())
        if not loads:
            return None, None, None
        key = tuple(id(load) for load in loads)
        if self._surface_ds[0] != key:  # one facet tagging per set of loads
            self._surface_ds = (key, *surface_measure(self.mesh, loads))
        _, ds, ids = self._surface_ds
        dead, closed, work = None, None, None
        for load, sub in zip(loads, ids):
            measure = ds(sub, metadata={"quadrature_degree": load.degree})
            if load.follower:
                term = load.virtual_work(
                    self.u, ufl.TestFunction(self.V), self.load_factor, measure
                )
                work = term if work is None else work + term
                if load.closed:
                    term = load.potential(self.u, self.load_factor, measure)
                    closed = term if closed is None else closed + term
            else:
                term = load.potential(self.u, self.load_factor, measure)
                dead = term if dead is None else dead + term
        return dead, closed, work

    def set_body_force(self, b) -> None:
        """Body force per reference volume (UFL vector expression), scaled by the load factor."""
        self.body_force = b
        self.loads_version += 1
        self._compiled = None

    def add_muscle(self, name: str, cells, directions, fiber, excitation: float = 0.0) -> Muscle:
        """Add a fiber-activated region.

        Args:
            cells: input element indices of the region.
            directions: fiber directions, (3,) for all cells or (len(cells), 3) per
                element; normalized here; zero vectors are an error. Or a vector
                ``fem.Function`` on this body's mesh holding unit directions per
                quadrature point (a quadrature space of the energy's degree, see
                :meth:`quadrature_points`), used as is: full-order bodies only (a
                reduced body reads one direction per cell).
            fiber: fiber material with ``strain_energy(F, a0, excitation)``.
        """
        if name in self.muscles:
            raise InputError(f"FemBody {self.name!r}: muscle {name!r} already defined")
        _check_excitation(name, excitation)
        cells = np.asarray(cells, dtype=np.int64).ravel()
        n_cells_global = self.mesh.topology.index_map(self.mesh.topology.dim).size_global
        if cells.size == 0 or cells.min() < 0 or cells.max() >= n_cells_global:
            raise InputError(
                f"FemBody {self.name!r}: muscle {name!r}: cell indices must be a "
                f"non-empty subset of [0, {n_cells_global})"
            )
        if isinstance(directions, fem.Function):
            a0 = self._check_point_directions(name, directions)
            local_of_input = self._input_cell_to_local()
            local = np.array(
                [local_of_input[c] for c in cells.tolist() if c in local_of_input], dtype=np.int32
            )
            n_owned = self.mesh.topology.index_map(self.mesh.topology.dim).size_local
            muscle = Muscle(
                name,
                np.sort(local[local < n_owned]),
                a0,
                fiber,
                fem.Constant(self.mesh, PETSc.ScalarType(excitation)),
            )
            self.muscles[name] = muscle
            self._compiled = self._layers = None
            return muscle
        directions = np.broadcast_to(np.asarray(directions, dtype=float), (cells.size, 3))
        norms = np.linalg.norm(directions, axis=1)
        if np.any(~np.isfinite(norms)) or np.any(norms <= 0):
            bad = cells[~(norms > 0)]
            raise InputError(
                f"FemBody {self.name!r}: muscle {name!r}: zero or non-finite fiber "
                f"direction in elements {bad[:10].tolist()}"
            )
        unit = directions / norms[:, None]

        local_of_input = self._input_cell_to_local()
        pairs = [
            (local_of_input[c], k) for k, c in enumerate(cells.tolist()) if c in local_of_input
        ]
        local = np.array([p[0] for p in pairs], dtype=np.int32)
        rows = np.array([p[1] for p in pairs], dtype=np.int64)
        W = fem.functionspace(self.mesh, ("DG", 0, (3,)))
        a0 = fem.Function(W, name=f"fiber_{name}")
        if local.size:
            a0.x.array.reshape(-1, 3)[W.dofmap.list[local, 0]] = unit[rows]
        a0.x.scatter_forward()
        n_owned = self.mesh.topology.index_map(self.mesh.topology.dim).size_local
        owned = np.sort(local[local < n_owned])
        muscle = Muscle(
            name, owned, a0, fiber, fem.Constant(self.mesh, PETSc.ScalarType(excitation))
        )
        self.muscles[name] = muscle
        self._compiled = self._layers = None
        return muscle

    def quadrature_space(self) -> fem.FunctionSpace:
        """The vector quadrature space of the energy rule (degree ``quadrature_degree``)."""
        element = basix.ufl.quadrature_element(
            self.cell_name, value_shape=(3,), degree=self.quadrature_degree
        )
        return fem.functionspace(self.mesh, element)

    def quadrature_points(self) -> np.ndarray:
        """Reference positions of the energy's quadrature points of the local cells,
        shape (cells, points, 3), in the order of :meth:`quadrature_space`'s dofs."""
        pts, _ = basix.make_quadrature(
            getattr(basix.CellType, self.cell_name), self.quadrature_degree
        )
        tdim = self.mesh.topology.dim
        imap = self.mesh.topology.index_map(tdim)
        cells = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
        x = fem.Expression(ufl.SpatialCoordinate(self.mesh), pts).eval(self.mesh, cells)
        return x.reshape(cells.size, pts.shape[0], 3)

    def _check_point_directions(self, name: str, a0: fem.Function) -> fem.Function:
        what = f"FemBody {self.name!r}: muscle {name!r}"
        space = a0.function_space
        if space.mesh is not self.mesh or space.value_shape != (3,):
            raise InputError(
                f"{what}: a direction Function must be a 3-vector field on this body's mesh"
            )
        expected = self.quadrature_space()
        dg0 = fem.functionspace(self.mesh, ("DG", 0, (3,)))
        if space.ufl_element() not in (expected.ufl_element(), dg0.ufl_element()):
            raise InputError(
                f"{what}: the direction Function must be DG0 or on the quadrature "
                f"space of degree {self.quadrature_degree} "
                f"(FemBody.quadrature_space()), got {space.ufl_element()}"
            )
        norms = np.linalg.norm(a0.x.array.reshape(-1, 3), axis=1)
        if not np.all(np.isfinite(norms)) or np.any(np.abs(norms - 1.0) > 1e-8):
            raise InputError(
                f"{what}: fiber directions must be finite unit vectors "
                f"(|a0| in [{norms.min():.3g}, {norms.max():.3g}])"
            )
        return a0

    def set_load_factor(self, factor: float) -> None:
        """The static solve's load factor: lambda = lambda_a = ``factor`` (module docstring),
        the external loads and the activation ramped together, so that a cut load increment
        is a smaller activation too."""
        self.load_factor.value = factor
        self.activation_factor.value = factor

    def set_excitation(self, name: str, value: float) -> None:
        """Set a muscle's excitation in [0, 1] (no recompilation)."""
        if name not in self.muscles:
            raise UnknownNameError(
                f"FemBody {self.name!r}: unknown muscle {name!r}; defined: {sorted(self.muscles)}"
            )
        _check_excitation(name, value)
        self.muscles[name].excitation.value = value

    def _input_cell_to_local(self) -> dict[int, int]:
        tdim = self.mesh.topology.dim
        n_local = (
            self.mesh.topology.index_map(tdim).size_local
            + self.mesh.topology.index_map(tdim).num_ghosts
        )
        original = self.mesh.topology.original_cell_index[:n_local]
        return dict(zip(np.asarray(original).tolist(), range(n_local)))

    def input_cell_index(self, local_cells) -> np.ndarray:
        """Input (file) indices of local cells."""
        return np.asarray(self.mesh.topology.original_cell_index)[np.asarray(local_cells)]

    # ---- compiled forms ----------------------------------------------------

    def kinematics(self):
        """F = I + grad u as a UFL expression."""
        return ufl.Identity(3) + ufl.grad(self.u)

    def energy_terms(self, merged: bool = False) -> list[EnergyTerm]:
        """The internal energy as a sum of integrals, one per ingredient (see EnergyTerm):
        one per muscle, or (``merged``, the body's own forms) one per layer of muscles
        (:mod:`artifem.muscle_layers`: the same sum with far fewer kernels to compile)."""
        material = with_form_constants(self.material, self.mesh)
        terms = [
            EnergyTerm("material", lambda F, a0: material.strain_energy(F), self.quadrature_degree)
        ]
        if merged:
            for k, (density, cells, direction, fields_at) in enumerate(
                self._muscle_layers().terms()
            ):
                terms.append(
                    EnergyTerm(
                        f"muscle layer {k}",
                        density,
                        self.quadrature_degree,
                        cells,
                        direction,
                        fields_at,
                    )
                )
        for m in self.muscles.values() if not merged else ():
            fiber = with_form_constants(m.fiber, self.mesh)
            terms.append(
                EnergyTerm(
                    f"muscle:{m.name}",
                    lambda F, a0, m=m, f=fiber: f.strain_energy(
                        F, a0, self.activation_factor * m.excitation
                    ),
                    self.quadrature_degree,
                    m.cells,
                    m.direction,
                )
            )
        if self.incompressibility is not None:
            kappa = fem.Constant(self.mesh, PETSc.ScalarType(self.incompressibility))
            terms.append(
                EnergyTerm(
                    "incompressibility", lambda F, a0: 0.5 * kappa * (ufl.det(F) - 1) ** 2, 1
                )
            )
        return terms

    def _muscle_layers(self) -> MuscleLayers:
        if self._layers is None:
            self._layers = MuscleLayers(self)
        return self._layers

    def _density_factor(self):
        """rho in the forms: a run-time constant when it is a number (with_form_constants)."""
        if isinstance(self.density, (int, float)):
            return fem.Constant(self.mesh, PETSc.ScalarType(self.density))
        return self.density

    def term_energies(self) -> dict[str, ufl.Form]:
        """{name: int_{cells} density(F, a0) dX} of each of ``energy_terms(merged=True)``, with
        its own quadrature degree (the terms of Pi_int, one form each)."""
        F = self.kinematics()
        terms = self.energy_terms(merged=True)
        restricted = [t for t in terms if t.cells is not None]
        data = [(i + 1, t.cells) for i, t in enumerate(restricted)] or None
        energies = {}
        for t in terms:
            md = {"quadrature_degree": t.degree}
            if t.cells is None:
                energies[t.name] = t.density(F, None) * ufl.Measure(
                    "dx", domain=self.mesh, metadata=md
                )
            else:
                dx = ufl.Measure("dx", domain=self.mesh, metadata=md, subdomain_data=data)
                energies[t.name] = t.density(F, t.direction) * dx(restricted.index(t) + 1)
        return energies

    def potential_energy_form(self, closed_pressures: bool = True):
        """UFL integrand of Pi(u) (see the module docstring); ``closed_pressures=False``
        leaves out the closed pressures' potential (the residual takes their virtual
        work instead)."""
        Pi = sum(self.term_energies().values())
        external = self._density_factor() * ufl.dot(self.gravity, self.u)
        if self.body_force is not None:
            external += ufl.dot(self.body_force, self.u)
        dx = ufl.Measure(
            "dx", domain=self.mesh, metadata={"quadrature_degree": self.quadrature_degree}
        )
        Pi -= self.load_factor * external * dx
        dead, closed, _ = self._surface_terms()
        if dead is not None:
            Pi += dead
        if closed is not None and closed_pressures:
            Pi += closed
        return Pi

    def compile(self) -> None:
        """Compile residual, tangent, energy, mass and det F evaluation (once)."""
        if self._compiled is not None:
            return
        for load in self.surface_loads.values():
            if load.closed:
                check_closed(
                    self.mesh,
                    load,
                    self._geometry_node_dofs(),
                    self._fixed_mask,
                    self._fixed_values.x.array.reshape(-1, 3),
                )
        Pi = self.potential_energy_form(closed_pressures=False)
        v, du = ufl.TestFunction(self.V), ufl.TrialFunction(self.V)
        R = ufl.derivative(Pi, self.u, v)
        vc = self.volume_constraint
        _, closed, follower = self._surface_terms()
        if follower is not None:
            R -= follower  # R = dPi/du - delta W_follower
            if closed is not None:
                Pi += closed
        K = ufl.derivative(R, self.u, du)
        if vc is not None:  # -G^T pi and its geometric tangent, in the same integrals
            F, dx = self.kinematics(), vc.measure()
            R += ufl.derivative(vc.residual_term(F) * dx, self.u, v)
            K += ufl.derivative(ufl.derivative(vc.geometric_term(F) * dx, self.u, v), self.u, du)
        c = {}
        c["R"], c["K"], c["Pi"] = fem.form(R), fem.form(K), fem.form(Pi)
        zero = np.zeros(3, dtype=PETSc.ScalarType)
        if self._partly_fixed():  # one condition per component
            self.bcs = [
                fem.dirichletbc(
                    PETSc.ScalarType(0.0),
                    (3 * np.flatnonzero(self._fixed_mask[:, k]) + k).astype(np.int32),
                    self.V.sub(k),
                )
                for k in range(3)
            ]
        else:
            self.bcs = [fem.dirichletbc(zero, self._fixed_dofs, self.V)]
        self.K = fem_petsc.create_matrix(c["K"])
        self.R = fem_petsc.create_vector(self.V)
        if vc is not None:
            vc.compile()
            vc.assemble(tangent=True)  # room in K for G^T D G (nodal pressures: 2-ring)
            self.K.assemble()
            self.K.axpy(1.0, vc.GtDG, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
            self.K.zeroEntries()

        dxm = ufl.Measure(
            "dx", domain=self.mesh, metadata={"quadrature_degree": MASS_DEGREE[self.cell_name]}
        )
        rho = self._density_factor()
        mass_form = rho * ufl.inner(du, v) * dxm
        # Lumped mass: row sums of the consistent mass, M_ii = int rho phi_i dX.
        ones = fem.Constant(self.mesh, np.ones(3, dtype=PETSc.ScalarType))
        self.M_lumped = fem_petsc.assemble_vector(fem.form(rho * ufl.dot(ones, v) * dxm))
        self.M_lumped.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.M_consistent = None
        self._scaled_mass = None  # work vector of add_mass
        if self.mass_kind == "consistent":
            self.M_consistent = fem_petsc.assemble_matrix(
                fem.form(mass_form), bcs=self.bcs, diag=1.0
            )
            self.M_consistent.assemble()
            c["mass_form"] = mass_form

        pts, _ = basix.make_quadrature(
            getattr(basix.CellType, self.cell_name), self.quadrature_degree
        )
        c["detF"] = fem.Expression(ufl.det(self.kinematics()), pts)
        tdim = self.mesh.topology.dim
        self._owned_cells = np.arange(self.mesh.topology.index_map(tdim).size_local, dtype=np.int32)
        self._compiled = c

    # ---- evaluation --------------------------------------------------------

    def assemble(self, tangent: bool = True, diag: float = 0.0, linearized: bool = False) -> None:
        """Assemble R = dPi/du (into self.R, nodal loads included) and K (into self.K).

        The force on the body is f = -R. Fixed rows/columns of K are zeroed with
        ``diag`` on the diagonal (0 when a mass term is added, 1 for statics).
        ``linearized`` (a semi-implicit step) takes the hard incompressibility's
        geometric tangent with its multipliers p rather than the current pressures
        (:meth:`artifem.incompressibility.VolumeConstraint.assemble`); K is then not
        exactly dR/du where the constraint has drifted.
        """
        self.compile()
        c = self._compiled
        self._muscle_layers().refresh()
        vc = self.volume_constraint
        if vc is not None:
            vc.assemble(tangent, linearized)
        if tangent:
            self.K.zeroEntries()
            fem_petsc.assemble_matrix(self.K, c["K"], bcs=self.bcs, diag=diag)
            self.K.assemble()
            if vc is not None:  # + G^T D G
                self.K.axpy(1.0, vc.GtDG, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        with self.R.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(self.R, c["R"])
        self.R.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.R.axpy(-self.load_factor.value, self.nodal_load)

    def rest_stiffness(self) -> PETSc.Mat:
        """K_0 = d^2/du^2 of the material energy (the matrix material and the element
        penalty, no muscle, load or hard constraint) at u = 0: the stiffness of the
        Rayleigh damping D = alpha M + beta K_0 (module docstring). Fixed rows and columns
        are zero. It is assembled once with the forms; its sparsity is a subset of K's."""
        self.compile()
        c = self._compiled
        if "K_rest" not in c:
            rest = fem.Function(self.V)  # u = 0
            F = ufl.Identity(3) + ufl.grad(rest)
            energy = sum(
                t.density(F, None)
                * ufl.Measure("dx", domain=self.mesh, metadata={"quadrature_degree": t.degree})
                for t in self.energy_terms()
                if t.cells is None
            )
            v, du = ufl.TestFunction(self.V), ufl.TrialFunction(self.V)
            form = fem.form(ufl.derivative(ufl.derivative(energy, rest, v), rest, du))
            c["K_rest"] = fem_petsc.assemble_matrix(form, bcs=self.bcs, diag=0.0)
            c["K_rest"].assemble()
        return c["K_rest"]

    def damping_mult(self, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """y = D x = (alpha M + beta K_0) x."""
        self.mass_mult(x, y)
        y.scale(self.alpha)
        if self.beta:
            tmp = y.duplicate()
            self.rest_stiffness().mult(x, tmp)
            y.axpy(self.beta, tmp)
            tmp.destroy()

    def add_damping(self, A: PETSc.Mat, scale: float) -> None:
        """A += scale * D (A's sparsity holds K's)."""
        self.add_mass(A, scale * self.alpha)
        if self.beta:
            A.axpy(
                scale * self.beta,
                self.rest_stiffness(),
                structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN,
            )

    def zero_fixed(self, vec: PETSc.Vec) -> None:
        """Zero the owned entries of fixed dofs in a blocked vector."""
        n_owned = self.V.dofmap.index_map.size_local
        if self._partly_fixed():
            fixed = self.fixed_components
            vec.array[fixed[fixed < 3 * n_owned]] = 0.0
            return
        fixed = self._fixed_dofs[self._fixed_dofs < n_owned]
        arr = vec.array.reshape(-1, 3)
        arr[fixed] = 0.0

    def mass_mult(self, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """y = M x."""
        if self.M_consistent is not None:
            self.M_consistent.mult(x, y)
        else:
            y.pointwiseMult(self.M_lumped, x)

    def add_mass(self, A: PETSc.Mat, scale: float) -> None:
        """A += scale * M."""
        if self.M_consistent is not None:
            A.axpy(scale, self.M_consistent, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        else:
            if self._scaled_mass is None:
                self._scaled_mass = self.M_lumped.duplicate()
            self.M_lumped.copy(self._scaled_mass)
            self._scaled_mass.scale(scale)
            A.setDiagonal(self._scaled_mass, addv=PETSc.InsertMode.ADD_VALUES)

    def det_F(self) -> np.ndarray:
        """det F at the energy quadrature points of owned cells, shape (cells, points)."""
        self.compile()
        return self._compiled["detF"].eval(self.mesh, self._owned_cells)

    def constraint_failure(self) -> str | None:
        """After a step (the body interface; collective): None, or which of the body's own
        constraints the step left off by more than it may (the hard incompressibility's
        ``step_tol``: :meth:`~artifem.incompressibility.VolumeConstraint.step_failure`)."""
        vc = self.volume_constraint
        return None if vc is None else vc.step_failure()

    def inverted_elements(self) -> tuple[np.ndarray, float]:
        """(input indices of elements with det F <= 0 anywhere, global min det F)."""
        detF = self.det_F()
        local_min = detF.min(axis=1) if detF.size else np.zeros(0)
        bad = self.input_cell_index(self._owned_cells[local_min <= 0]) if detF.size else []
        comm = self.mesh.comm
        gmin = comm.allreduce(float(local_min.min()) if local_min.size else np.inf, op=MPI.MIN)
        all_bad = np.sort(
            np.concatenate([np.asarray(b, dtype=np.int64) for b in comm.allgather(np.asarray(bad))])
        )
        return all_bad, gmin

    def potential_energy(self) -> float:
        """Pi(u) (strain and fiber energy minus the work of the loads). An open follower
        pressure has no potential and is left out (``conservative`` is False); a closed
        one enters as -lambda p V (:mod:`artifem.surface_loads`)."""
        self.compile()
        self._muscle_layers().refresh()
        local = fem.assemble_scalar(self._compiled["Pi"])
        Pi = self.mesh.comm.allreduce(local)
        if self.volume_constraint is not None:
            self.volume_constraint.assemble(tangent=False)
            Pi += self.volume_constraint.energy()
        with self.nodal_load.localForm() as f, self.u.x.petsc_vec.localForm() as u:
            n = self.V.dofmap.index_map.size_local * 3
            work = float(np.dot(f.array[:n], u.array[:n]))
        return Pi - self.load_factor.value * self.mesh.comm.allreduce(work)

    def volume(self) -> float:
        """The current volume int J dX (the energy's quadrature: exact for Q1 hexahedra)."""
        self.compile()
        if "volume" not in self._compiled:
            dx = ufl.Measure(
                "dx", domain=self.mesh, metadata={"quadrature_degree": self.quadrature_degree}
            )
            self._compiled["volume"] = fem.form(ufl.det(self.kinematics()) * dx)
        return self.mesh.comm.allreduce(fem.assemble_scalar(self._compiled["volume"]))

    def kinetic_energy(self) -> float:
        """T = 1/2 v^T M v."""
        self.compile()
        Mv = self.v.x.petsc_vec.duplicate()
        self.mass_mult(self.v.x.petsc_vec, Mv)
        T = 0.5 * Mv.dot(self.v.x.petsc_vec)
        Mv.destroy()
        return T

    def total_mass(self) -> float:
        self.compile()
        return self.M_lumped.sum() / 3.0

    # ---- state -------------------------------------------------------------

    def state(self) -> tuple[np.ndarray, ...]:
        """A copy of (u, v) local arrays (owned and ghost), and the multipliers p of the
        hard incompressibility when there is one."""
        if self.volume_constraint is not None:
            return (
                self.u.x.array.copy(),
                self.v.x.array.copy(),
                self.volume_constraint.p.x.array.copy(),
            )
        return self.u.x.array.copy(), self.v.x.array.copy()

    def set_state(self, state) -> None:
        self.u.x.array[:] = state[0]
        self.v.x.array[:] = state[1]
        if self.volume_constraint is not None:
            self.volume_constraint.p.x.array[:] = state[2]

    def output_fields(self) -> dict[str, list[fem.Function]]:
        """The fields a result series writes, by file suffix (one element type per file):
        the displacement and, with the hard incompressibility, the pressures p."""
        fields = {"": [self.u]}
        if self.volume_constraint is not None:
            fields["_pressure"] = [self.volume_constraint.p]
        return fields

    def nodal_positions(self) -> np.ndarray:
        """Current positions X + u of the local geometry nodes, shape (nodes, 3)."""
        x = self.mesh.geometry.x.copy()
        x_dofmap = self.mesh.geometry.dofmaps[0].reshape(-1)
        dofs = self.V.dofmap.list.reshape(-1)
        x[x_dofmap] += self.u.x.array.reshape(-1, 3)[dofs]
        return x

    def displacement_at(self, nodes) -> np.ndarray:
        """Displacements of input nodes (gathered on every rank), shape (len(nodes), 3)."""
        nodes = self._check_nodes(nodes, "displacement_at")
        n_owned = self.V.dofmap.index_map.size_local
        out = np.zeros((nodes.size, 3))
        arr = self.u.x.array.reshape(-1, 3)
        for k, n in enumerate(nodes.tolist()):
            d = self._node_to_dof.get(n)
            if d is not None and d < n_owned:
                out[k] = arr[d]
        return self.mesh.comm.allreduce(out)


def with_form_constants(material, domain: dmesh.Mesh):
    """A copy of ``material`` whose ``form_constants`` fields are run-time ``fem.Constant`` objects.

    The material declares which parameters enter its energy only as factors
    (``MooneyRivlin.form_constants``); passed as run-time constants they leave the
    generated kernels independent of their values, so a model with another
    stiffness reuses the JIT cache instead of compiling again (a new tongue kappa
    cost about 35 s of compilation, a reduced tongue one kernel per muscle's
    max_stress). Zero values stay literal zeros, which UFL folds away (a
    Mooney-Rivlin with C01 = 0 never evaluates I2bar). Parts of a combined
    material are converted too; anything else is returned unchanged.
    """
    out = copy.copy(material)
    for name in getattr(material, "form_constants", ()):
        value = getattr(material, name)
        if value != 0.0:
            object.__setattr__(out, name, fem.Constant(domain, PETSc.ScalarType(value)))
    parts = getattr(material, "parts", None)
    if isinstance(parts, tuple):
        object.__setattr__(out, "parts", tuple(with_form_constants(p, domain) for p in parts))
    return out


def _check_excitation(name: str, value: float) -> None:
    if not (0.0 <= value <= 1.0):  # also rejects NaN
        raise InputError(f"excitation of {name!r} must be in [0, 1], got {value}")
