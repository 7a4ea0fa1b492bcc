"""The foot's soft tissue meshed with gmsh: P1 tetrahedra between the skin and the bones.

Domain: inside the skin (:func:`artifem.models.foot.skin.envelope`), below the cap plane
y = cap_y, outside every rigid group's surface (:func:`~artifem.models.foot.skin.
group_surface`: the group's bones fused by a level set and moved ``shrink`` inside, which
keeps the groups apart: raw gaps go down to 0.2 mm, navicular to the lateral cuneiforms).
The tibia group leaves through the cap: its surface, cut by the cap plane, is a hole of
the cap (vtkClipClosedSurface on skin + inward tibia). The boundary triangles are given to
gmsh as discrete surfaces and kept; gmsh fills the volume (Delaunay 3D, sizes from the
boundary, at most ``h_max``).

Facet tags: SKIN, CAP, and BONE + i for the i-th group of
:data:`~artifem.models.foot.bones.GROUPS`. Levels (:data:`LEVELS`): 0 coarse, for tests
(1,923 nodes, 7,544 tetrahedra, 7 s); 1 the default (13,453 nodes,
54,255 tetrahedra, 13 s; most of it the level sets, gmsh under 1 s). Meshes are
cached as .npz under ``cache`` keyed by a hash of the parameters.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from artifem.errors import InputError, MeshError
from artifem.models.cache import user_cache

from . import bones as fb
from . import skin as fs

SKIN, CAP, BONE = 1, 2, 10
DEFAULT_CACHE = user_cache("foot")


@dataclass(frozen=True)
class MeshParams:
    """A level's sizes (metres): the groups' grid ``spacing``, ``shrink`` and target edge
    ``h_bone``; the skin's target triangle count (in ``skin``); the largest tet edge."""

    spacing: float
    shrink: float
    h_bone: float
    h_max: float
    skin: fs.SkinParams = field(default_factory=fs.SkinParams)


LEVELS = {
    0: MeshParams(0.0012, 0.0003, 0.008, 0.014, fs.SkinParams(triangles=1200)),
    1: MeshParams(0.0008, 0.0003, 0.0028, 0.006, fs.SkinParams(triangles=4000)),
}


@dataclass
class FootMesh:
    """Tetrahedra of the foot's soft tissue (metres, tibia frame), boundary facets tagged
    (SKIN, CAP, BONE + group index), and each rigid group's surface (the holes)."""

    points: np.ndarray
    cells: np.ndarray
    facets: np.ndarray
    facet_tags: np.ndarray
    groups: list[str]
    group_surfaces: dict[str, tuple[np.ndarray, np.ndarray]]
    skin: tuple[np.ndarray, np.ndarray]
    cap_y: float
    stats: dict

    def tag(self, name: str) -> int:
        """The facet tag of "skin", "cap" or a group name."""
        if name in ("skin", "cap"):
            return SKIN if name == "skin" else CAP
        return BONE + self.groups.index(name)


def check_input(
    bones: list[fb.Bone],
    skin: tuple[np.ndarray, np.ndarray] | None = None,
    cap_y: float | None = None,
) -> None:
    """Refuse, before meshing: units off (:func:`~.bones.check_units`), bones of different
    groups intersecting (:func:`~.bones.penetrations`), a skin that does not contain every
    bone vertex below the cap."""
    fb.check_units(bones)
    files = {b.name: b.file for b in bones}
    bad = fb.penetrations(bones)
    if bad:
        a, b, depth = max(bad, key=lambda x: x[2])
        raise MeshError(
            f"bones of different rigid groups intersect: {a} ({files[a]}) and "
            f"{b} ({files[b]}), {depth * 1e3:.3g} mm deep"
            + (f"; and {len(bad) - 1} more pair(s)" if len(bad) > 1 else "")
        )
    if skin is not None:
        for b in bones:
            v = b.vertices[b.vertices[:, 1] < cap_y]
            if len(v) and (fs.signed_distance(v, *skin) > 0).any():
                raise MeshError(
                    f"the skin does not contain bone {b.name} ({b.file}): "
                    f"{int((fs.signed_distance(v, *skin) > 0).sum())} vertex(es) "
                    f"outside"
                )


