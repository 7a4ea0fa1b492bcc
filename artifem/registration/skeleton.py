"""A reference skeleton for registration and the scenes that fit it (Sanchez et al. 2015;
the seed paper's section 3.2, Fig. 12).

A :class:`Skeleton` is bones (closed, outward triangle surfaces in one frame, metres)
and revolute joints between them (a centre on the hinge axis, the axis, optional limits
on the angle), a tree: each bone but the root is the child of one joint. It reads and
writes a directory: ``skeleton.json`` (units, the bones' mesh files, the joints) beside
the meshes (any format pyvista reads; written as VTP, which keeps the vertex order).

:func:`jointed_scene` embeds each bone in its own voxel FEM grid
(:class:`~artifem.embedding.voxel_fem.VoxelFemBody`, cubic cells of ``cell_size``) and
joins the grids at the joints: on each of the two grids a Procrustes frame fitted to
its nodes within ``reach`` of the joint centre carries a marker, and a RevoluteJoint
between the markers at the centre (its z the hinge axis) keeps the two frames on one
axis, with the angle's limits as unilateral rows; the bones' surfaces ride the grids
as SkinMeshes, which the registration forces pull. :func:`single_structure_scene` is
the baseline without joints (the seed paper's argument): every bone in one grid
around their union, so each joint is a region of one elastic body.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from artifem.embedding.voxel_fem import VoxelFemBody, enclosed_volume
from artifem.errors import InputError, MeshError
from artifem.multibody.attachments import FrameAttachment
from artifem.multibody.frame_attachments import FemFrame
from artifem.multibody.joints import RevoluteJoint, axis_rotation
from artifem.multibody.rigid_body import RigidBody
from artifem.multibody.skin import SkinMesh
from artifem.registration.rigid import TriangleSurface
from artifem.scene import Scene

__all__ = [
    "Hinge",
    "Skeleton",
    "SkeletonScene",
    "jointed_scene",
    "read_surface",
    "single_structure_scene",
    "UNITS",
]

#: metres per unit of the names a skeleton.json or target.json may give
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def read_surface(path: Path, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) of a surface file (pyvista: STL, VTP, VTK, OBJ, PLY), polygons
    triangulated and coincident points merged, times ``scale``."""
    import pyvista as pv

    path = Path(path)
    if not path.is_file():
        raise InputError(f"surface file {path} does not exist")
    mesh = pv.read(path)
    if not isinstance(mesh, pv.PolyData):
        mesh = mesh.extract_surface()
    mesh = mesh.triangulate().clean(tolerance=0.0)
    if not mesh.n_cells:
        raise MeshError(f"surface file {path} has no triangles")
    return scale * np.asarray(mesh.points, dtype=float), np.asarray(mesh.faces).reshape(-1, 4)[
        :, 1:
    ].astype(np.int64)


def write_surface(path: Path, vertices, triangles) -> None:
    """Write a triangle surface (STL, VTP, ...: by the suffix) with pyvista."""
    import pyvista as pv

    T = np.asarray(triangles, dtype=np.int64)
    pv.PolyData(np.asarray(vertices, float), np.c_[np.full(len(T), 3), T].ravel()).save(path)


