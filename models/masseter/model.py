"""A synthetic masseter: fascicles, aponeuroses and a rigid jaw, on an embedding (voxel) FEM
and on a conforming tet FEM (Lloyd et al. 2019, section 4.2, Figs. 14-15).

The geometry is SYNTHETIC. There is no public masseter data (the paper's fascicles and
aponeuroses were digitized from a dissection, Sanchez et al. 2017), so the muscle, its
fascicles and its aponeuroses are made up here, at roughly the size of a human superficial
masseter, to exercise the techniques of section 4.2, not to reproduce a subject.

Geometry (metres; z up from the mandible's angle to the zygomatic arch, x anterior, y lateral)
-------------------------------------------------------------------------------------------
A block B = [0, W_b] x [0, T] x [0, H] (reference coordinates X, Y, Z) is meshed by gmsh
and bent by the smooth map phi(X, Y, Z) = (x, y, z), with s = X/W_b - 1/2, t = Y/T - 1/2,
r = Z/H in [0, 1]:

    x = s W(r) + lean r + curve sin(pi r),        W(r) = W_b + (W_t - W_b) r   (taper)
    y = t T (1 + bulge sin(pi r)) + bow sin(pi r)                               (belly, bow)
    z = Z

(H = 50 mm, W_b = 25 mm, W_t = 20 mm, T = 10 mm). Fascicles are the images of the lines
X, Y = const (a grid of s x t lines, each a polyline): they run from the zygomatic arch
(z = H) down and back to the mandible (z = 0), tangent dphi/dr. They are straight when
bulge = bow = curve = 0.

Aponeuroses: three interdigitating tendon sheets, the images of rectangles Y = Y_k: two
"upper" sheets hanging from the arch (r in [0.35, 1]) and one "lower" sheet rising from the
jaw insertion (r in [0, 0.65]) between them, each s in [-0.4, 0.4]. A sheet is a triangle
mesh (structured, edge ``membrane_size``) extruded by +-h/2 in Y (h = 0.5 mm) into a
membrane of 6-node wedge (prism) elements, mapped by phi.

Attachments: the top face (z = H) is carried by a rigid "zygomatic arch" body, the bottom
face's insertion strip |y| <= ``jaw_strip``/2 (z = 0; None: the whole bottom face) by a
rigid jaw (:class:`NodeAttachment`, x_i = p + R r_i). Both bodies are dynamic and welded to
the world (:class:`FixedJoint`): a clenched, isometric jaw. Gravity is off, so the jaw
force is the muscle's alone.

Models
------
- embedding: a :class:`VoxelFemBody` (a regular hex grid around the muscle surface, empty
  cells removed, mass and every energy density weighted by the volume fraction phi_e;
  Nesme et al. 2009), the grid planes aligned with the attachment edges; the aponeurosis
  membranes are separate wedge FEM bodies whose every node follows the primary element it
  lies in, x_s = sum_j N_j(X_s) x_j (:class:`EmbeddedFemAttachment`, non-conforming,
  section 3.1/4.2): the membranes' dofs leave the solve, their mass, stiffness and forces
  act on the primary through W^T.
- conforming: a gmsh tet mesh of the block, mapped by phi; with aponeuroses either the same
  embedded wedge membranes ("embedded", the paper's Fig. 15 middle) or the sheets as
  conforming slabs: the 0.5 mm slabs are volumes of the gmsh fragment, meshed at
  ``slab_size`` (graded to ``tet_size`` away), and their tets get the tendon energy on top of
  the muscle ("slabs", the conforming alternative the paper avoids). In every model the
  membrane overlaps the muscle (muscle + tendon in the membrane volume), so all represent
  the same superposition.

Materials: muscle = Mooney-Rivlin (C10 = 5 kPa, kappa = 50 kPa: compressible, nu ~ 0.41,
to keep the P1 tets from locking) plus Blemker's fiber energy (max stress 100 kPa,
excitation a); tendon = neo-Hookean E = 5 MPa, nu = 0.3. Densities 1060 (muscle), 1100
(tendon), 1900 (bone) kg/m^3. These are plausible round numbers, not fitted values.

Fiber directions: at every quadrature point of the primary mesh (8 per hex, 2 x 2 x 2 Gauss;
1 per P1 tet, its centroid), the unit tangent of the nearest fascicle segment (exact
point-to-segment distance), stored in a quadrature-space Function
(:meth:`FemBody.quadrature_space`).

``artifem simulate masseter --case C --level L`` runs one model through the runner
(:mod:`artifem.models.runner`): the excitation ramped over :data:`RAMP` seconds, then
held; ``artifem study masseter`` (:mod:`artifem.models.masseter.study`) compares the five
models and measures the jaw force at equilibrium (docs/masseter.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
import basix.ufl
import numpy as np
from dolfinx import fem
from dolfinx import mesh as dmesh
from mpi4py import MPI
from scipy.spatial import cKDTree

from artifem.arguments import fraction
from artifem.errors import InputError, SolverError
from artifem.excitation import ExcitationSchedule
from artifem.embedding.embedded_mesh import EmbeddedMesh
from artifem.embedding.voxel_fem import VoxelFemBody
from artifem.fem_body import FemBody
from artifem.forms import BlemkerFiber, MooneyRivlin, NeoHookean
from artifem.multibody.attachments import EmbeddedFemAttachment, NodeAttachment
from artifem.models.masseter.render import render
from artifem.models.runner import Built, Model, command
from artifem.scene import Scene
from artifem.multibody.joints import FixedJoint
from artifem.multibody.rigid_body import RigidBody

__all__ = [
    "MasseterConfig",
    "MasseterShape",
    "MasseterModel",
    "fascicles",
    "fiber_directions",
    "membrane_mesh",
    "block_mesh",
    "build_model",
    "dof_counts",
    "MODELS",
    "COARSE",
    "MODEL",
]

#: (primary, aponeuroses) of the compared models.
MODELS = (
    ("embedding", "none"),
    ("embedding", "embedded"),
    ("conforming", "none"),
    ("conforming", "embedded"),
    ("conforming", "slabs"),
)


@dataclass(frozen=True)
class MasseterConfig:
    """Geometry, meshes, materials and run of the synthetic masseter (SI units)."""

    height: float = 0.050
    width_bottom: float = 0.025
    width_top: float = 0.020
    thickness: float = 0.010
    bulge: float = 0.2
    lean: float = 0.0075
    bow: float = 0.003
    curve: float = 0.002
    #: aponeuroses (t, r0, r1): the sheet Y = (t + 1/2) T for r in [r0, r1]; s in sheet_span.
    sheets: tuple = ((-0.25, 0.35, 1.0), (0.0, 0.0, 0.65), (0.25, 0.35, 1.0))
    sheet_span: tuple = (-0.4, 0.4)
    membrane_thickness: float = 0.0005
    membrane_size: float = 0.0015
    #: width (y) of the jaw insertion strip on the bottom face; None: the whole face.
    jaw_strip: float | None = 0.005
    #: fascicles: (n_s, n_t) lines, each of ``fascicle_segments`` segments.
    fascicle_grid: tuple = (7, 5)
    fascicle_segments: int = 20
    voxel_size: float = 0.0025
    voxel_samples: int = 4
    tet_size: float = 0.0025
    slab_size: float = 0.001
    muscle_c10: float = 5.0e3
    muscle_kappa: float = 5.0e4
    max_stress: float = 1.0e5
    excitation: float = 0.1
    tendon_young: float = 5.0e6
    tendon_poisson: float = 0.3
    density: float = 1060.0
    tendon_density: float = 1100.0
    bone_density: float = 1900.0
    rayleigh: tuple = (10.0, 0.0)
    dt: float = 0.01
    steps: int = 10

    def __post_init__(self):
        for name in (
            "height",
            "width_bottom",
            "width_top",
            "thickness",
            "membrane_thickness",
            "membrane_size",
            "voxel_size",
            "tet_size",
            "slab_size",
            "muscle_c10",
            "muscle_kappa",
            "max_stress",
            "tendon_young",
            "density",
            "tendon_density",
            "bone_density",
            "dt",
        ):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(f"MasseterConfig: {name} must be > 0, got {value!r}")
        if not 0.0 <= self.excitation <= 1.0:
            raise InputError(
                f"MasseterConfig: excitation must be in [0, 1], got {self.excitation!r}"
            )
        if self.jaw_strip is not None and not 0 < self.jaw_strip <= self.thickness:
            raise InputError(
                f"MasseterConfig: jaw_strip must be in (0, thickness] or None, got "
                f"{self.jaw_strip!r}"
            )
        if self.steps < 1 or self.fascicle_segments < 1 or min(self.fascicle_grid) < 1:
            raise InputError(
                "MasseterConfig: steps, fascicle_segments and fascicle_grid must be >= 1"
            )
        for t, r0, r1 in self.sheets:
            if not (-0.5 < t < 0.5 and 0.0 <= r0 < r1 <= 1.0):
                raise InputError(
                    f"MasseterConfig: a sheet (t, r0, r1) needs -1/2 < t < 1/2 and "
                    f"0 <= r0 < r1 <= 1, got {(t, r0, r1)}"
                )
        s0, s1 = self.sheet_span
        if not -0.5 < s0 < s1 < 0.5:
            raise InputError(
                f"MasseterConfig: sheet_span must satisfy -1/2 < s0 < s1 < 1/2, "
                f"got {self.sheet_span}"
            )


#: A fast setting for tests: 5 mm voxels and tets, 2 mm slab and membrane elements.
COARSE = dict(
    voxel_size=0.005,
    tet_size=0.005,
    slab_size=0.002,
    membrane_size=0.003,
    voxel_samples=3,
    fascicle_grid=(5, 3),
    fascicle_segments=10,
    steps=3,
)


class MasseterShape:
    """The map phi from the reference block to the muscle (module docstring)."""

    def __init__(self, config: MasseterConfig):
        self.c = config

    def _srt(self, P):
        P = np.asarray(P, dtype=float).reshape(-1, 3)
        c = self.c
        return (P[:, 0] / c.width_bottom - 0.5, P[:, 1] / c.thickness - 0.5, P[:, 2] / c.height)

    def to_physical(self, P) -> np.ndarray:
        """phi(P) for reference points P (n, 3)."""
        c = self.c
        s, t, r = self._srt(P)
        sn = np.sin(np.pi * r)
        x = s * (c.width_bottom + (c.width_top - c.width_bottom) * r) + c.lean * r + c.curve * sn
        y = t * c.thickness * (1.0 + c.bulge * sn) + c.bow * sn
        return np.column_stack([x, y, r * c.height])

    def fascicle_tangent(self, P) -> np.ndarray:
        """Unit dphi/dZ at reference points P (n, 3): the fascicle direction there."""
        c = self.c
        s, t, r = self._srt(P)
        cs = np.pi * np.cos(np.pi * r)
        d = np.column_stack(
            [
                s * (c.width_top - c.width_bottom) + c.lean + c.curve * cs,
                t * c.thickness * c.bulge * cs + c.bow * cs,
                np.full_like(r, c.height),
            ]
        )
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def sheet_y(self, t: float) -> float:
        return (t + 0.5) * self.c.thickness


# ---- fascicles and fiber directions -----------------------------------------------------


def fascicles(config: MasseterConfig) -> list[np.ndarray]:
    """The fascicle polylines (physical, each (segments + 1, 3), from the jaw up)."""
    shape = MasseterShape(config)
    ns, nt = config.fascicle_grid
    s = (np.arange(ns) + 0.5) / ns
    t = (np.arange(nt) + 0.5) / nt
    Z = np.linspace(0.0, config.height, config.fascicle_segments + 1)
    lines = []
    for si in s:
        for ti in t:
            P = np.column_stack(
                [
                    np.full_like(Z, si * config.width_bottom),
                    np.full_like(Z, ti * config.thickness),
                    Z,
                ]
            )
            lines.append(shape.to_physical(P))
    return lines


def fiber_directions(points, lines) -> np.ndarray:
    """Unit tangent of the nearest fascicle segment at each point (p, 3).

    Exact: the nearest segment has distance <= d0 (the nearest midpoint's), so its midpoint
    is within d0 + L_max/2 of the point; all segments whose midpoints lie in that ball are
    measured (point-to-segment distance) and the closest one gives the direction.
    """
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    if not lines:
        raise InputError("fiber_directions: no fascicles")
    a = np.concatenate([np.asarray(L, float)[:-1] for L in lines])
    b = np.concatenate([np.asarray(L, float)[1:] for L in lines])
    d = b - a
    length = np.linalg.norm(d, axis=1)
    if np.any(length <= 0):
        raise InputError("fiber_directions: a fascicle has a zero-length segment")
    tangent = d / length[:, None]
    tree = cKDTree(0.5 * (a + b))
    d0, _ = tree.query(P)
    candidates = tree.query_ball_point(P, d0 + 0.5 * length.max() * (1 + 1e-12))
    out = np.empty_like(P)
    for i, cand in enumerate(candidates):
        cand = np.asarray(cand)
        w = np.clip(np.einsum("ij,ij->i", P[i] - a[cand], d[cand]) / length[cand] ** 2, 0, 1)
        dist = np.linalg.norm(a[cand] + w[:, None] * d[cand] - P[i], axis=1)
        out[i] = tangent[cand[np.argmin(dist)]]
    return out


def quadrature_fibers(body: FemBody, lines) -> fem.Function:
    """The fiber direction field at the body's energy quadrature points (nearest fascicle)."""
    Q = body.quadrature_space()
    x = body.quadrature_points()  # (cells, points, 3)
    a0 = fem.Function(Q, name="fiber direction")
    dirs = fiber_directions(x.reshape(-1, 3), lines)
    a0.x.array.reshape(-1, 3)[Q.dofmap.list.reshape(-1)] = dirs
    return a0


# ---- meshes ----------------------------------------------------------------------------


def membrane_mesh(config: MasseterConfig, sheet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (n, 3), prisms (c, 6), mid-surface triangles (c, 3)) of one aponeurosis.

    The sheet's rectangle is triangulated (edge about ``membrane_size``) and extruded to
    Y_k -+ h/2 in the reference block; phi maps the nodes. Prism nodes: the triangle at
    Y_k - h/2, then the one at Y_k + h/2 (basix/DOLFINx prism order). The triangles index
    the first layer (the mid-surface is drawn from it).
    """
    c = config
    t, r0, r1 = sheet
    s0, s1 = c.sheet_span
    X = (np.array([s0, s1]) + 0.5) * c.width_bottom
    Z = np.array([r0, r1]) * c.height
    ns = max(1, int(np.ceil((X[1] - X[0]) / c.membrane_size)))
    nr = max(1, int(np.ceil((Z[1] - Z[0]) / c.membrane_size)))
    gx, gz = np.meshgrid(np.linspace(*X, ns + 1), np.linspace(*Z, nr + 1), indexing="ij")
    idx = np.arange(gx.size).reshape(ns + 1, nr + 1)
    q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    tri = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    n = gx.size
    Y = MasseterShape(c).sheet_y(t)
    h = c.membrane_thickness
    ref = np.concatenate(
        [
            np.column_stack([gx.ravel(), np.full(n, Y + dy), gz.ravel()])
            for dy in (-0.5 * h, 0.5 * h)
        ]
    )
    prisms = np.column_stack([tri, tri + n])
    return MasseterShape(c).to_physical(ref), prisms, tri


def _boundary_triangles(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """The faces of a tet mesh that belong to one tet, oriented outward."""
    local = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    faces = tets[:, local].reshape(-1, 3)
    opposite = tets.reshape(-1)  # local face k is opposite vertex k
    _, first, counts = np.unique(
        np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True
    )
    keep = first[counts == 1]
    f, o = faces[keep], opposite[keep]
    a, b, cc = (points[f[:, k]] for k in range(3))
    inward = np.einsum("ij,ij->i", np.cross(b - a, cc - a), points[o] - a) > 0
    f[inward] = f[inward][:, ::-1]
    return f


def block_mesh(config: MasseterConfig, slabs: bool) -> dict:
    """The conforming tet mesh (gmsh) of the muscle, mapped by phi.

    The reference block is fragmented with the jaw insertion strip (so the strip's edges are
    mesh lines) and, with ``slabs``, the aponeurosis slabs Y_k -+ h/2, meshed at
    ``slab_size`` and graded to ``tet_size`` within 3 ``tet_size`` of them. Returns points,
    tets, region (0 muscle, k + 1 slab k) and the outward boundary triangles.
    """
    import gmsh

    c = config
    W, T, H = c.width_bottom, c.thickness, c.height
    shape = MasseterShape(c)
    slab_boxes = []
    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("masseter")
        occ = gmsh.model.occ
        box = occ.addBox(0, 0, 0, W, T, H)
        tools = []
        if c.jaw_strip is not None:
            tools.append((2, occ.addRectangle(0, 0.5 * (T - c.jaw_strip), 0, W, c.jaw_strip)))
        if slabs:
            s0, s1 = c.sheet_span
            for t, r0, r1 in c.sheets:
                y = shape.sheet_y(t) - 0.5 * c.membrane_thickness
                x0 = (s0 + 0.5) * W
                slab_boxes.append((x0, (s1 - s0) * W, y, r0 * H, (r1 - r0) * H))
                tools.append(
                    (
                        3,
                        occ.addBox(
                            x0, y, r0 * H, (s1 - s0) * W, c.membrane_thickness, (r1 - r0) * H
                        ),
                    )
                )
        if tools:
            occ.fragment([(3, box)], tools)
        occ.synchronize()
        volumes = [tag for _, tag in gmsh.model.getEntities(3)]
        region = {}
        eps = 0.1 * c.membrane_thickness  # OCC bounding boxes are padded
        for tag in volumes:  # a slab volume lies inside its slab box
            lo, hi = np.split(np.array(gmsh.model.getBoundingBox(3, tag)), 2)
            region[tag] = next(
                (
                    k + 1
                    for k, (x0, dx, y0, z0, dz) in enumerate(slab_boxes)
                    if np.all(lo >= np.array([x0, y0, z0]) - eps)
                    and np.all(hi <= np.array([x0 + dx, y0 + c.membrane_thickness, z0 + dz]) + eps)
                ),
                0,
            )
        gmsh.option.setNumber("Mesh.MeshSizeMax", c.tet_size)
        gmsh.option.setNumber("Mesh.MeshSizeMin", min(c.slab_size, c.tet_size))
        if slabs:
            slab_surfaces = [
                s
                for tag, k in region.items()
                if k
                for _, s in gmsh.model.getBoundary([(3, tag)], oriented=False)
            ]
            dist = gmsh.model.mesh.field.add("Distance")
            gmsh.model.mesh.field.setNumbers(dist, "SurfacesList", slab_surfaces)
            thr = gmsh.model.mesh.field.add("Threshold")
            gmsh.model.mesh.field.setNumber(thr, "InField", dist)
            gmsh.model.mesh.field.setNumber(thr, "SizeMin", c.slab_size)
            gmsh.model.mesh.field.setNumber(thr, "SizeMax", c.tet_size)
            gmsh.model.mesh.field.setNumber(thr, "DistMin", 0.5 * c.slab_size)
            gmsh.model.mesh.field.setNumber(thr, "DistMax", 3.0 * c.tet_size)
            gmsh.model.mesh.field.setAsBackgroundMesh(thr)
            gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
            gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        order = np.argsort(tags)
        index = np.empty(int(tags.max()) + 1, dtype=np.int64)
        index[tags[order]] = np.arange(tags.size)
        points = coords.reshape(-1, 3)[order]
        tets, regions = [], []
        for tag in volumes:
            types, _, nodes = gmsh.model.mesh.getElements(3, tag)
            for etype, enodes in zip(types, nodes):
                if etype != 4:
                    raise SolverError(f"block_mesh: gmsh made element type {etype}, not tets")
                cells = index[np.asarray(enodes, dtype=np.int64)].reshape(-1, 4)
                tets.append(cells)
                regions.append(np.full(len(cells), region[tag]))
    finally:
        gmsh.finalize()
    tets = np.concatenate(tets)
    used, tets = np.unique(tets, return_inverse=True)
    tets = tets.reshape(-1, 4)
    points = shape.to_physical(points[used])
    return {
        "points": points,
        "tets": tets,
        "region": np.concatenate(regions),
        "surface": _boundary_triangles(points, tets),
    }


def _dolfinx_mesh(points, cells, cell: str):
    element = basix.ufl.element("Lagrange", cell, 1, shape=(3,))
    return dmesh.create_mesh(
        MPI.COMM_SELF, np.asarray(cells, dtype=np.int64), element, np.asarray(points, dtype=float)
    )


def _box_surface(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and outward triangles of an axis-aligned box."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    V = lo + corners * (hi - lo)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    T = np.array([[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads])
    return V, T


class _RegionMaterial:
    """An isotropic energy in FemBody's fiber-material slot (a0 and the excitation ignored):
    adds the tendon to the slab cells of the conforming model."""

    def __init__(self, material):
        self.material = material

    def strain_energy(self, F, a0, excitation):
        return self.material.strain_energy(F)


# ---- the scene ---------------------------------------------------------------------------


@dataclass
class MasseterModel:
    """A built scene (see :func:`build_model`)."""

    config: MasseterConfig
    primary_kind: str
    aponeuroses: str
    scene: Scene
    primary: FemBody
    membranes: list
    attachments: list
    jaw: RigidBody
    arch: RigidBody
    jaw_joint: FixedJoint
    arch_joint: FixedJoint
    fascicles: EmbeddedMesh
    fibers: fem.Function
    jaw_nodes: np.ndarray
    arch_nodes: np.ndarray
    info: dict = field(default_factory=dict)

    @property
    def label(self) -> str:
        return f"{self.primary_kind}/{self.aponeuroses}"


def _attachment_nodes(config: MasseterConfig, body: FemBody):
    """(arch nodes: on the top face's footprint, jaw nodes: on the bottom insertion strip)."""
    c = config
    tol = 1e-9
    strip = c.thickness if c.jaw_strip is None else c.jaw_strip
    jaw = body.find_nodes(
        lambda x: (
            (np.abs(x[2]) < tol)
            & (np.abs(x[0]) <= 0.5 * c.width_bottom + tol)
            & (np.abs(x[1]) <= 0.5 * strip + tol)
        )
    )
    arch = body.find_nodes(
        lambda x: (
            (np.abs(x[2] - c.height) < tol)
            & (np.abs(x[0] - c.lean) <= 0.5 * c.width_top + tol)
            & (np.abs(x[1]) <= 0.5 * c.thickness + tol)
        )
    )
    if jaw.size == 0 or arch.size == 0:
        raise InputError(
            f"masseter: no nodes on the jaw strip ({jaw.size}) or the arch "
            f"({arch.size}); refine the mesh"
        )
    return arch, jaw


def _voxel_bounds(config: MasseterConfig, surface_points: np.ndarray):
    """Grid bounds whose planes hold the attachment edges (x = -W_b/2, y = -strip/2, z = 0)."""
    h = config.voxel_size
    strip = config.thickness if config.jaw_strip is None else config.jaw_strip
    anchor = np.array([-0.5 * config.width_bottom, -0.5 * strip, 0.0])
    lo = anchor - np.ceil((anchor - surface_points.min(axis=0)) / h - 1e-9) * h
    return lo, surface_points.max(axis=0)


def build_model(
    config: MasseterConfig,
    primary: str = "embedding",
    aponeuroses: str = "embedded",
    integrator: str = "semi-implicit",
) -> MasseterModel:
    """The scene of one model (module docstring).

    Args:
        primary: "embedding" (voxel hex grid) or "conforming" (gmsh tets).
        aponeuroses: "none", "embedded" (wedge membranes on EmbeddedFemAttachment) or
            "slabs" (conforming tendon slabs; conforming primary only).
        integrator: the scene's (:data:`artifem.scene.INTEGRATORS`).
    """
    if (primary, aponeuroses) not in MODELS:
        raise InputError(
            f"masseter: unknown model ({primary!r}, {aponeuroses!r}); choose one of {MODELS}"
        )
    c = config
    muscle = MooneyRivlin(c.muscle_c10, kappa=c.muscle_kappa)
    tendon = NeoHookean.from_young_poisson(c.tendon_young, c.tendon_poisson)
    kwargs = dict(rayleigh=c.rayleigh, name=f"masseter ({primary})")
    info = {}
    t0 = time.perf_counter()
    if primary == "embedding":
        surf = block_mesh(c, slabs=False)
        V, T = surf["points"], surf["surface"]
        lo, hi = _voxel_bounds(c, V)
        body = VoxelFemBody(
            V,
            T,
            muscle,
            c.density,
            cell_size=c.voxel_size,
            bounds=(lo, hi),
            samples=c.voxel_samples,
            comm=MPI.COMM_SELF,
            **kwargs,
        )
        info["voxel_volume"] = body.voxels.volume
        info["surface_volume"] = float(_tet_volume(V, surf["tets"]))
        info["surface_area"] = float(_area(V, T))
        info["sample_diagonal"] = body.voxels.sample_diagonal
    else:
        mesh = block_mesh(c, slabs=aponeuroses == "slabs")
        body = FemBody(
            _dolfinx_mesh(mesh["points"], mesh["tets"], "tetrahedron"), muscle, c.density, **kwargs
        )
        info["tet_volume"] = float(_tet_volume(mesh["points"], mesh["tets"]))
    n_cells = body.mesh.topology.index_map(3).size_local
    lines = fascicles(c)
    fibers = quadrature_fibers(body, lines)
    body.add_muscle("masseter", np.arange(n_cells), fibers, BlemkerFiber(max_stress=c.max_stress))
    if aponeuroses == "slabs":
        slab_cells = np.flatnonzero(mesh["region"] > 0)
        body.add_muscle("aponeuroses", slab_cells, (0.0, 0.0, 1.0), _RegionMaterial(tendon))
        info["slab_cells"] = int(slab_cells.size)
    info["build_s"] = time.perf_counter() - t0

    scene = Scene(gravity=(0.0, 0.0, 0.0), integrator=integrator)
    scene.add(body)
    membranes, attachments = [], []
    if aponeuroses == "embedded":
        for k, sheet in enumerate(c.sheets):
            P, prisms, _ = membrane_mesh(c, sheet)
            m = FemBody(
                _dolfinx_mesh(P, prisms, "prism"),
                tendon,
                c.tendon_density,
                rayleigh=c.rayleigh,
                name=f"aponeurosis {k}",
            )
            att = EmbeddedFemAttachment(m, body, snap=True, name=f"aponeurosis {k}")
            scene.add(m, att)
            membranes.append(m)
            attachments.append(att)
        info["membrane_snap_max"] = float(max(a.distance.max() for a in attachments))
    arch_nodes, jaw_nodes = _attachment_nodes(c, body)
    W, H = c.width_bottom, c.height
    jaw = RigidBody.from_surface(
        "jaw",
        *_box_surface((-0.6 * W, -0.8 * c.thickness, -0.3 * H), (0.6 * W, 0.8 * c.thickness, 0.0)),
        c.bone_density,
    )
    arch = RigidBody.from_surface(
        "zygomatic arch",
        *_box_surface(
            (c.lean - 0.8 * W, -0.8 * c.thickness, H),
            (c.lean + 0.8 * W, 0.8 * c.thickness, 1.15 * H),
        ),
        c.bone_density,
    )
    jaw_joint = FixedJoint.at_world(jaw, None, jaw.position, name="jaw weld")
    arch_joint = FixedJoint.at_world(arch, None, arch.position, name="arch weld")
    scene.add(
        jaw,
        arch,
        jaw_joint,
        arch_joint,
        NodeAttachment(body, jaw_nodes, jaw, name="jaw insertion"),
        NodeAttachment(body, arch_nodes, arch, name="arch origin"),
    )
    embedded = EmbeddedMesh(
        body,
        np.concatenate(lines),
        np.concatenate(
            [
                np.column_stack([np.arange(len(L) - 1), np.arange(1, len(L))]) + k * len(L)
                for k, L in enumerate(lines)
            ]
        ),
        "line",
        snap=True,
        name="fascicles",
    )
    info["fascicle_snap_max"] = float(embedded.distance.max())
    return MasseterModel(
        c,
        primary,
        aponeuroses,
        scene,
        body,
        membranes,
        attachments,
        jaw,
        arch,
        jaw_joint,
        arch_joint,
        embedded,
        fibers,
        jaw_nodes,
        arch_nodes,
        info,
    )


def _tet_volume(points, tets) -> float:
    a, b, c, d = (points[tets[:, k]] for k in range(4))
    return float(np.abs(np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a))).sum() / 6.0)