def surfaces(bones: list[fb.Bone], params: MeshParams):
    """(outer boundary (vertices, triangles, tags), group surfaces, skin): the skin and
    the tibia group joined through the cap, the other groups as closed holes."""
    skin_open = fs.envelope(bones, params.skin, capped=False)
    skin = fs.cap([skin_open], params.skin.cap_y)
    check_input(bones, skin, params.skin.cap_y)
    groups = {}
    for name, members in fb.GROUPS.items():
        gb = [b for b in bones if b.name in members]
        y_max = params.skin.cap_y + 4 * params.spacing if name == "tibia" else None
        area = sum(_area(b.vertices, b.triangles, y_max) for b in gb)
        triangles = max(60, int(area / (0.433 * params.h_bone**2)))
        groups[name] = fs.group_surface(gb, params.spacing, params.shrink, triangles, y_max)
    tv, tf = groups["tibia"]
    v, f = fs.cap([skin_open, (tv, tf[:, ::-1])], params.skin.cap_y)
    fb.check_closed("skin + cap + tibia surface", v, f)
    centre = v[f].mean(1)
    tags = np.where(
        np.abs(fs.signed_distance(centre, tv, tf)) < np.abs(fs.signed_distance(centre, *skin_open)),
        BONE,
        SKIN,
    )
    tags[np.all(v[f][:, :, 1] == params.skin.cap_y, axis=1)] = CAP
    groups["tibia"] = fs.cap([(tv, tf)], params.skin.cap_y)
    return (v, f, tags), groups, skin


def _area(v, f, y_max: float | None = None) -> float:
    """Area of the triangles (those whose centre is below ``y_max``)."""
    if y_max is not None:
        f = f[v[f][:, :, 1].mean(1) < y_max]
    return float(
        0.5
        * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
    )


def _gmsh(outer, holes: list[tuple[np.ndarray, np.ndarray, int]], h_max: float):
    """Tetrahedra filling the outer surface minus the holes, boundary triangles kept:
    (points, cells, facets, facet tags)."""
    import gmsh

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("foot")
        shells = [outer] + [(v, f, np.full(len(f), t)) for v, f, t in holes]
        offset, entities, points = 1, [], []
        for v, f, tags in shells:
            first = True
            for t in np.unique(tags):
                s = gmsh.model.addDiscreteEntity(2)
                if first:
                    gmsh.model.mesh.addNodes(2, s, np.arange(offset, offset + len(v)), v.ravel())
                    first = False
                gmsh.model.mesh.addElementsByType(s, 2, [], (f[tags == t] + offset).ravel())
                entities.append((s, int(t)))
            points.append(v)
            offset += len(v)
        loop = gmsh.model.geo.addSurfaceLoop([s for s, _ in entities])
        gmsh.model.geo.addVolume([loop])
        gmsh.model.geo.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", h_max)
        gmsh.option.setNumber("Mesh.Optimize", 1)
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        pts = np.empty((int(tags.max()), 3))
        pts[tags.astype(int) - 1] = coords.reshape(-1, 3)
        _, nodes = gmsh.model.mesh.getElementsByType(4)
        cells = nodes.reshape(-1, 4).astype(np.int64) - 1
        facets, ftags = [], []
        for s, t in entities:
            _, fn = gmsh.model.mesh.getElementsByType(2, s)
            facets.append(fn.reshape(-1, 3).astype(np.int64) - 1)
            ftags.append(np.full(len(facets[-1]), t, np.int32))
    finally:
        gmsh.finalize()
    used, inverse = np.unique(cells, return_inverse=True)
    renumber = np.full(len(pts), -1)
    renumber[used] = np.arange(len(used))
    facets = renumber[np.vstack(facets)]
    if (facets < 0).any():
        missing = np.unique(np.concatenate(ftags)[np.any(facets < 0, axis=1)])
        raise MeshError(
            f"gmsh: {int(np.any(facets < 0, axis=1).sum())} boundary triangles "
            f"(tags {missing.tolist()}) are not on the tetrahedra "
            f"({len(cells)} tetrahedra)"
        )
    return pts[used], inverse.reshape(-1, 4), facets, np.concatenate(ftags)


