"""Jaw and tongue: the level-0 tongue hanging from a rigid, hinged, muscle-driven jaw.

Scene (issue 5, "Jaw and tongue")
---------------------------------
- Tongue: the ArtiSynth hex tongue of :mod:`artifem.models.tongue.model`
  (level 0, same Mooney-Rivlin material, the element-wise incompressibility penalty
  :data:`~artifem.models.tongue.model.PENALTY` rather than the tongue's default hard
  constraint, because the reduced jaw-tongue's training has no reduced pressure space
  yet (issue 15's reductor will give it one), Rayleigh
  damping and 21 Blemker muscle bundles, built by ``Tongue`` itself) but only
  its *hyoid* attachment nodes (hyoidAttachments.txt, 56 nodes) are fixed; its
  59 *jaw* attachment nodes (jawAttachments.txt, ArtiSynth 0-based node rows)
  are carried by the jaw through a :class:`NodeAttachment` (x_i = p + R r_i).
- Jaw: a rigid body from ArtiSynth's jaw.obj (mm, its own frame), aligned to
  the tongue (below), closed (its 288 boundary edges form holes that are
  capped by fans around their centroids) and given bone density
  1900 kg/m^3 (:meth:`RigidBody.from_surface`).
- Temporomandibular joint: a :class:`RevoluteJoint` between the jaw and the
  fixed skull (the world) about the left-right axis through the two condyle
  centres (the centroids of the jaw.obj vertices of each condylar head), with
  the angle limited to [0, 0.5] rad: 0 is the closed (rest) pose, positive
  opens the mouth (chin down and back).
- Jaw closer: a pre-tensioned :class:`AxialSpring` (masseter-like) from a
  fixed zygomatic point to the jaw's gonial angle that holds the jaw on its
  closed limit against gravity and the tongue's weight.
- Jaw opener: a Thelen 2003 :class:`ThelenMuscle` (digastric-like, rigid
  tendon) from a fixed point below the hyoid to the chin, through a
  :class:`FramePath`, its excitation ramped by a schedule.
- Gravity (0, 0, -9.81) on everything (the tongue frame has z up, x posterior,
  y left-right).

Alignment of jaw.obj
--------------------
jaw.obj has x anterior, y up, z left-right (mm); the tongue has x posterior,
y left-right, z up (m). The axis permutation (x, y, z)_jaw -> (-x, z, y)_tongue
(a proper rotation) and the scale 1e-3 bring it to the tongue's axes; the
translation and a residual rotation come from point-to-surface ICP of the
tongue's 59 jaw-attachment nodes against the jaw surface (each iteration: the
nearest surface point of each node, then the Procrustes/Kabsch rigid fit),
started from a grid of translations and keeping the start with the smallest
mean distance. :func:`align_jaw` returns the transform and the node-to-surface
distances of the result (mean / max, in the JSON).

Measured (level 0): node-to-surface distance mean 1.19 mm, max 4.86 mm, after
a residual rotation of 5.4 degrees; one flipped triangle of jaw.obj is
reversed and 14 holes are capped, giving a closed surface of 0.116 kg. The fit
is a best fit of two meshes from different sources, not a registration: the
tongue tip at rest lies about 17 mm anterior of the jaw's most anterior point.
The closer's 3 N pre-tension does not quite hold the jaw against gravity and
the tongue's weight: with the opener off the jaw sags 0.23 degrees in 0.2 s.
With the opener ramped to 0.5 over 0.2 s during protrusion the jaw opens to
8.3 degrees (0.6 s run, dt = 0.01 s, about 80-125 ms per step on a loaded
machine, 2499 masters, one MUMPS LU per step).

Run ``artifem simulate jaw-tongue --out DIR [--case M] [--duration T]``
(:mod:`artifem.models.runner`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from mpi4py import MPI

from artifem.errors import InputError, UnknownNameError
from artifem.excitation import ExcitationSchedule
from artifem.models.jaw_tongue.render import render
from artifem.models.runner import Built, Model, command
from artifem.models.tongue.model import (
    DATA,
    PENALTY,
    Tongue,
    TongueConfig,
    load_tongue_data,
)
from artifem.multibody.attachments import FemPoint, LiftAttachment, NodeAttachment
from artifem.scene import Scene
from artifem.multibody.frame_paths import FramePath
from artifem.multibody.joints import FixedJoint, RevoluteJoint, axis_rotation
from artifem.multibody.muscles import AxialSpring, ThelenMuscle, ThelenParameters
from artifem.multibody.point_attachments import FemPointWeights
from artifem.multibody.rigid_body import Frame, RigidBody
from artifem.reduction.reduced_body import ReducedFemBody
from artifem.registration import TriangleSurface, icp

__all__ = [
    "JawTongueConfig",
    "JawTongueScene",
    "align_jaw",
    "build_scene",
    "jaw_attachment_rows",
    "hyoid_attachment_rows",
    "read_obj",
    "close_surface",
    "records",
    "MODEL",
]

#: jaw.obj axes -> tongue axes: (x, y, z)_jaw -> (-x, z, y)_tongue (det +1).
AXES = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])


@dataclass(frozen=True)
class JawTongueConfig:
    bone_density: float = 1900.0
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    #: hinge angle limits (rad): closed at 0, opening positive.
    limits: tuple[float, float] = (0.0, 0.5)
    #: opener (digastric-like) Thelen muscle.
    opener_force: float = 40.0
    opener_excitation: float = 0.5
    opener_ramp: float = 0.2
    #: closer spring: stiffness (N/m), pre-tension at the closed pose (N), damping (N s/m).
    closer_stiffness: float = 400.0
    closer_pretension: float = 3.0
    closer_damping: float = 2.0
    #: "hinge" (revolute + limits), "welded" (FixedJoint to the skull).
    joint: str = "hinge"
    tongue: TongueConfig = TongueConfig(level=0, incompressibility=PENALTY, linear_solver="mumps")


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and triangles (m, 3), 0-based, of a triangle OBJ file."""
    vertices, faces = [], []
    for line in Path(path).read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            vertices.append([float(v) for v in parts[1:4]])
        elif parts[0] == "f":
            face = [int(p.split("/")[0]) - 1 for p in parts[1:]]
            if len(face) != 3:
                raise InputError(f"{path}: only triangles are supported, got {line!r}")
            faces.append(face)
    return np.array(vertices), np.array(faces, dtype=np.int64)