def _area(points, tris) -> float:
    a, b, c = (points[tris[:, k]] for k in range(3))
    return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


def dof_counts(model: MasseterModel) -> dict:
    """Masters in the solve and the FEM nodes (primary, membranes)."""
    n = model.primary.V.dofmap.index_map.size_local
    return {
        "masters": int(model.scene.master_count()),
        "primary_nodes": int(n),
        "membrane_nodes": int(sum(m.V.dofmap.index_map.size_local for m in model.membranes)),
    }


# ---- the runner's masseter (``artifem simulate masseter``) ---------------------------------

#: seconds over which the runner ramps the excitation (then held)
RAMP = 0.1
#: case name -> (primary, aponeuroses) of :data:`MODELS`
CASES = {
    "embedding": ("embedding", "none"),
    "embedding-aponeuroses": ("embedding", "embedded"),
    "conforming": ("conforming", "none"),
    "conforming-aponeuroses": ("conforming", "embedded"),
    "conforming-slabs": ("conforming", "slabs"),
}


def build(
    case: str, level: int = 1, integrator: str = "semi-implicit", excitation: float = 0.1
) -> Built:
    """One masseter model (``case``: :data:`CASES`) at ``level`` (0: :data:`COARSE`, 1: the
    default sizes), its excitation ramped to ``excitation`` over :data:`RAMP` s, for
    :mod:`artifem.models.runner`. Recorded: the force the muscle transmits to the jaw over
    each step, -(the weld's reaction) (0 at the start); the figures: the masters and nodes,
    that force at the end and its largest magnitude, the displacement and the mass."""
    coarse = {k: v for k, v in COARSE.items() if k != "steps"} if level == 0 else {}
    config = MasseterConfig(excitation=excitation, **coarse)
    model = build_model(config, *CASES[case], integrator=integrator)
    schedule = ExcitationSchedule(np.array([0.0, RAMP]), {"masseter": np.array([0.0, excitation])})
    model.scene.add_controller(schedule.controller(model.primary))

    def jaw_force(scene) -> np.ndarray:
        return -scene.reaction(model.jaw_joint)[0][:3]

    def figures(run) -> dict:
        f_jaw = run.records["jaw_force_N"]
        u = model.primary.u.x.array.reshape(-1, 3)
        return {
            "geometry": "synthetic (no public masseter data; see models/masseter/model.py)",
            "excitation": excitation,
            "ramp_s": RAMP,
            **dof_counts(model),
            "jaw_force_N": f_jaw[-1].tolist(),
            "jaw_force_magnitude_N": float(np.linalg.norm(f_jaw[-1])),
            "jaw_force_magnitude_max_N": float(np.linalg.norm(f_jaw, axis=1).max()),
            "max_displacement_mm": 1e3 * float(np.linalg.norm(u, axis=1).max()),
            "mass_kg": float(model.primary.total_mass()),
            **model.info,
        }

    return Built(
        model.scene,
        record={"jaw_force_N": jaw_force},
        figures=figures,
        render=lambda png, run, shown: render([model], png),
    )


def _options(group) -> None:
    group.add_argument(
        "--excitation",
        type=fraction,
        default=MasseterConfig.excitation,
        help="the muscle's, reached at the end of the ramp (%(default)s)",
    )


MODEL = Model(
    name="masseter",
    summary="synthetic masseter: embedding vs conforming, aponeuroses",
    build=build,
    cases={
        "embedding-aponeuroses": "voxel (embedding) FEM, aponeuroses as embedded membranes",
        "embedding": "voxel (embedding) FEM, no aponeuroses",
        "conforming": "conforming tet FEM, no aponeuroses",
        "conforming-aponeuroses": "conforming tet FEM, aponeuroses as embedded membranes",
        "conforming-slabs": "conforming tet FEM, aponeuroses as conforming tendon slabs",
    },
    levels={0: "5 mm voxels and tets", 1: "2.5 mm voxels and tets"},
    dt=MasseterConfig.dt,
    duration=0.2,
    default_level=1,
    camera="xz",
    options=_options,
)
add_arguments, run = command(MODEL)
