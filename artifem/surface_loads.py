"""Surface loads on FEM bodies: a follower pressure and a dead traction on boundary facets.

Both act on facets of the body's boundary chosen by a predicate on the
reference coordinates, by facet tags, or by a surface mesh, and both are
scaled by the body's load factor lambda (ramped by static load steps). With
F = I + grad u, N the outward unit normal and dA the area of the *reference*
face:

- **follower pressure** p (Pa, positive pushes into the body): it acts on the
  deformed face, t da = -p n da = -p J F^-T N dA (Nanson), so its virtual work
  and its contribution to the residual R = dPi/du are

      delta W = -lambda int p J F^-T N . delta u dA,    R += lambda int p cof(F) N . v dA,

  and its tangent dR/du comes from ``ufl.derivative`` (unsymmetric in general).
  A follower pressure has no potential in general, so it is *not* part of the
  body's ``potential_energy()`` and the body is not ``conservative``; the line
  searches of the static and implicit solvers then rely on their residual test,
  which crawls on nearly incompressible bodies (the residual of a good Newton
  step jumps with the volume penalty; measured on the inflated sphere: 30
  iterations without converging one load step of three).
- **closed pressure** (``closed=True``): the loaded faces bound a volume, i.e.
  the surface is closed, or each edge of it is fixed, or lies in a symmetry
  plane x_k = c_k through ``center`` c with u_k fixed to 0 there (checked when
  the body compiles). Then the pressure is conservative, with potential

      Pi_p = -lambda p V,   V = -1/3 int (x - c) . cof(F) N dA   (x = X + u),

  the enclosed volume (the cone from c over the faces; N points out of the body,
  so into the cavity). Its derivative along every admissible variation is the
  follower's virtual work above (the edge term 1/3 oint ((x - c) x delta x) . dl
  vanishes on fixed edges and on the planes), and both integrals are exact with
  the default quadrature (degree (2, 2) on bilinear faces, 1 on flat ones), so
  ``potential_energy()`` includes Pi_p, the body stays ``conservative`` and the
  energy test of the line searches applies (7 Newton iterations per load step
  on the sphere). The residual is still the follower's virtual work itself.
- **dead traction** t (Pa per reference area, fixed direction): potential
  -lambda int t . u dA, part of the body's potential energy.

The value is a ``fem.Constant`` set between steps with :meth:`SurfaceLoad.set`
(no recompilation), e.g. by a scene controller
``scene.add_controller(lambda scene, t0, t1: load.set(p(t1)))``.

Facet selection (:func:`select_facets`), exactly one of:

- ``where``: a predicate on coordinates x of shape (3, n), true at every vertex
  of a selected boundary facet (like ``dolfinx.mesh.locate_entities_boundary``);
- ``tags`` (a ``dolfinx.mesh.MeshTags`` on facets of the body's mesh) and
  ``values`` (the tag values to load): every tagged facet must be on the boundary;
- ``surface``: (vertices, faces) of a triangle or quad surface mesh: its
  vertices must be nodes of the body (within ``tol``), each face must lie on one
  boundary facet and the faces on a facet must cover all of its vertices (a quad
  facet is loaded by itself or by the two triangles that split it).

Errors name the offending faces, facets (by midpoint) or values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc
from scipy import sparse
from scipy.spatial import cKDTree

from dolfinx import fem, mesh as dmesh
from dolfinx.fem import petsc as fem_petsc

import artifem.jit  # noqa: F401  (waits for another process's compile of a form)
from artifem.errors import InputError

__all__ = ["SurfaceLoad", "SurfacePatch", "select_facets", "surface_measure", "FACET_DEGREE"]

#: Default quadrature degree of the facet integrals per cell type: 2 x 2 Gauss on the
#: bilinear faces of Q1 hexahedra and prisms; on a P1 tetrahedron cof(F) and N are
#: constant per face, so the integrand is linear and one point is exact.
FACET_DEGREE = {"hexahedron": 2, "tetrahedron": 1, "prism": 2}

KINDS = ("pressure", "traction")


@dataclass(eq=False)
class SurfaceLoad:
    """A pressure or traction on boundary facets of one FEM body (module docstring).

    Made by ``FemBody.add_pressure`` / ``FemBody.add_traction``.

    Attributes:
        name: the load's name in ``body.surface_loads``.
        kind: ``"pressure"`` (follower, scalar) or ``"traction"`` (dead, 3-vector).
        facets: local facet indices (sorted, unique; exterior facets of the body).
        value: the ``fem.Constant`` holding p or t (multiplied by the body's load factor).
        degree: quadrature degree of the facet integral.
        owner: the body's name (for messages).
    """

    name: str
    kind: str
    facets: np.ndarray
    value: fem.Constant
    degree: int
    owner: str = ""
    closed: bool = False
    center: fem.Constant | None = None

    @property
    def follower(self) -> bool:
        """True for a load that follows the deformed surface."""
        return self.kind == "pressure"

    @property
    def conservative(self) -> bool:
        """True when the load has a potential (a dead traction, a closed pressure)."""
        return self.kind == "traction" or self.closed

    def set(self, value) -> None:
        """Set p (a number) or t (3 numbers), effective from the next assembly."""
        self.value.value = _checked_value(self.kind, value, f"{self.owner!r}: {self.name!r}")

    def get(self):
        """The current p (float) or t (array of 3), before the load factor."""
        v = np.array(self.value.value, dtype=float)
        return float(v) if self.kind == "pressure" else v

    def virtual_work(self, u, v, load_factor, ds):
        """UFL form delta W(u; v) of the external virtual work (module docstring)."""
        if self.kind == "pressure":
            F = ufl.Identity(3) + ufl.grad(u)
            N = ufl.FacetNormal(u.function_space.mesh)
            return -load_factor * self.value * ufl.dot(ufl.cofac(F) * N, v) * ds
        return load_factor * ufl.dot(self.value, v) * ds

    def potential(self, u, load_factor, ds):
        """UFL form of the load's potential (module docstring), None for an open pressure."""
        if self.kind == "traction":
            return -load_factor * ufl.dot(self.value, u) * ds
        if not self.closed:
            return None
        F = ufl.Identity(3) + ufl.grad(u)
        domain = u.function_space.mesh
        N = ufl.FacetNormal(domain)
        x = ufl.SpatialCoordinate(domain) + u - self.center
        return load_factor * self.value / 3.0 * ufl.dot(x, ufl.cofac(F) * N) * ds


def _checked_value(kind: str, value, what: str):
    shape = () if kind == "pressure" else (3,)
    arr = np.asarray(value, dtype=float) if _is_numeric(value) else None
    if arr is None or arr.shape != shape or not np.all(np.isfinite(arr)):
        expected = "a finite number" if kind == "pressure" else "3 finite numbers"
        raise InputError(f"surface load {what}: {kind} must be {expected}, got {value!r}")
    return arr


def _is_numeric(value) -> bool:
    try:
        np.asarray(value, dtype=float)
        return True
    except (TypeError, ValueError):
        return False


def make_load(
    domain: dmesh.Mesh,
    kind: str,
    name: str,
    facets: np.ndarray,
    value,
    degree: int | None,
    owner: str,
    closed: bool = False,
    center=(0.0, 0.0, 0.0),
) -> SurfaceLoad:
    """A SurfaceLoad on ``domain`` (checks the value, the quadrature degree and the center)."""
    if kind not in KINDS:
        raise InputError(
            f"FemBody {owner!r}: surface load kind must be one of {KINDS}, got {kind!r}"
        )
    arr = _checked_value(kind, value, f"{owner!r}: {name!r}")
    if degree is None:
        degree = FACET_DEGREE[domain.topology.cell_name()]
    if int(degree) != degree or degree < 0:
        raise InputError(
            f"FemBody {owner!r}: surface load {name!r}: quadrature degree must be "
            f"an integer >= 0, got {degree!r}"
        )
    const = fem.Constant(domain, np.asarray(arr, dtype=PETSc.ScalarType))
    c = None
    if closed:
        c = np.asarray(center, dtype=float) if _is_numeric(center) else None
        if c is None or c.shape != (3,) or not np.all(np.isfinite(c)):
            raise InputError(
                f"FemBody {owner!r}: surface load {name!r}: center must be 3 "
                f"finite numbers, got {center!r}"
            )
        c = fem.Constant(domain, c.astype(PETSc.ScalarType))
    return SurfaceLoad(name, kind, facets, const, int(degree), owner, bool(closed), c)


def check_closed(
    domain: dmesh.Mesh,
    load: SurfaceLoad,
    node_dofs: np.ndarray,
    fixed_mask: np.ndarray,
    fixed_values: np.ndarray,
) -> None:
    """InputError unless every edge of the surface of a closed pressure is fixed or lies in
    a symmetry plane x_k = c_k through its center with u_k fixed to 0 (module docstring).

    ``node_dofs`` maps geometry nodes to block dofs; ``fixed_mask`` (blocks, 3) and
    ``fixed_values`` (blocks, 3) are the body's fixed components and their values.
    An edge is on the surface's border when one loaded facet holds it.
    """
    fdim = domain.topology.dim - 1
    nodes = dmesh.entities_to_geometry(domain, fdim, load.facets.astype(np.int32))
    pairs = ((0, 1), (1, 2), (2, 0)) if nodes.shape[1] == 3 else ((0, 1), (0, 2), (1, 3), (2, 3))
    inputs = np.asarray(domain.geometry.input_global_indices, dtype=np.int64)
    owned = np.isin(load.facets, dmesh.exterior_facet_indices(domain.topology))
    edges = np.concatenate([np.sort(nodes[:, list(p)], axis=1) for p in pairs])
    edges = edges[np.tile(owned, len(pairs))].reshape(-1, 2)  # each exterior facet once
    keys = np.sort(inputs[edges], axis=1).reshape(-1, 2)
    unique, counts = np.unique(
        np.concatenate(domain.comm.allgather(keys)), axis=0, return_counts=True
    )
    border = {tuple(k) for k in unique[counts == 1].tolist()}
    c = np.asarray(load.center.value, dtype=float)
    x = domain.geometry.x
    scale = float(np.ptp(x, axis=0).max()) if x.size else 1.0
    tol = 1e-8 * domain.comm.allreduce(scale, op=MPI.MAX)

    def planes(g: int) -> set:
        d = node_dofs[g]
        fixed = fixed_mask[d] & (np.abs(fixed_values[d]) == 0.0)
        if fixed_mask[d].all():
            return {"fixed"} | {k for k in range(3) if fixed[k] and abs(x[g, k] - c[k]) <= tol}
        return {k for k in range(3) if fixed[k] and abs(x[g, k] - c[k]) <= tol}

    bad = []
    for a, b in edges.tolist():
        key = tuple(sorted((int(inputs[a]), int(inputs[b]))))
        if key not in border:
            continue
        pa, pb = planes(a), planes(b)
        if not (("fixed" in pa and "fixed" in pb) or (pa & pb) - {"fixed"}):
            bad.append(0.5 * (x[a] + x[b]))
    bad = [p for rank in domain.comm.allgather(bad) for p in rank]
    if bad:
        raise InputError(
            f"FemBody {load.owner!r}: surface load {load.name!r} is declared closed, but "
            f"{len(bad)} edge(s) of its border are neither fixed nor in a symmetry plane "
            f"x_k = c_k through its center c = {c.tolist()} with u_k fixed to 0, e.g. the edge "
            f"at {np.round(bad[0], 6).tolist()}: fix them, or drop closed=True (then the "
            f"pressure has no potential)"
        )


# ---- facet selection ---------------------------------------------------------------------


def select_facets(
    domain: dmesh.Mesh,
    *,
    where=None,
    tags=None,
    values=None,
    surface=None,
    tol: float | None = None,
    what: str = "surface load",
) -> np.ndarray:
    """Local indices of the boundary facets chosen by exactly one of ``where``, ``tags``
    (with ``values``) or ``surface`` (module docstring); sorted and unique.

    An empty selection (on every rank) is an error: a load on nothing is a typo.
    """
    given = [
        k for k, v in (("where", where), ("tags", tags), ("surface", surface)) if v is not None
    ]
    if len(given) != 1:
        raise InputError(
            f"{what}: choose the facets by exactly one of where=, tags= or "
            f"surface=, got {given or 'none'}"
        )
    if values is not None and tags is None:
        raise InputError(f"{what}: values= selects tag values and needs tags=")
    fdim = domain.topology.dim - 1
    domain.topology.create_connectivity(fdim, domain.topology.dim)
    exterior = dmesh.exterior_facet_indices(domain.topology)
    if where is not None:
        if not callable(where):
            raise InputError(
                f"{what}: where= must be a callable x -> bool array, x of shape "
                f"(3, n), got {type(where).__name__}"
            )
        facets = dmesh.locate_entities_boundary(domain, fdim, where)
        how = (
            "where= selects no boundary facet (the predicate must hold at every vertex of a facet)"
        )
    elif tags is not None:
        facets = _tagged_facets(domain, tags, values, exterior, what)
        how = f"no facet carries the tag values {values!r}"
    else:
        facets = _surface_facets(domain, surface, exterior, tol, what)
        how = "the surface mesh has no face"
    facets = np.unique(np.asarray(facets, dtype=np.int32))
    if domain.comm.allreduce(int(facets.size), op=MPI.SUM) == 0:
        raise InputError(f"{what}: {how}")
    return facets


def _tagged_facets(domain, tags, values, exterior, what) -> np.ndarray:
    if not isinstance(tags, dmesh.MeshTags):
        raise InputError(
            f"{what}: tags= must be a dolfinx.mesh.MeshTags, got {type(tags).__name__}"
        )
    fdim = domain.topology.dim - 1
    if tags.dim != fdim:
        raise InputError(
            f"{what}: tags= must tag facets (dimension {fdim}), got dimension {tags.dim}"
        )
    if (
        tags.topology is not domain.topology
        and tags.topology.index_map(fdim).size_local != domain.topology.index_map(fdim).size_local
    ):
        raise InputError(f"{what}: tags= belong to another mesh")
    if values is None:
        raise InputError(f"{what}: tags= needs values= (the tag values to load)")
    wanted = np.atleast_1d(np.asarray(values)).ravel()
    present = np.unique(np.concatenate(domain.comm.allgather(np.asarray(tags.values))))
    missing = np.setdiff1d(wanted, present)
    if missing.size:
        raise InputError(
            f"{what}: no facet carries the tag value(s) {missing.tolist()}; "
            f"the tags hold {present.tolist()}"
        )
    facets = np.asarray(tags.indices)[np.isin(tags.values, wanted)]
    interior = np.setdiff1d(facets, exterior)
    if domain.comm.allreduce(int(interior.size), op=MPI.SUM):
        mid = dmesh.compute_midpoints(domain, fdim, interior.astype(np.int32))
        raise InputError(
            f"{what}: {interior.size} tagged facet(s) are not on the boundary "
            f"(a surface load acts on boundary facets only), e.g. facet "
            f"{int(interior[0])} at {np.round(mid[0], 6).tolist()}"
        )
    return facets


def _surface_facets(domain, surface, exterior, tol, what) -> np.ndarray:
    """Boundary facets covered by the faces of a surface mesh (module docstring)."""
    try:
        vertices, faces = surface
        vertices = np.asarray(vertices, dtype=float)
        faces = np.asarray(faces)
    except (TypeError, ValueError):
        raise InputError(
            f"{what}: surface= must be (vertices, faces), vertices of shape "
            "(n, 3) and faces of shape (m, 3) or (m, 4)"
        ) from None
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.all(np.isfinite(vertices)):
        raise InputError(
            f"{what}: surface vertices must be finite, of shape (n, 3), got shape {vertices.shape}"
        )
    if (
        faces.ndim != 2
        or faces.shape[1] not in (3, 4)
        or faces.shape[0] == 0
        or not np.issubdtype(faces.dtype, np.integer)
    ):
        raise InputError(
            f"{what}: surface faces must be integers of shape (m, 3) or (m, 4), "
            f"got {faces.dtype} of shape {faces.shape}"
        )
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"{what}: surface faces index vertices out of range [0, {len(vertices)})")
    fdim = domain.topology.dim - 1
    x = domain.geometry.x
    if tol is None:
        extent = np.ptp(x, axis=0).max() if x.size else 1.0
        tol = 1e-8 * domain.comm.allreduce(float(extent), op=MPI.MAX)
    facet_nodes = dmesh.entities_to_geometry(domain, fdim, exterior.astype(np.int32))
    # geometry node -> exterior facets that hold it
    holders: dict[int, set[int]] = {}
    for k, nodes in enumerate(facet_nodes.tolist()):
        for n in nodes:
            holders.setdefault(n, set()).add(k)
    distance, node = (
        cKDTree(x).query(vertices)
        if len(x)
        else (np.full(len(vertices), np.inf), np.zeros(len(vertices), int))
    )
    on_node = distance <= tol
    covered: dict[int, set[int]] = {}
    matched = np.zeros(len(faces), dtype=bool)
    for i, face in enumerate(faces.tolist()):
        if not on_node[face].all():
            continue
        nodes = [int(node[j]) for j in face]
        candidates = set.intersection(*(holders.get(n, set()) for n in nodes))
        if len(candidates) == 1:
            k = candidates.pop()
            matched[i] = True
            covered.setdefault(k, set()).update(nodes)
    matched = np.asarray(domain.comm.allreduce(matched.astype(np.int64), op=MPI.SUM)) > 0
    if not matched.all():
        bad = np.flatnonzero(~matched)
        raise InputError(
            f"{what}: {bad.size} of {len(faces)} surface face(s) match no boundary "
            f"facet of the body (vertices within {tol:.3g} of its nodes, all on "
            f"one facet): faces {bad[:20].tolist()}" + (" ..." if bad.size > 20 else "")
        )
    partial = [k for k, nodes in covered.items() if not set(facet_nodes[k].tolist()) <= nodes]
    if partial:
        mid = dmesh.compute_midpoints(domain, fdim, exterior[partial].astype(np.int32))
        raise InputError(
            f"{what}: the surface covers {len(partial)} boundary facet(s) only in "
            f"part (its faces on a facet must reach all of the facet's vertices), "
            f"e.g. the facet at {np.round(mid[0], 6).tolist()}"
        )
    return exterior[sorted(covered)]