def close_surface(vertices: np.ndarray, triangles: np.ndarray):
    """Reverse triangles oriented against all their neighbours, then cap every hole (loop of
    boundary edges) with a fan around its centroid, oriented consistently with the surface.
    Returns (vertices, triangles, number of holes, number of flipped triangles)."""
    triangles = np.array(triangles, dtype=np.int64)
    directed = {}
    for tri in triangles:
        for k in range(3):
            key = (int(tri[k]), int(tri[(k + 1) % 3]))
            directed[key] = directed.get(key, 0) + 1
    # a triangle whose three edges all run the same way as a neighbour's is flipped
    # (jaw.obj has one: 1949 1964 1894): reverse it.
    flipped = [
        i
        for i, tri in enumerate(triangles)
        if all(directed[(int(tri[k]), int(tri[(k + 1) % 3]))] > 1 for k in range(3))
    ]
    triangles[flipped] = triangles[flipped][:, ::-1]
    edges = {}
    for tri in triangles:
        for k in range(3):
            a, b = int(tri[k]), int(tri[(k + 1) % 3])
            edges[(a, b)] = edges.get((a, b), 0) + 1
    # a boundary edge a->b has no opposite b->a; the cap must contain b->a.
    nxt = {}
    for a, b in edges:
        if (b, a) not in edges:
            if b in nxt:
                raise InputError("close_surface: a boundary vertex with two outgoing edges")
            nxt[b] = a  # cap edge b -> a
    vertices, triangles = list(vertices), list(triangles)
    holes = 0
    while nxt:
        start = next(iter(nxt))
        loop = [start]
        while True:
            following = nxt.pop(loop[-1])
            if following == start:
                break
            loop.append(following)
        c = len(vertices)
        vertices.append(np.mean([vertices[i] for i in loop], axis=0))
        for i, j in zip(loop, loop[1:] + loop[:1]):
            triangles.append([i, j, c])
        holes += 1
    return np.array(vertices), np.array(triangles, dtype=np.int64), holes, len(flipped)


def jaw_attachment_rows() -> np.ndarray:
    return np.loadtxt(DATA / "jawAttachments.txt", dtype=np.int64).ravel()


def hyoid_attachment_rows() -> np.ndarray:
    return np.loadtxt(DATA / "hyoidAttachments.txt", dtype=np.int64).ravel()


