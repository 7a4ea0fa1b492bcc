"""The foot scene (Lloyd et al. 2019, section 2.3; Perrier et al. 2017): soft tissue around
every foot bone, the bones rigid, their joints contacts, the foot on a floor.

- Soft tissue: the tetrahedra of :mod:`~artifem.models.foot.mesh`, neo-Hookean with
  :data:`TISSUE` (E = 60 kPa, nu = 0.45, 1,050 kg/m^3: the bulk plantar soft tissue's
  small-strain modulus measured in vivo, Erdemir et al. 2006, J Biomech 39:1857,
  60 +- 23 kPa over 20 subjects; nu from the near-incompressible range these models use)
  with light Rayleigh damping.
- Bones: one rigid body per rigid group (:data:`~artifem.models.foot.bones.GROUPS`),
  its mass from its surface at :data:`BONE_DENSITY`; the tissue nodes on a group's surface
  are attached to it (:class:`~artifem.NodeAttachment`: forces flow back by G^T).
- Joints between the bones: contacts of their surfaces (:class:`~artifem.MeshContact`)
  for each anatomical joint of :data:`JOINTS`, meeting at their neutral gap (the contact's
  ``offset``: the cartilage that fills the space between the bone meshes), through a
  compliant layer (:data:`CARTILAGE`: E = 10 MPa, nu = 0.4, 1 mm; articular cartilage's
  aggregate modulus is 0.5-1 MPa and its instantaneous modulus 10-20 MPa, which is what a
  step of a few milliseconds sees).
- The tibia (with the fibula) is guided by a vertical slider (it sinks and rises, does
  not turn) and carries ``load`` newtons downwards (:class:`TibiaLoad`, ramped in
  ``ramp`` seconds).
- The floor: a plane under the sole with Coulomb friction ``mu`` (0.6: skin on a dry
  floor) on every skin node.
- Ligaments: tension-only springs between the groups
  (:mod:`~artifem.models.foot.ligaments`: the deltoid, lateral collateral, spring, long and
  short plantar ligaments, the plantar fascia, and a capsule across every other joint),
  with a toe region of :data:`TOE_STRAIN` and stiffness-proportional damping (the
  tissue's beta).
- Muscles (:mod:`~artifem.models.foot.muscle`, Thelen): the tibialis anterior from the
  tibia to the medial cuneiform and the first metatarsal (two branches of F0 / 2), its
  excitation ``excitation(t)``; the soleus, unexcited, to the calcaneus (its passive force
  bounds the dorsiflexion).

Load cases (:data:`CASES`): ``standing`` (the above); ``lift`` (the tibia held fixed,
no floor and no load: the tibialis anterior lifts the hanging forefoot, the seed paper's
Fig. 7); ``heavy`` (standing with half the weight of 90 kg, held out from training the
reduced foot), through :func:`foot_case`.

Frame: OpenSim's tibia_r frame (metres, y up, x forward, z to the right).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

import artifem as af
from artifem.models.runner import Built, Model, command

from . import bones as fb
from . import ligaments as fl
from . import mesh as fm
from . import muscle as fmu
from .render import plot_plantar_pressure, render_foot

#: neo-Hookean soft tissue (module docstring): Young's modulus (Pa), Poisson, density.
TISSUE = dict(young=60e3, poisson=0.45, density=1050.0)
#: Rayleigh damping (alpha 1/s, beta s) of the tissue.
RAYLEIGH = (2.0, 0.002)
#: the ligaments' toe region, as a strain (OpenSim's Blankevoort1991Ligament default).
TOE_STRAIN = 0.06
#: cortical and trabecular bone together (kg/m^3).
BONE_DENSITY = 1500.0
#: the joints: pairs of rigid groups whose surfaces meet through contact (the talocrural,
#: subtalar, talonavicular, calcaneocuboid, naviculocuneiform, intercuneiform,
#: cuneocuboid, tarsometatarsal, intermetatarsal and metatarsophalangeal joints).
JOINTS = (
    ("tibia", "talus"),
    ("talus", "calcaneus"),
    ("talus", "navicular"),
    ("calcaneus", "cuboid"),
    ("navicular", "medial_cuneiform"),
    ("navicular", "lateral_cuneiforms"),
    ("medial_cuneiform", "lateral_cuneiforms"),
    ("cuboid", "lateral_cuneiforms"),
    ("medial_cuneiform", "metatarsal1"),
    ("lateral_cuneiforms", "metatarsals2_5"),
    ("cuboid", "metatarsals2_5"),
    ("metatarsal1", "metatarsals2_5"),
    ("metatarsal1", "hallux"),
    ("metatarsals2_5", "toes2_5"),
)
#: a joint's contact rows start this far (m) beyond its offset.
JOINT_MARGIN = 2e-3
#: the cartilage layer of the joint contacts.
CARTILAGE = af.ElasticFoundation(young=10e6, poisson=0.4, thickness=1e-3)
#: half the body weight of a 70 kg person (N).
HALF_WEIGHT = 0.5 * 70.0 * 9.81


@dataclass
class TibiaLoad:
    """A downward force on the tibia, ramped linearly to ``level`` x ``force`` newtons in
    ``ramp`` seconds: f(t) = -level force min(t / ramp, 1) e_y (a load element:
    artifem.multibody.loads; ``level`` a scene input, :class:`~artifem.scene.inputs.LoadLevel`:
    another body weight)."""

    tibia: af.RigidBody
    force: float
    ramp: float = 0.1
    level: float = 1.0
    name: str = "tibia load"

    @property
    def bodies(self) -> tuple:
        return (self.tibia,)

    def magnitude(self, t: float) -> float:
        """The downward force at t, newtons."""
        return self.level * self.force * (min(t / self.ramp, 1.0) if self.ramp > 0 else 1.0)

    def master_loads(self, t: float):
        wrench = np.zeros(6)
        wrench[1] = -self.magnitude(t)
        return [(self.tibia, wrench)]

    def potential_energy(self, t: float) -> float:
        """f(t) y of the tibia's centre of mass (the load's potential)."""
        return self.magnitude(t) * float(self.tibia.position[1])


@dataclass(frozen=True)
class Ramp:
    """An excitation u(t) = level min(t / time, 1)."""

    level: float
    time: float = 0.1

    def __call__(self, t: float) -> float:
        return self.level * min(t / self.time, 1.0) if self.time > 0 else self.level


@dataclass
class Foot:
    """The foot scene and its parts."""

    scene: af.Scene
    mesh: fm.FootMesh
    tissue: af.FemBody
    bones: dict[str, af.RigidBody]
    joints: list[af.MeshContact] = field(default_factory=list)
    ligaments: list[af.PointPath] = field(default_factory=list)
    muscles: dict[str, list[af.PointPath]] = field(default_factory=dict)
    floor: af.PlaneContact | None = None
    load: TibiaLoad | None = None


#: the load cases (module docstring): keyword arguments of :func:`build_foot`.
CASES = {
    "standing": dict(),
    "lift": dict(load=0.0, floor=False, tibia="fixed", excitation=Ramp(0.3, 0.1)),
    "heavy": dict(load=0.5 * 90.0 * 9.81),
}


def foot_case(case: str, level: int = 1, **kwargs) -> Foot:
    """The foot of load case ``case`` (:data:`CASES`) at mesh ``level``; ``kwargs``
    override the case's arguments of :func:`build_foot`."""
    if case not in CASES:
        raise af.InputError(f"foot: unknown load case {case!r}; the cases are {sorted(CASES)}")
    return build_foot(level, **{**CASES[case], **kwargs})