# ---- the facet measure of a body's loads --------------------------------------------------


def surface_measure(domain: dmesh.Mesh, loads) -> tuple[ufl.Measure, list[tuple[int, ...]]]:
    """One ``ds`` measure for all ``loads`` and each load's subdomain ids.

    A form takes one set of facet tags per integral type, and facets may carry
    several loads: each distinct set of loads on a facet gets one tag (numbered
    the same on every rank), and a load integrates over the tags whose sets
    contain it.
    """
    fdim = domain.topology.dim - 1
    owners: dict[int, list[int]] = {}
    for i, load in enumerate(loads):
        for f in load.facets.tolist():
            owners.setdefault(f, []).append(i)
    keys = sorted(set().union(*domain.comm.allgather({tuple(k) for k in owners.values()})))
    tag_of = {key: t + 1 for t, key in enumerate(keys)}
    facet_ids = np.asarray(sorted(owners), dtype=np.int32)
    values = np.asarray([tag_of[tuple(owners[f])] for f in facet_ids.tolist()], dtype=np.int32)
    tags = dmesh.meshtags(domain, fdim, facet_ids, values)
    ids = [tuple(tag_of[key] for key in keys if i in key) for i in range(len(loads))]
    return ufl.Measure("ds", domain=domain, subdomain_data=tags), ids