def align_jaw(
    nodes: np.ndarray, vertices_mm: np.ndarray, triangles: np.ndarray, iterations: int = 60
) -> dict:
    """Rigid transform x_tongue = R x_jaw_m + t (x_jaw_m = 1e-3 x_obj) that puts the jaw
    surface through the tongue's jaw-attachment ``nodes`` (m): the axis permutation AXES,
    then point-to-surface ICP (:func:`artifem.registration.icp`) from a grid of starting
    translations, the fit of the smallest mean distance kept (module docstring). Returns
    the transform, the residual rotation and the distances of the nodes to the aligned
    surface."""
    base = 1e-3 * vertices_mm @ AXES.T
    surface = TriangleSurface(base, triangles)
    best = None
    lo, hi = base.min(0), base.max(0)
    centroid = nodes.mean(0)
    # starts: the node centroid placed at a grid of points of the jaw's bounding box.
    for fx in np.linspace(0.1, 0.6, 6):
        for fz in np.linspace(0.0, 0.6, 7):
            target = np.array(
                [lo[0] + fx * (hi[0] - lo[0]), 0.5 * (lo[1] + hi[1]), lo[2] + fz * (hi[2] - lo[2])]
            )
            # the jaw mesh's open border keeps its pairs: the documented scenes were
            # aligned so
            fit = icp(
                nodes,
                surface,
                np.eye(3),
                target - centroid,
                iterations=iterations,
                drop_border=False,
            )
            if best is None or fit.score < best.score:
                best = fit
    fit = best
    # the nodes moved by (R, t) onto the surface: the surface moves by the inverse.
    R_inv = fit.R.T
    t_inv = -R_inv @ fit.t
    rotation = R_inv @ AXES * 1e-3  # x_tongue = rotation x_obj + t
    dist, _ = TriangleSurface(base @ R_inv.T + t_inv, triangles).closest(nodes)
    residual = np.degrees(np.arccos(np.clip((np.trace(R_inv) - 1) / 2, -1, 1)))
    return {
        "linear": rotation,
        "translation": t_inv,
        "distances": dist,
        "mean_distance": float(dist.mean()),
        "max_distance": float(dist.max()),
        "residual_rotation_deg": float(residual),
    }


def _condyle_centres(vertices: np.ndarray) -> np.ndarray:
    """Centroids (2, 3) of the condylar heads of the aligned jaw (tongue frame, z up, y LR):
    the vertices within 8 mm of the jaw's top, split by the sign of y."""
    top = vertices[:, 2] > vertices[:, 2].max() - 0.008
    pts = vertices[top]
    return np.array([pts[pts[:, 1] < 0].mean(0), pts[pts[:, 1] > 0].mean(0)])


@dataclass
class JawTongueScene:
    scene: Scene
    tongue: Tongue
    jaw: RigidBody
    attachment: NodeAttachment | LiftAttachment
    joint: object
    opener: FramePath | None
    closer: FramePath | None
    alignment: dict
    jaw_rows: np.ndarray
    hinge: np.ndarray  # hinge centre (world)
    reduced: ReducedFemBody | None = None

    def tongue_displacement(self) -> np.ndarray:
        """The tongue's nodal displacement (block-interleaved; O(n r) for a reduced one)."""
        if self.reduced is not None:
            return self.reduced.nodal_displacement()
        return self.tongue.body.u.x.array.copy()

    def opening_angle(self) -> float:
        return float(self.joint.angle()) if isinstance(self.joint, RevoluteJoint) else 0.0