def build_foot(
    level: int = 1,
    *,
    load: float = HALF_WEIGHT,
    floor: bool = True,
    tibia: str = "guided",
    excitation=None,
    mu: float = 0.6,
    ramp: float = 0.1,
    bones: bool = True,
    joints: bool = True,
    integrator: str = "semi-implicit",
    cache=fm.DEFAULT_CACHE,
) -> Foot:
    """The foot (module docstring) at mesh ``level`` (0 coarse for tests, 1 the default: at
    least 10,000 nodes): ``load`` newtons down the tibia, the tibia ``"guided"`` (a vertical
    slider) or ``"fixed"``, on the floor if ``floor``, the tibialis anterior's
    ``excitation(t)`` (None: unexcited). For timing the parts (the seed paper's figures):
    ``joints=False`` leaves out the joint contacts, ``bones=False`` everything but the
    tissue, its bone surfaces then fixed (the FEM alone)."""
    if tibia not in ("guided", "fixed"):
        raise af.InputError(f"foot: tibia must be 'guided' or 'fixed', got {tibia!r}")
    mesh = fm.foot_mesh(level, cache=cache)
    msh, _ = fm.to_dolfinx(mesh)
    tissue = af.FemBody(
        msh,
        af.NeoHookean.from_young_poisson(TISSUE["young"], TISSUE["poisson"]),
        TISSUE["density"],
        rayleigh=RAYLEIGH,
        name="tissue",
    )
    scene = af.Scene(gravity=(0.0, -9.81, 0.0), integrator=integrator)
    scene.add(tissue)
    foot = Foot(scene, mesh, tissue, {})
    if bones:
        _add_bones(foot, tibia, excitation, joints)
    else:
        tissue.fix_nodes(np.unique(mesh.facets[mesh.facet_tags >= fm.BONE]))
    if floor:
        skin = np.unique(mesh.facets[mesh.facet_tags == fm.SKIN])
        y0 = float(mesh.points[skin, 1].min()) - 1e-4
        foot.floor = af.PlaneContact(
            tissue,
            (0.0, y0, 0.0),
            (0.0, 1.0, 0.0),
            mu=mu,
            points=skin,
            tolerance=1e-4,
            margin=5e-3,
            name="floor",
        )
        scene.add(foot.floor)
    if load and bones:
        foot.load = TibiaLoad(foot.bones["tibia"], load, ramp)
        scene.add(foot.load)
    return foot