def edge_defects(triangles: np.ndarray) -> tuple[int, int]:
    """(boundary edges, non-manifold edges) of a triangle surface: edges of one triangle,
    edges of more than two."""
    e = np.sort(np.asarray(triangles)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    counts = np.unique(e, axis=0, return_counts=True)[1]
    return int(np.sum(counts == 1)), int(np.sum(counts > 2))


@dataclass(frozen=True)
class Hinge:
    """A revolute joint of a skeleton: ``child`` turns about ``axis`` (unit) through
    ``centre`` relative to ``parent`` by the angle (rad, right-handed about the axis; 0 in
    the reference), within ``limits`` (lower, upper) if given."""

    name: str
    parent: str
    child: str
    centre: np.ndarray
    axis: np.ndarray
    limits: tuple[float, float] | None = None

    def rotation(self, angle: float) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) of x -> R x + t, the turn by ``angle`` about the hinge."""
        R = Rotation.from_rotvec(angle * self.frame_rotation()[:, 2]).as_matrix()
        return R, self.centre - R @ self.centre

    def frame_rotation(self) -> np.ndarray:
        """A rotation whose z column is the axis (the joint frame of RevoluteJoint)."""
        return axis_rotation(self.axis)


@dataclass
class Skeleton:
    """Bones (name -> (vertices (n, 3) m, triangles (m, 3))) and hinges (module docstring)."""

    bones: dict[str, tuple[np.ndarray, np.ndarray]]
    hinges: list[Hinge] = field(default_factory=list)

    def __post_init__(self):
        names = set(self.bones)
        children = [h.child for h in self.hinges]
        for h in self.hinges:
            for bone in (h.parent, h.child):
                if bone not in names:
                    raise InputError(f"joint {h.name!r}: no bone {bone!r} (bones: {sorted(names)})")
            if not np.linalg.norm(h.axis) > 0 or np.asarray(h.centre).shape != (3,):
                raise InputError(
                    f"joint {h.name!r}: its centre must be 3 numbers and its "
                    f"axis a nonzero 3-vector"
                )
        if len(set(children)) != len(children):
            raise InputError(f"a bone is the child of two joints: {children}")
        if len(self.roots()) != 1 and self.hinges:
            raise InputError(
                f"the joints do not join the bones into one tree: roots {self.roots()}"
            )

    def roots(self) -> list[str]:
        """The bones that are no joint's child."""
        children = {h.child for h in self.hinges}
        return [b for b in self.bones if b not in children]

    def hinge(self, name: str) -> Hinge:
        return next(h for h in self.hinges if h.name == name)

    def check(self, reach: float) -> None:
        """Every bone closed, manifold and outward; every joint centre within ``reach`` of
        both its bones; else :class:`MeshError` / :class:`InputError` naming them."""
        for name, (V, T) in self.bones.items():
            boundary, nonmanifold = edge_defects(T)
            if boundary or nonmanifold:
                raise MeshError(
                    f"bone {name!r} is not a closed surface: {boundary} boundary "
                    f"edge(s), {nonmanifold} non-manifold edge(s)"
                )
            if not enclosed_volume(V, T) > 0:
                raise MeshError(
                    f"bone {name!r} is inward oriented (enclosed volume <= 0): flip its triangles"
                )
        for h in self.hinges:
            for bone in (h.parent, h.child):
                d = float(TriangleSurface(*self.bones[bone]).closest(h.centre)[0][0])
                if d > reach:
                    raise InputError(
                        f"joint {h.name!r}: its centre {np.round(h.centre, 4)} "
                        f"is {d:.4g} m from bone {bone!r}, farther than the "
                        f"frames' reach {reach:.4g} m"
                    )

    def transforms(self, angles: dict[str, float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """bone -> (R, t): each bone turned by the given joint angles (others 0) about its
        chain of hinges from the root (the hinges as in the reference)."""
        out = {b: (np.eye(3), np.zeros(3)) for b in self.roots()}
        pending = list(self.hinges)
        while pending:
            h = next(h for h in pending if h.parent in out)
            pending.remove(h)
            Rp, tp = out[h.parent]
            R, t = h.rotation(float(angles.get(h.name, 0.0)))
            out[h.child] = (Rp @ R, Rp @ t + tp)
        return out

    def posed(self, angles: dict[str, float]) -> dict[str, np.ndarray]:
        """bone -> its vertices at the given joint angles (:meth:`transforms`)."""
        return {b: self.bones[b][0] @ R.T + t for b, (R, t) in self.transforms(angles).items()}

    def moved(self, R, t) -> Skeleton:
        """The skeleton moved rigidly by x -> R x + t (bones, centres and axes)."""
        R, t = np.asarray(R, float), np.asarray(t, float)
        return Skeleton(
            {b: (V @ R.T + t, T) for b, (V, T) in self.bones.items()},
            [replace(h, centre=R @ h.centre + t, axis=R @ h.axis) for h in self.hinges],
        )

    @classmethod
    def read(cls, directory: Path) -> Skeleton:
        """The skeleton of ``directory/skeleton.json``: {"units": "m" | "cm" | "mm",
        "bones": {name: file}, "joints": [{"name", "parent", "child", "centre",
        "axis", "limits" (degrees, optional)}]} (centres in the units)."""
        directory = Path(directory)
        spec = _read_json(directory / "skeleton.json")
        scale = _units(spec, directory / "skeleton.json")
        bones = {
            name: read_surface(directory / file, scale)
            for name, file in dict(spec.get("bones", {})).items()
        }
        if not bones:
            raise InputError(f"{directory / 'skeleton.json'}: no bones")
        hinges = []
        for j in spec.get("joints", []):
            try:
                limits = (
                    None
                    if j.get("limits") is None
                    else tuple(np.radians(np.asarray(j["limits"], float)).tolist())
                )
                hinges.append(
                    Hinge(
                        str(j["name"]),
                        str(j["parent"]),
                        str(j["child"]),
                        scale * np.asarray(j["centre"], float),
                        np.asarray(j["axis"], float),
                        limits,
                    )
                )
            except (KeyError, TypeError, ValueError) as e:
                raise InputError(
                    f"{directory / 'skeleton.json'}: joint {j!r} needs name, "
                    f"parent, child, centre and axis ({e})"
                ) from None
        return cls(bones, hinges)

    def write(self, directory: Path) -> None:
        """``directory/skeleton.json`` (metres, limits in degrees) and one VTP per bone."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        for name, (V, T) in self.bones.items():
            write_surface(directory / f"{name}.vtp", V, T)
        spec = {
            "units": "m",
            "bones": {name: f"{name}.vtp" for name in self.bones},
            "joints": [
                {
                    "name": h.name,
                    "parent": h.parent,
                    "child": h.child,
                    "centre": np.asarray(h.centre).tolist(),
                    "axis": np.asarray(h.axis).tolist(),
                    "limits": None if h.limits is None else np.degrees(h.limits).tolist(),
                }
                for h in self.hinges
            ],
        }
        (directory / "skeleton.json").write_text(json.dumps(spec, indent=1))


def _read_json(path: Path) -> dict:
    if not path.is_file():
        raise InputError(f"{path} does not exist")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise InputError(f"{path} is not valid JSON: {e}") from None


def _units(spec: dict, path: Path) -> float:
    units = spec.get("units")
    if units not in UNITS:
        raise InputError(f"{path}: units must be one of {sorted(UNITS)}, got {units!r}")
    return UNITS[units]


@dataclass
class SkeletonScene:
    """A scene built from a skeleton: its FEM bodies, each bone's SkinMesh, and the
    RevoluteJoints by hinge name (none in the single structure)."""

    scene: Scene
    bodies: list
    skins: dict[str, SkinMesh]
    joints: dict[str, RevoluteJoint]

    def angles(self) -> dict[str, float]:
        """The joints' angles (rad): the child's turn about the hinge relative to its
        parent, 0 in the reference."""
        return {name: joint.angle() for name, joint in self.joints.items()}

    def min_det_F(self) -> float:
        """The smallest det F over every grid (<= 0: an element inverted)."""
        return min(body.inverted_elements()[1] for body in self.bodies)


def _grid(vertices, triangles, material, cell_size: float, name: str) -> VoxelFemBody:
    return VoxelFemBody(vertices, triangles, material, 1000.0, cell_size=cell_size, name=name)


def jointed_scene(
    skeleton: Skeleton, material, cell_size: float, *, reach: float | None = None
) -> SkeletonScene:
    """Each bone in its own voxel grid, the grids joined by the hinges (module docstring);
    ``reach`` (default 4 cells) bounds the distance from a joint centre to the grid nodes
    that carry its frames. No gravity."""
    reach = 4.0 * cell_size if reach is None else float(reach)
    skeleton.check(reach)
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    bodies, skins, joints = {}, {}, {}
    for name, (V, T) in skeleton.bones.items():
        bodies[name] = _grid(V, T, material, cell_size, name)
        skins[name] = SkinMesh(V, T, masters=[bodies[name]], name=name)
        scene.add(bodies[name])
    for h in skeleton.hinges:
        markers = []
        for bone in (h.child, h.parent):
            body = bodies[bone]
            nodes = body.find_nodes(lambda x, c=h.centre: np.linalg.norm(x.T - c, axis=1) <= reach)
            if len(nodes) < 4:
                raise InputError(
                    f"joint {h.name!r}: {len(nodes)} node(s) of bone {bone!r}'s "
                    f"grid within {reach:.4g} m of its centre, 4 needed: the "
                    f"centre is outside the bone, or reach too small"
                )
            frame = FemFrame(body, method="procrustes", support=nodes)
            marker = RigidBody.marker(f"{h.name} on {bone}", position=frame.position())
            scene.add(marker, FrameAttachment(marker, frame))
            markers.append(marker)
        joints[h.name] = RevoluteJoint.at_world(
            *markers, h.centre, h.frame_rotation(), name=h.name, limits=h.limits
        )
        scene.add(joints[h.name])
    return SkeletonScene(scene, list(bodies.values()), skins, joints)


def single_structure_scene(skeleton: Skeleton, material, cell_size: float) -> SkeletonScene:
    """Every bone in one voxel grid around their union, no joints (module docstring)."""
    skeleton.check(np.inf)
    names = list(skeleton.bones)
    offsets = np.cumsum([0] + [len(skeleton.bones[b][0]) for b in names])
    V = np.vstack([skeleton.bones[b][0] for b in names])
    T = np.vstack([skeleton.bones[b][1] + o for b, o in zip(names, offsets)])
    body = _grid(V, T, material, cell_size, "skeleton")
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add(body)
    skins = {}
    for name in names:
        skins[name] = SkinMesh(*skeleton.bones[name], masters=[body], name=name)
    return SkeletonScene(scene, [body], skins, {})