def build_scene(
    config: JawTongueConfig = JawTongueConfig(),
    *,
    opener_schedule=None,
    data=None,
    reduce=None,
    comm=MPI.COMM_WORLD,
) -> JawTongueScene:
    """The tongue, the aligned jaw, the TMJ hinge, the opener and the closer (docstring).

    ``reduce``, a reduced model of this scene (``ReducedModel`` of
    :mod:`artifem.reduction.reductor`, e.g. ``jaw_tongue.reduced.train``), puts the reduced
    tongue in place of the full one, riding on the jaw by a lift attachment. ``comm``: the
    tongue mesh's communicator (``MPI.COMM_SELF``: a serial scene on each rank, as a
    reductor's training runs and :func:`simulate` need; on several ranks the coupled
    island is stepped by the Schur complement of ``artifem.scene.schur_island``).
    """
    data = data or load_tongue_data(config.tongue.level)
    if config.tongue.level != 0:
        raise InputError("jaw_tongue: the attachment files index level-0 nodes")
    jaw_rows, hyoid_rows = jaw_attachment_rows(), hyoid_attachment_rows()
    tongue = Tongue(config.tongue, comm, data=replace(data, fixed_nodes=np.unique(hyoid_rows)))
    nodes = data.mesh.points[jaw_rows]
    vertices_mm, triangles = read_obj(DATA / "jaw.obj")
    alignment = align_jaw(nodes, vertices_mm, triangles)
    closed_mm, closed_tri, holes, flipped = close_surface(vertices_mm, triangles)
    alignment["holes_capped"], alignment["triangles_flipped"] = holes, flipped
    vertices = closed_mm @ alignment["linear"].T + alignment["translation"]
    jaw = RigidBody.from_surface("jaw", vertices, closed_tri, config.bone_density)
    scene = Scene(gravity=config.gravity, integrator=config.tongue.integrator)
    attachment = NodeAttachment(tongue.body, jaw_rows, jaw, name="tongue->jaw")
    scene.add(tongue.body, jaw, attachment)
    condyles = _condyle_centres(vertices)
    hinge = condyles.mean(0)
    axis = condyles[0] - condyles[1]  # +y -> -y: positive angle opens
    if config.joint == "hinge":
        joint = RevoluteJoint.at_world(
            jaw, None, hinge, axis_rotation(axis), name="TMJ", limits=config.limits
        )
    elif config.joint == "welded":
        joint = FixedJoint.at_world(jaw, None, hinge, name="TMJ welded")
    else:
        raise InputError(f"jaw_tongue: joint must be 'hinge' or 'welded', got {config.joint!r}")
    scene.add(joint)
    # chin: the most anterior (min x) jaw vertex near the midline; opener origin below the hyoid.
    mid = vertices[np.abs(vertices[:, 1]) < 0.005]
    chin = mid[np.argmin(mid[:, 0] + 0.5 * (mid[:, 2] - mid[:, 2].min()))]
    chin_insert = chin + np.array([0.008, 0.0, 0.004])  # digastric fossa, inside
    hyoid = data.mesh.points[hyoid_rows].mean(0) + np.array([0.0, 0.0, -0.015])
    opener = closer = None
    if config.opener_force > 0:
        L0 = float(np.linalg.norm(chin_insert - hyoid))
        muscle = ThelenMuscle(ThelenParameters(config.opener_force, L0, 0.0), name="opener")
        schedule = opener_schedule or ExcitationSchedule.ramp_and_hold(
            {"opener": config.opener_excitation}, config.opener_ramp
        )
        opener = FramePath(
            muscle,
            [Frame(None, hyoid), Frame.at_world(jaw, chin_insert)],
            excitation=lambda t, s=schedule: s.at(t)["opener"],
            name="opener",
        )
        scene.add(opener)
    if config.closer_stiffness > 0:
        # gonial angle: the lowest-posterior jaw vertex on each side; zygoma 35 mm above it.
        gonion = vertices[np.argmax(vertices[:, 0] - vertices[:, 2])].copy()
        gonion[0] -= 0.01
        gonion[1] = 0.0  # one midline spring for the two masseters
        zygoma = gonion + np.array([-0.01, 0.0, 0.035])
        length = float(np.linalg.norm(zygoma - gonion))
        rest = length - config.closer_pretension / config.closer_stiffness
        closer = FramePath(
            AxialSpring(config.closer_stiffness, rest, config.closer_damping),
            [Frame(None, zygoma), Frame.at_world(jaw, gonion)],
            name="closer",
        )
        scene.add(closer)
    reduced = None
    if reduce is not None:
        reduced, replaced = reduce.put_in(scene)
        attachment = replaced[attachment.name]
    return JawTongueScene(
        scene, tongue, jaw, attachment, joint, opener, closer, alignment, jaw_rows, hinge, reduced
    )


def records(s: JawTongueScene) -> dict:
    """name -> f(scene), to record while the scene runs: the opening ``angle``, the
    ``tip`` landmark's displacement, the largest ``attachment_error`` and ``joint_error``,
    the jaw nodes' mean vertical motion ``jaw_nodes_dz``, the ``opener_tension``, the tongue
    displacement ``u`` and the jaw pose ``jaw_position``, ``jaw_rotation``."""
    body = s.tongue.body
    dof = int(body.local_dofs([s.tongue.data.landmarks["tip"]])[0])
    tip = FemPoint(
        s.reduced or body,
        FemPointWeights(np.array([dof]), np.ones(1), body.V.tabulate_dof_coordinates()[dof]),
    )
    tip0 = tip.weights.rest_position
    z0 = s.attachment.positions()[:, 2].copy()
    return {
        "angle": lambda scene: s.opening_angle(),
        "tip": lambda scene: tip.position() - tip0,
        "attachment_error": lambda scene: max(scene.attachment_errors().values()),
        "joint_error": lambda scene: max(scene.constraint_errors().values()),
        "jaw_nodes_dz": lambda scene: float((s.attachment.positions()[:, 2] - z0).mean()),
        "opener_tension": lambda scene: s.opener.tension() if s.opener else 0.0,
        "u": lambda scene: s.tongue_displacement(),
        "jaw_position": lambda scene: s.jaw.position.copy(),
        "jaw_rotation": lambda scene: s.jaw.rotation.copy(),
    }