def _add_bones(foot: Foot, tibia: str, excitation, joints: bool) -> None:
    """The rigid groups carrying the tissue on their surfaces, the tibia's guide, the
    ligaments, the muscles and (``joints``) the joint contacts."""
    scene, mesh, bones = foot.scene, foot.mesh, foot.bones
    bone_meshes = fb.load_bones()
    for i, group in enumerate(mesh.groups):
        v, f = mesh.group_surfaces[group]
        motion = "fixed" if group == "tibia" and tibia == "fixed" else "dynamic"
        bones[group] = af.RigidBody.from_surface(group, v, f, BONE_DENSITY, motion=motion)
        nodes = np.unique(mesh.facets[mesh.facet_tags == fm.BONE + i])
        scene.add(
            bones[group],
            af.NodeAttachment(foot.tissue, nodes, bones[group], name=f"tissue on {group}"),
        )
    if tibia == "guided":
        body = bones["tibia"]
        up = af.axis_rotation((0.0, 1.0, 0.0))
        scene.add(
            af.SliderJoint(
                af.Frame.at_world(body, body.position, up),
                af.Frame(None, body.position, up),
                name="tibia guide",
            )
        )
    for spec in fl.ligaments(bone_meshes, JOINTS):
        k = spec.stiffness
        spring = af.AxialSpring(
            k,
            rest_length=spec.length,
            damping=RAYLEIGH[1] * k,
            tension_only=True,
            toe=TOE_STRAIN * spec.length,
        )
        frames = [af.Frame.at_world(bones[g], p) for g, p in zip(spec.groups, spec.points)]
        foot.ligaments.append(af.PointPath(spring, frames, name=spec.name))
    scene.add(*foot.ligaments)
    for muscle in fmu.MUSCLES:
        drive = excitation if muscle == "tibialis anterior" else None
        for branch in fmu.muscle_branches(bone_meshes, muscle):
            frames = [af.Frame.at_world(bones[g], p) for g, p in zip(branch.groups, branch.points)]
            path = af.PointPath(
                af.ThelenMuscle(branch.params, name=branch.name),
                frames,
                excitation=drive,
                name=branch.name,
            )
            foot.muscles.setdefault(muscle, []).append(path)
            scene.add(path)
    for a, b in JOINTS if joints else ():
        gap = fb.surface_gap(mesh.group_surfaces[a], mesh.group_surfaces[b])
        contact = af.MeshContact(
            bones[a],
            bones[b],
            tolerance=1e-4,
            margin=JOINT_MARGIN,
            offset=gap,
            foundation=CARTILAGE,
            name=f"{a}-{b} joint",
        )
        foot.joints.append(contact)
        scene.add(contact)


# ---- the runner's foot (``artifem simulate foot``) -----------------------------------------

#: step (s) and duration (s) of a run: the load's ramp (0.1 s) and the settling.
DT, DURATION = 0.005, 0.3
#: the published standing figures the plantar pressure is shown beside.
REFERENCE = (
    "Published, barefoot standing (Cavanagh, Rodgers & Iiboshi 1987, Foot & Ankle "
    "7:262, 107 feet): mean peak pressure 139 kPa under the heel, 88 kPa under the "
    "forefoot; the heel carries about 60% of the load."
)
PUBLISHED_KPA = {"rearfoot": 139.0, "forefoot": 88.0}


def sole(foot: Foot) -> dict:
    """The floor's pressure at the sole's nodes (those within 1 cm of the floor at rest),
    their current positions, the contact area and the centre of pressure."""
    tissue, floor = foot.tissue, foot.floor
    p = foot.scene.contact_pressure(floor)[tissue.name]
    x = tissue.V.tabulate_dof_coordinates() + tissue.u.x.array.reshape(-1, 3)
    dofs = tissue.local_dofs(p.points)
    rest = tissue.V.tabulate_dof_coordinates()[dofs]
    sole = rest[:, 1] < floor.offset + 0.01
    pressure, area, points = p.pressure[sole], p.area[sole], x[dofs][sole]
    force = pressure * area
    centre = force @ points / force.sum() if force.sum() > 0 else np.full(3, np.nan)
    return {
        "points": points,
        "pressure": pressure,
        "force": force,
        "centre": centre,
        "area": float(area[pressure > 0].sum()),
    }