def build(
    level: int = 1, bones: list[fb.Bone] | None = None, params: MeshParams | None = None
) -> FootMesh:
    """Mesh the foot (module docstring) at ``level`` (or with ``params``), not cached."""
    if params is None:
        if level not in LEVELS:
            raise InputError(f"foot mesh level {level} unknown: {sorted(LEVELS)}")
        params = LEVELS[level]
    bones = fb.load_bones() if bones is None else bones
    fb.check_units(bones)
    t0 = time.perf_counter()
    outer, groups, skin = surfaces(bones, params)
    t1 = time.perf_counter()
    names = list(fb.GROUPS)
    holes = [(*groups[g], BONE + i) for i, g in enumerate(names) if g != "tibia"]
    outer = (outer[0], outer[1], np.where(outer[2] == BONE, BONE + names.index("tibia"), outer[2]))
    points, cells, facets, ftags = _gmsh(outer, holes, params.h_max)
    t2 = time.perf_counter()
    a, b, c, d = (points[cells[:, i]] for i in range(4))
    volumes = np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a)) / 6.0
    cells[volumes < 0] = cells[volumes < 0][:, [0, 2, 1, 3]]
    stats = {
        "nodes": len(points),
        "tetrahedra": len(cells),
        "surfaces_s": t1 - t0,
        "gmsh_s": t2 - t1,
        "min_volume": float(np.abs(volumes).min()),
    }
    return FootMesh(points, cells, facets, ftags, names, groups, skin, params.skin.cap_y, stats)


def _key(level: int, params: MeshParams) -> str:
    text = json.dumps(
        {
            "level": level,
            "params": asdict(params),
            "bones": fb.BONES,
            "groups": fb.GROUPS,
            "version": 1,
        },
        sort_keys=True,
        default=str,
    )
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def foot_mesh(level: int = 1, cache: Path | None = DEFAULT_CACHE) -> FootMesh:
    """The foot mesh at ``level``, read from ``cache`` if there, else built and stored
    (``cache=None``: always built)."""
    if level not in LEVELS:
        raise InputError(f"foot mesh level {level} unknown: {sorted(LEVELS)}")
    params = LEVELS[level]
    path = None if cache is None else Path(cache) / f"foot_l{level}_{_key(level, params)}.npz"
    if path is not None and path.is_file():
        return _load(path)
    mesh = build(level, params=params)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        _save(mesh, path)
    return mesh


def _save(mesh: FootMesh, path: Path) -> None:
    arrays = {
        "points": mesh.points,
        "cells": mesh.cells,
        "facets": mesh.facets,
        "facet_tags": mesh.facet_tags,
        "skin_v": mesh.skin[0],
        "skin_f": mesh.skin[1],
    }
    for i, g in enumerate(mesh.groups):
        arrays[f"g{i}_v"], arrays[f"g{i}_f"] = mesh.group_surfaces[g]
    meta = json.dumps({"groups": mesh.groups, "cap_y": mesh.cap_y, "stats": mesh.stats})
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, meta=np.array(meta), **arrays)
    tmp.replace(path)


def _load(path: Path) -> FootMesh:
    with np.load(path) as z:
        meta = json.loads(str(z["meta"]))
        groups = meta["groups"]
        return FootMesh(
            z["points"],
            z["cells"],
            z["facets"],
            z["facet_tags"],
            groups,
            {g: (z[f"g{i}_v"], z[f"g{i}_f"]) for i, g in enumerate(groups)},
            (z["skin_v"], z["skin_f"]),
            meta["cap_y"],
            meta["stats"],
        )


def to_dolfinx(mesh: FootMesh, comm=None):
    """(dolfinx mesh, facet MeshTags) of a FootMesh (facet values: SKIN, CAP, BONE + i)."""
    import dolfinx.graph
    import dolfinx.mesh
    from mpi4py import MPI

    from artifem.io.mesh_data import MeshData
    from artifem.io.to_dolfinx import dolfinx_node_to_input, to_dolfinx as convert

    comm = MPI.COMM_SELF if comm is None else comm
    n = len(mesh.cells)
    data = MeshData(
        mesh.points,
        "tetrahedron",
        mesh.cells,
        np.arange(len(mesh.points)),
        np.arange(n),
        np.zeros(n, np.int32),
        source="foot",
    )
    msh, _ = convert(data, comm)
    msh.topology.create_connectivity(3, 0)
    c2v = msh.topology.connectivity(3, 0).array.reshape(-1, 4)
    dofmap = msh.geometry.dofmaps[0]
    vertex_of_node = np.empty(msh.geometry.x.shape[0], np.int32)
    vertex_of_node[dofmap.ravel()] = c2v.ravel()
    node_of_input = np.full(len(mesh.points), -1)
    node_of_input[dolfinx_node_to_input(msh)] = np.arange(msh.geometry.x.shape[0])
    local = node_of_input[mesh.facets]
    keep = np.all(local >= 0, axis=1)
    entities = vertex_of_node[local[keep]]
    msh.topology.create_entities(2)
    tags = dolfinx.mesh.meshtags_from_entities(
        msh,
        2,
        dolfinx.graph.adjacencylist(entities.astype(np.int32)),
        mesh.facet_tags[keep].astype(np.int32),
    )
    return msh, tags