# ---- the runner's jaw-tongue (``artifem simulate jaw-tongue``) ------------------------------


def build(
    case: str, level: int = 0, integrator: str = "semi-implicit", schedule: Path | None = None
) -> Built:
    """The jaw-tongue scene driven by the tongue motion ``case`` ("none": the muscles off,
    the jaw opener only) or the exciter ``schedule`` file, for
    :mod:`artifem.models.runner`; records :func:`records` and draws the tongue with the jaw."""
    config = JawTongueConfig(tongue=replace(JawTongueConfig.tongue, integrator=integrator))
    if schedule is not None:
        motion = ExcitationSchedule.from_file(schedule)
        exciters = load_tongue_data(level).exciters
        unknown = sorted(set(motion.values) - set(exciters))
        if unknown:  # before any work
            raise UnknownNameError(
                f"{schedule}: unknown muscles {unknown}; the tongue's exciters are "
                f"{', '.join(sorted(exciters))}"
            )
    else:
        motion = None if case == "none" else Tongue.motion(case)
    s = build_scene(config)
    if motion is not None:
        s.scene.add_controller(s.tongue.bundle_schedule(motion).controller(s.tongue.body))
    a = s.alignment
    facts = {
        "motion": case if schedule is None else schedule.stem,
        "tongue": {
            "nodes": int(s.tongue.data.mesh.points.shape[0]),
            "jaw_attachment_nodes": int(s.jaw_rows.size),
            "hyoid_fixed_nodes": int(hyoid_attachment_rows().size),
        },
        "jaw": {
            "mass_kg": s.jaw.mass,
            "com_m": s.jaw.position.tolist(),
            "hinge_m": s.hinge.tolist(),
            "limits_rad": list(config.limits),
            "alignment": {
                "method": "axis permutation + mm->m + point-to-surface ICP "
                "(Kabsch) of the jaw-attachment nodes, multi-start",
                "mean_distance_mm": 1e3 * a["mean_distance"],
                "max_distance_mm": 1e3 * a["max_distance"],
                "residual_rotation_deg": a["residual_rotation_deg"],
                "holes_capped": a["holes_capped"],
                "triangles_flipped": a["triangles_flipped"],
            },
        },
    }

    def figures(run) -> dict:
        r = run.records
        angle = np.degrees(r["angle"])
        return {
            "t": run.times.tolist(),
            "opening_angle_deg": angle.tolist(),
            "max_opening_angle_deg": float(angle.max()),
            "tip_displacement_mm": (1e3 * r["tip"]).tolist(),
            "final_tip_displacement_mm": (1e3 * r["tip"][-1]).tolist(),
            "jaw_nodes_mean_dz_mm": (1e3 * r["jaw_nodes_dz"]).tolist(),
            "opener_tension_N": r["opener_tension"].tolist(),
            "max_attachment_error_m": float(r["attachment_error"].max()),
            "max_joint_error": float(r["joint_error"].max()),
        }

    def draw(png, run, shown) -> None:
        r, frames = run.records, []
        for t in shown:
            k = int(np.argmin(abs(run.times - t)))
            title = f"t = {run.times[k]:.2f} s, jaw {np.degrees(r['angle'][k]):.1f} deg"
            frames.append((title, r["u"][k], r["jaw_position"][k], r["jaw_rotation"][k]))
        render(png, s, frames)

    name = None if schedule is None else schedule.stem
    return Built(s.scene, record=records(s), figures=figures, render=draw, facts=facts, name=name)


def _options(group) -> None:
    group.add_argument(
        "--schedule",
        type=Path,
        help='drive this exciter schedule JSON instead of the case\'s motion: {"times": '
        '[...], "excitations": {"GGP": [...], ...}} (as simulate tongue)',
    )


MODEL = Model(
    name="jaw-tongue",
    summary="tongue on a hinged rigid jaw opened by a Hill muscle",
    build=build,
    cases={
        "protrusion": "the tongue protrudes while the opener opens the jaw",
        "retraction": "the tongue retracts while the opener opens the jaw",
        "retroflexion": "the tongue tip curls up while the opener opens the jaw",
        "none": "the tongue's muscles off: the jaw opener only",
    },
    levels={0: "the level-0 tongue (946 nodes; the attachment files index it)"},
    dt=0.01,
    duration=0.6,
    options=_options,
)
add_arguments, run = command(MODEL)