def case_figures(foot: Foot, rest: dict, pressure: dict | None) -> dict:
    """The case's own figures: standing (``pressure``: :func:`sole`), the floor's force against
    the load at the time + weight, the contact area, the peak plantar pressure (rear and fore
    thirds) and the centre of pressure; lift, the first metatarsal's rise from ``rest`` (bone
    name -> rest position) and the talus's dorsiflexion."""
    tissue, figures = foot.tissue, {}
    if pressure is not None:
        weight = 9.81 * (tissue.total_mass() + sum(b.mass for b in foot.bones.values()))
        expected = (foot.load.magnitude(foot.scene.t) if foot.load else 0.0) + weight
        normal = float(foot.scene.contact_forces(foot.floor).normal.sum())
        x = pressure["points"][:, 0]
        third = (x.max() - x.min()) / 3
        regions = {"rearfoot": x < x.min() + third, "forefoot": x > x.max() - third}
        figures["standing"] = {
            "floor_normal_N": normal,
            "load_plus_weight_N": expected,
            "relative_error": abs(normal / expected - 1.0),
            "contact_area_cm2": 1e4 * pressure["area"],
            "peak_pressure_kPa": 1e-3 * float(pressure["pressure"].max()),
            "peak_pressure_by_region_kPa": {
                k: 1e-3 * float(pressure["pressure"][m].max()) for k, m in regions.items()
            },
            "published_peak_kPa": PUBLISHED_KPA,
            "rearfoot_load_share": float(
                pressure["force"][regions["rearfoot"]].sum() / pressure["force"].sum()
            ),
            "centre_of_pressure_mm": (1e3 * pressure["centre"]).round(2).tolist(),
            "centre_of_pressure_from_heel": float(
                (pressure["centre"][0] - x.min()) / (x.max() - x.min())
            ),
            "lowest_skin_above_floor_mm": 1e3
            * float(pressure["points"][:, 1].min() - foot.floor.offset),
        }
    if foot.muscles.get("tibialis anterior") and foot.floor is None:
        talus = Rotation.from_matrix(foot.bones["talus"].rotation).as_rotvec()
        figures["lift"] = {
            "first_metatarsal_rise_mm": 1e3
            * float(foot.bones["metatarsal1"].position[1] - rest["metatarsal1"][1]),
            "talus_dorsiflexion_deg": float(np.degrees(talus[2])),
            "tibialis_anterior_N": sum(
                p.evaluate(foot.scene.t).tension for p in foot.muscles["tibialis anterior"]
            ),
            "soleus_N": sum(p.evaluate(foot.scene.t).tension for p in foot.muscles["soleus"]),
        }
    return figures


def build(case: str, level: int = 1, integrator: str = "semi-implicit") -> Built:
    """The foot of load case ``case`` at mesh ``level``, for :mod:`artifem.models.runner`:
    its picture (bones, ligaments, muscles, the tissue cut and coloured by von Mises
    stress; standing, also the plantar pressure) and :func:`case_figures`."""
    foot = foot_case(case, level, integrator=integrator)
    rest = {name: body.position.copy() for name, body in foot.bones.items()}

    def figures(run) -> dict:
        return {
            "ligaments": len(foot.ligaments),
            "joint_contacts": len(foot.joints),
            "joint_failures": [f for f in (c.constraint_failure() for c in foot.joints) if f],
            **case_figures(foot, rest, sole(foot) if foot.floor is not None else None),
        }

    def draw(png, run, shown) -> None:
        render_foot(png, foot, case)
        if foot.floor is not None:
            s = sole(foot)
            plot_plantar_pressure(
                png.with_name("plantar_pressure.png"),
                s["points"],
                s["pressure"],
                s["centre"],
                f"foot {case}: plantar pressure, level {level}",
                REFERENCE,
            )

    return Built(foot.scene, figures=figures, render=draw)


MODEL = Model(
    name="foot",
    summary="the foot standing on the floor, or lifted by the tibialis anterior",
    build=build,
    cases={
        "standing": "half of 70 kg down the tibia, on the floor with friction",
        "lift": "the tibia fixed, the tibialis anterior lifts the hanging forefoot",
        "heavy": "standing with half of 90 kg (held out from the reduced foot's training)",
    },
    levels={0: "coarse (1,923 nodes)", 1: "the default (13,453 nodes)"},
    dt=DT,
    duration=DURATION,
    default_level=1,
)
add_arguments, run = command(MODEL)
