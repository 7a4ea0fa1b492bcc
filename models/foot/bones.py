"""The right-foot bones of OpenSim (models/data/opensim-foot), assembled in the tibia frame.

Files: the individual ``Geometry/*_rv(s).vtp`` bones of opensim-models (metres, triangles),
plus the Hamner et al. (2010) model ``FullBodyModel_Hamner2010_v2_0.osim``, whose joints
place the bodies: talus_r in tibia_r (ankle_r), calcn_r in talus_r (subtalar_r), toes_r in
calcn_r (mtp_r). The osim attaches the lumped ``foot.vtp`` to calcn_r and ``bofoot.vtp`` to
toes_r, not the individual bones; :data:`BONES` puts each individual bone in the body whose
lumped mesh covers it (talus_rv in talus_r, the tarsals and metatarsals in calcn_r, the
phalanges in toes_r), which :func:`check_bodies` verifies. The chain is evaluated at the
default pose (every coordinate at its default value, 0) by :func:`body_transforms`, from the
osim file itself (offset frames' translation and body-fixed XYZ orientation, the custom
joints' spatial transforms).

Repair: distal_phalanx2_rvs has two zero-volume fins (a triangle and its reverse, glued
to an edge of the closed surface, making two non-manifold edges); :func:`read_vtp` drops
such pairs, which leaves every bone closed and manifold.

Rigid groups (:data:`GROUPS`), 11 bodies: tibia + fibula; talus; calcaneus; navicular;
cuboid; the medial cuneiform alone (tibialis anterior inserts on it and on the base of the
first metatarsal); the intermediate and lateral cuneiforms together (stiff, ligament-bound
joints); metatarsal 1 (the other half of the tibialis anterior insertion, and the mobile
first ray); metatarsals 2-5 (held by the transverse ligaments, little relative motion in
stance); the hallux phalanges; the phalanges of toes 2-5 (each a small chain).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from artifem.errors import InputError, MeshError
from artifem.registration.skeleton import edge_defects

DATA = Path(__file__).resolve().parents[1] / "data" / "opensim-foot"
OSIM = DATA / "FullBodyModel_Hamner2010_v2_0.osim"

#: bone -> (file in DATA, OpenSim body whose frame the file is in).
BONES: dict[str, tuple[str, str]] = {
    "tibia": ("tibia_r.vtp", "tibia_r"),
    "fibula": ("fibula_r.vtp", "tibia_r"),
    "talus": ("talus_rv.vtp", "talus_r"),
    "calcaneus": ("calcaneous_rv.vtp", "calcn_r"),
    "navicular": ("navicular_rv.vtp", "calcn_r"),
    "cuboid": ("cuboid_rv.vtp", "calcn_r"),
    "medial_cuneiform": ("first_cuneiform_rv.vtp", "calcn_r"),
    "intermediate_cuneiform": ("second_cuneiform_rv.vtp", "calcn_r"),
    "lateral_cuneiform": ("third_cuneiform_rv.vtp", "calcn_r"),
    **{f"metatarsal{i}": (f"metatarsal{i}_rv.vtp", "calcn_r") for i in range(1, 6)},
    **{f"prox_phalanx{i}": (f"prox_phalanx{i}_rvs.vtp", "toes_r") for i in range(1, 6)},
    **{f"mid_phalanx{i}": (f"mid_phalanx{i}_rvs.vtp", "toes_r") for i in range(2, 6)},
    **{f"distal_phalanx{i}": (f"distal_phalanx{i}_rvs.vtp", "toes_r") for i in range(1, 6)},
}

#: rigid group -> its bones (module docstring).
GROUPS: dict[str, tuple[str, ...]] = {
    "tibia": ("tibia", "fibula"),
    "talus": ("talus",),
    "calcaneus": ("calcaneus",),
    "navicular": ("navicular",),
    "cuboid": ("cuboid",),
    "medial_cuneiform": ("medial_cuneiform",),
    "lateral_cuneiforms": ("intermediate_cuneiform", "lateral_cuneiform"),
    "metatarsal1": ("metatarsal1",),
    "metatarsals2_5": tuple(f"metatarsal{i}" for i in range(2, 6)),
    "hallux": ("prox_phalanx1", "distal_phalanx1"),
    "toes2_5": tuple(f"{p}_phalanx{i}" for i in range(2, 6) for p in ("prox", "mid", "distal")),
}

#: body -> (joint placing it in its parent, parent body); tibia_r is the root.
CHAIN = {
    "talus_r": ("ankle_r", "tibia_r"),
    "calcn_r": ("subtalar_r", "talus_r"),
    "toes_r": ("mtp_r", "calcn_r"),
}

#: the lumped meshes the osim attaches to the bodies, for :func:`check_bodies`.
LUMPED = {"calcn_r": "foot.vtp", "toes_r": "bofoot.vtp"}


@dataclass(frozen=True)
class Bone:
    """One bone: triangle surface (outward, closed) in the tibia frame, metres."""

    name: str
    group: str
    file: str
    vertices: np.ndarray
    triangles: np.ndarray


def read_vtp(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) of a VTK PolyData file, polygons triangulated, pairs of a
    triangle and its reverse (zero-volume fins) dropped, unused vertices removed."""
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    if not Path(path).is_file():
        raise MeshError(f"bone mesh file {path} does not exist")
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(str(path))
    tri = vtk.vtkTriangleFilter()
    tri.SetInputConnection(reader.GetOutputPort())
    tri.Update()
    poly = tri.GetOutput()
    if poly.GetNumberOfPolys() == 0:
        raise MeshError(f"bone mesh file {path} has no triangles")
    v = vtk_to_numpy(poly.GetPoints().GetData()).astype(float)
    f = vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).reshape(-1, 3).astype(np.int64)
    key = np.sort(f, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    f = f[counts[inverse.ravel()] == 1]
    used, f = np.unique(f, return_inverse=True)
    return v[used], f.reshape(-1, 3)


def signed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Volume enclosed by a closed surface, positive if it is outward oriented."""
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _rotation(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _frame(translation, orientation) -> np.ndarray:
    """4x4 of an OpenSim offset frame: body-fixed X-Y-Z rotation, then translation."""
    m = np.eye(4)
    m[:3, :3] = (
        _rotation([1, 0, 0], orientation[0])
        @ _rotation([0, 1, 0], orientation[1])
        @ _rotation([0, 0, 1], orientation[2])
    )
    m[:3, 3] = translation
    return m


def _vec(node, tag: str) -> np.ndarray:
    return np.array(node.find(tag).text.split(), float)


def _function_value(axis_node, coords: dict[str, float], joint: str) -> float:
    names = (axis_node.findtext("coordinates") or "").split()
    q = coords[names[0]] if names else 0.0
    for child in axis_node:
        if child.tag == "Constant":
            return float(child.findtext("value"))
        if child.tag == "LinearFunction":
            a, b = _vec(child, "coefficients")
            return a * q + b
        if child.tag not in ("coordinates", "axis"):
            raise InputError(
                f"joint {joint}: transform axis {axis_node.get('name')} has a "
                f"{child.tag}, only Constant and LinearFunction are read"
            )
    raise InputError(f"joint {joint}: transform axis {axis_node.get('name')} has no function")


def joint_frames(osim: Path = OSIM) -> dict[str, dict]:
    """The ankle_r, subtalar_r and mtp_r joints of the osim file: parent and child offset
    frames (body, translation, orientation), the spatial transform at the default pose and
    ``axis``, the axis of the first rotation driven by a coordinate (parent offset frame)."""
    root = ET.parse(osim).getroot()
    out = {}
    for joint_name, _ in CHAIN.values():
        joint = next(
            (j for j in root.iter() if j.get("name") == joint_name and j.tag.endswith("Joint")),
            None,
        )
        if joint is None:
            raise InputError(f"{osim}: no joint {joint_name!r}")
        frames = {f.get("name"): f for f in joint.find("frames")}
        info = {"type": joint.tag}
        for role in ("parent", "child"):
            f = frames[joint.findtext(f"socket_{role}_frame")]
            info[role] = {
                "body": f.findtext("socket_parent").rsplit("/", 1)[-1],
                "translation": _vec(f, "translation"),
                "orientation": _vec(f, "orientation"),
            }
        coords = {
            c.get("name"): float(c.findtext("default_value")) for c in joint.find("coordinates")
        }
        m = np.eye(4)
        spatial = joint.find("SpatialTransform")
        if spatial is not None:
            for axis in spatial:
                value = _function_value(axis, coords, joint_name)
                if (
                    axis.get("name").startswith("rotation")
                    and "axis" not in info
                    and (axis.findtext("coordinates") or "").strip()
                ):
                    info["axis"] = _vec(axis, "axis")  # the coordinate's hinge axis
                if axis.get("name").startswith("rotation"):
                    m[:3, :3] = m[:3, :3] @ _rotation(_vec(axis, "axis"), value)
                else:
                    m[:3, 3] += value * _vec(axis, "axis")
        info["spatial"], info["coordinates"] = m, coords
        out[joint_name] = info
    return out


def body_transforms(osim: Path = OSIM) -> dict[str, np.ndarray]:
    """body -> 4x4 map from the body frame to the tibia_r frame, at the default pose:
    X_parent = P_offset S(q) C_offset^-1 chained from tibia_r down to toes_r."""
    joints = joint_frames(osim)
    out = {"tibia_r": np.eye(4)}
    for body, (joint_name, parent) in CHAIN.items():
        j = joints[joint_name]
        if j["parent"]["body"] != parent or j["child"]["body"] != body:
            raise InputError(
                f"{osim}: joint {joint_name} connects {j['parent']['body']} -> "
                f"{j['child']['body']}, expected {parent} -> {body}"
            )
        p = _frame(j["parent"]["translation"], j["parent"]["orientation"])
        c = _frame(j["child"]["translation"], j["child"]["orientation"])
        out[body] = out[parent] @ p @ j["spatial"] @ np.linalg.inv(c)
    return out


def body_meshes(osim: Path = OSIM) -> dict[str, list[str]]:
    """body -> the mesh files the osim attaches to it."""
    root = ET.parse(osim).getroot()
    return {b.get("name"): [m.text.strip() for m in b.iter("mesh_file")] for b in root.iter("Body")}


def check_bodies(osim: Path = OSIM, data: Path = DATA) -> None:
    """The osim attaches tibia_r.vtp + fibula_r.vtp to tibia_r and talus_rv.vtp to talus_r,
    and the centre of each calcn_r / toes_r bone of :data:`BONES` lies in the bounding box
    of the lumped mesh the osim attaches to that body; else :class:`InputError`."""
    meshes = body_meshes(osim)
    for name, (file, body) in BONES.items():
        if body in LUMPED:
            if LUMPED[body] not in meshes.get(body, []):
                raise InputError(f"{osim}: body {body} does not carry {LUMPED[body]}")
            lumped = read_vtp(data / LUMPED[body])[0]
            v = read_vtp(data / file)[0]
            centre = 0.5 * (v.min(0) + v.max(0))
            if (centre < lumped.min(0)).any() or (centre > lumped.max(0)).any():
                raise InputError(
                    f"bone {name} ({file}) is not inside {LUMPED[body]}'s box: "
                    f"it is not in the frame of body {body}"
                )
        elif file not in meshes.get(body, []):
            raise InputError(f"{osim}: body {body} does not carry {file} (bone {name})")


def check_closed(name: str, vertices: np.ndarray, triangles: np.ndarray) -> None:
    """A surface must be closed, manifold and outward; else :class:`MeshError` naming it."""
    boundary, nonmanifold = edge_defects(triangles)
    if boundary or nonmanifold:
        raise MeshError(
            f"{name} is not closed: {boundary} boundary edge(s), {nonmanifold} non-manifold edge(s)"
        )
    if signed_volume(vertices, triangles) <= 0:
        raise MeshError(f"{name} is inward oriented (signed volume <= 0)")


def check_units(bones: list[Bone]) -> None:
    """The assembled foot must measure 1 cm to 1 m (metres); else :class:`InputError`
    naming the largest / smallest bone."""
    v = np.vstack([b.vertices for b in bones])
    size = float(np.max(v.max(0) - v.min(0)))
    extents = [float(np.max(b.vertices.max(0) - b.vertices.min(0))) for b in bones]
    if size > 1.0:
        worst = bones[int(np.argmax(extents))]
        raise InputError(
            f"the foot's bones span {size:.4g} m (> 1 m): units off, mm instead "
            f"of m? (largest: bone {worst.name}, {worst.file}, {max(extents):.4g})"
        )
    if size < 0.01:
        worst = bones[int(np.argmin(extents))]
        raise InputError(
            f"the foot's bones span {size:.4g} m (< 1 cm): units off? "
            f"(smallest: bone {worst.name}, {worst.file}, {min(extents):.4g})"
        )


def load_bones(data: Path = DATA, osim: Path = OSIM) -> list[Bone]:
    """Every bone of :data:`BONES`, read, checked (:func:`check_closed`) and moved to the
    tibia frame by :func:`body_transforms`."""
    transforms = body_transforms(osim)
    group_of = {b: g for g, members in GROUPS.items() for b in members}
    bones = []
    for name, (file, body) in BONES.items():
        v, f = read_vtp(Path(data) / file)
        check_closed(f"bone {name} ({file})", v, f)
        m = transforms[body]
        bones.append(Bone(name, group_of[name], file, v @ m[:3, :3].T + m[:3, 3], f))
    return bones


def penetrations(bones: list[Bone]) -> list[tuple[str, str, float]]:
    """(bone, bone, depth) for each pair of bones of different groups where vertices of one
    lie inside the other (winding number > 1/2): depth is the deepest such vertex's
    distance to the other's surface."""
    import igl

    out = []
    for i, a in enumerate(bones):
        for b in bones[i + 1 :]:
            if a.group == b.group or not _boxes_overlap(a.vertices, b.vertices):
                continue
            depth = 0.0
            for p, q in ((a, b), (b, a)):
                w = igl.winding_number(q.vertices, q.triangles, p.vertices)
                inside = p.vertices[w > 0.5]
                if len(inside):
                    d = igl.point_mesh_squared_distance(inside, q.vertices, q.triangles)[0]
                    depth = max(depth, float(np.sqrt(d.max())))
            if depth > 0:
                out.append((a.name, b.name, depth))
    return out


def _boxes_overlap(u: np.ndarray, v: np.ndarray) -> bool:
    return bool(np.all(u.min(0) <= v.max(0)) and np.all(v.min(0) <= u.max(0)))


def surface_gap(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> float:
    """The smallest vertex-to-surface distance between two (vertices, triangles) surfaces,
    both ways (an upper bound of the true surface gap)."""
    import igl

    return min(
        float(np.sqrt(igl.point_mesh_squared_distance(p[0], q[0], q[1])[0].min()))
        for p, q in ((a, b), (b, a))
    )


def min_gaps(bones: list[Bone]) -> dict[tuple[str, str], float]:
    """(group, group) -> :func:`surface_gap` between their bones, for the pairs of groups
    closer than 1 cm."""
    out: dict[tuple[str, str], float] = {}
    for i, a in enumerate(bones):
        for b in bones[i + 1 :]:
            if a.group == b.group:
                continue
            d = surface_gap((a.vertices, a.triangles), (b.vertices, b.triangles))
            key = tuple(sorted((a.group, b.group)))
            if d < 0.01:
                out[key] = min(out.get(key, np.inf), float(d))
    return out