# ---- the loads on the cells next to their facets (reduced bodies) --------------------------


class SurfacePatch:
    """Surface loads of a body evaluated on the cells next to their facets only.

    A submesh of those cells carries a copy of each load (its facets and
    values), so the residual R_s, tangent K_s and potential Pi_s of the loads
    cost O(cells next to the loaded facets), never O(mesh): what a reduced body
    needs, with u = u_bar + U q rebuilt on the patch's dofs only. The loads'
    values and the load factor are copied from the body's constants at every
    evaluation (a controller's ``load.set`` acts here too). Serial.

    Attributes:
        dofs: the body's local scalar dofs (3 * block + component) of the patch's
            dofs, in the patch's order.
    """

    def __init__(self, V: fem.FunctionSpace, loads, load_factor: fem.Constant):
        domain = V.mesh
        tdim = domain.topology.dim
        fdim = tdim - 1
        domain.topology.create_connectivity(fdim, tdim)
        f2c = domain.topology.connectivity(fdim, tdim)
        facets = np.unique(np.concatenate([load.facets for load in loads]))
        cells = np.unique(np.concatenate([f2c.links(f) for f in facets.tolist()])).astype(np.int32)
        sub, cell_map, vertex_map, _ = dmesh.create_submesh(domain, tdim, cells)
        self.mesh = sub
        self.V = fem.functionspace(sub, ("Lagrange", 1, (3,)))
        n_sub = sub.topology.index_map(tdim).size_local + sub.topology.index_map(tdim).num_ghosts
        parent = cell_map.sub_topology_to_topology(np.arange(n_sub, dtype=np.int32), False)
        blocks = np.empty(
            self.V.dofmap.index_map.size_local + self.V.dofmap.index_map.num_ghosts, dtype=np.int64
        )
        blocks[self.V.dofmap.list.reshape(-1)] = V.dofmap.list[parent].reshape(-1)
        self.dofs = (3 * blocks[:, None] + np.arange(3)).ravel()
        self.loads = list(loads)
        self._load_factor = load_factor
        self._lf = fem.Constant(sub, PETSc.ScalarType(0.0))
        sub.topology.create_connectivity(fdim, tdim)
        copies = []
        for load in self.loads:
            tags = dmesh.meshtags(domain, fdim, load.facets, np.ones_like(load.facets))
            moved = dmesh.transfer_meshtags_to_submesh(tags, sub, vertex_map, cell_map)
            center = load.center.value if load.center is not None else (0.0, 0.0, 0.0)
            copies.append(
                make_load(
                    sub,
                    load.kind,
                    load.name,
                    np.sort(moved.indices[moved.values == 1]),
                    load.get(),
                    load.degree,
                    load.owner,
                    load.closed,
                    center,
                )
            )
        self._copies = copies
        self.u = fem.Function(self.V)
        ds, ids = surface_measure(sub, copies)
        v, du = ufl.TestFunction(self.V), ufl.TrialFunction(self.V)
        R, Pi = 0, None
        for load, sub_ids in zip(copies, ids):
            measure = ds(sub_ids, metadata={"quadrature_degree": load.degree})
            R -= load.virtual_work(self.u, v, self._lf, measure)
            term = load.potential(self.u, self._lf, measure)
            if term is not None:
                Pi = term if Pi is None else Pi + term
        self._R = fem.form(R)
        self._K = fem.form(ufl.derivative(R, self.u, du))
        self._Pi = fem.form(Pi) if Pi is not None else None
        self._vec = fem_petsc.create_vector(self.V)
        self._mat = fem_petsc.create_matrix(self._K)

    def _set(self, u: np.ndarray) -> None:
        """u: the body's displacement at :attr:`dofs`; values and load factor synced."""
        self.u.x.array[:] = u
        self._lf.value = self._load_factor.value
        for load, copy in zip(self.loads, self._copies):
            copy.value.value = load.value.value

    def residual(self, u: np.ndarray) -> np.ndarray:
        """R_s = -(virtual work of the loads) at the patch's dofs."""
        self._set(u)
        with self._vec.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(self._vec, self._R)
        self._vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return self._vec.array.copy()

    def tangent(self, u: np.ndarray):
        """K_s = dR_s/du (scipy CSR, unsymmetric for open pressures)."""
        self._set(u)
        self._mat.zeroEntries()
        fem_petsc.assemble_matrix(self._mat, self._K)
        self._mat.assemble()
        ai, aj, av = self._mat.getValuesCSR()
        return sparse.csr_matrix((av, aj, ai), shape=self._mat.getSize())

    def potential(self, u: np.ndarray) -> float:
        """The loads' potential (dead tractions, closed pressures; 0 without)."""
        if self._Pi is None:
            return 0.0
        self._set(u)
        return float(fem.assemble_scalar(self._Pi))
