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
  for each anatomical joint of :data:`JOINTS`, through a cartilage-like
  compliant layer (:data:`CARTILAGE`: E = 10 MPa, nu = 0.4, 1 mm; articular cartilage's
  aggregate modulus is 0.5-1 MPa and its instantaneous modulus 10-20 MPa, which is what a
  step of a few milliseconds sees).
- The tibia (with the fibula) is guided by a vertical slider (it sinks and rises, does
  not turn) and carries ``load`` newtons downwards (:class:`TibiaLoad`, ramped in
  ``ramp`` seconds).
- The floor: a plane under the sole with Coulomb friction ``mu`` (0.6: skin on a dry
  floor) on every skin node.

Frame: OpenSim's tibia_r frame (metres, y up, x forward, z to the right).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np

import artifem as af

from . import bones as fb
from . import mesh as fm

#: neo-Hookean soft tissue (module docstring): Young's modulus (Pa), Poisson, density.
TISSUE = dict(young=60e3, poisson=0.45, density=1050.0)
#: Rayleigh damping (alpha 1/s, beta s) of the tissue.
RAYLEIGH = (2.0, 0.002)
#: cortical and trabecular bone together (kg/m^3).
BONE_DENSITY = 1500.0
#: the joints: pairs of rigid groups whose surfaces meet through contact (the talocrural,
#: subtalar, talonavicular, calcaneocuboid, naviculocuneiform, intercuneiform,
#: cuneocuboid, tarsometatarsal, intermetatarsal and metatarsophalangeal joints).
JOINTS = (("tibia", "talus"), ("talus", "calcaneus"), ("talus", "navicular"),
          ("calcaneus", "cuboid"), ("navicular", "medial_cuneiform"),
          ("navicular", "lateral_cuneiforms"), ("medial_cuneiform", "lateral_cuneiforms"),
          ("cuboid", "lateral_cuneiforms"), ("medial_cuneiform", "metatarsal1"),
          ("lateral_cuneiforms", "metatarsals2_5"), ("cuboid", "metatarsals2_5"),
          ("metatarsal1", "metatarsals2_5"), ("metatarsal1", "hallux"),
          ("metatarsals2_5", "toes2_5"))
#: a joint's contact rows start this far (m) beyond its gap in the neutral pose.
JOINT_MARGIN = 2e-3
#: the cartilage layer of the joint contacts.
CARTILAGE = af.ElasticFoundation(young=10e6, poisson=0.4, thickness=1e-3)
#: half the body weight of a 70 kg person (N).
HALF_WEIGHT = 0.5 * 70.0 * 9.81


@dataclass
class TibiaLoad:
    """A downward force on the tibia, ramped linearly to ``force`` newtons in ``ramp``
    seconds: f(t) = -force min(t / ramp, 1) e_y (a load element: artifem.multibody.loads)."""

    tibia: af.RigidBody
    force: float
    ramp: float = 0.1

    @property
    def bodies(self) -> tuple:
        return (self.tibia,)

    def master_loads(self, t: float):
        scale = min(t / self.ramp, 1.0) if self.ramp > 0 else 1.0
        wrench = np.zeros(6)
        wrench[1] = -self.force * scale
        return [(self.tibia, wrench)]


@dataclass
class Foot:
    """The foot scene and its parts."""

    scene: af.Scene
    mesh: fm.FootMesh
    tissue: af.FemBody
    bones: dict[str, af.RigidBody]
    joints: list[af.MeshContact] = field(default_factory=list)
    floor: af.PlaneContact | None = None
    load: TibiaLoad | None = None


def build_foot(level: int = 1, *, load: float = HALF_WEIGHT, floor: bool = True,
               mu: float = 0.6, ramp: float = 0.1, cache=fm.DEFAULT_CACHE) -> Foot:
    """The foot standing on the floor (module docstring) at mesh ``level`` (0 coarse for
    tests, 1 the default: at least 10,000 nodes), ``load`` newtons down the tibia."""
    mesh = fm.foot_mesh(level, cache=cache)
    msh, _ = fm.to_dolfinx(mesh)
    tissue = af.FemBody(msh, af.NeoHookean.from_young_poisson(TISSUE["young"],
                                                               TISSUE["poisson"]),
                        TISSUE["density"], rayleigh=RAYLEIGH, name="soft tissue")
    scene = af.Scene(gravity=(0.0, -9.81, 0.0))
    scene.add(tissue)
    bones = {}
    for i, group in enumerate(mesh.groups):
        v, f = mesh.group_surfaces[group]
        bones[group] = af.RigidBody.from_surface(group, v, f, BONE_DENSITY)
        nodes = np.unique(mesh.facets[mesh.facet_tags == fm.BONE + i])
        scene.add(bones[group], af.NodeAttachment(tissue, nodes, bones[group],
                                                  name=f"tissue on {group}"))
    tibia = bones["tibia"]
    up = af.axis_rotation((0.0, 1.0, 0.0))
    scene.add(af.SliderJoint(af.Frame.at_world(tibia, tibia.position, up),
                             af.Frame(None, tibia.position, up), name="tibia guide"))
    foot = Foot(scene, mesh, tissue, bones)
    gaps = fb.min_gaps(fb.load_bones())
    for a, b in JOINTS:
        gap = gaps.get(tuple(sorted((a, b))), 0.01)
        contact = af.MeshContact(bones[a], bones[b], tolerance=1e-4,
                                 margin=gap + JOINT_MARGIN, foundation=CARTILAGE,
                                 name=f"{a}-{b} joint")
        foot.joints.append(contact)
        scene.add(contact)
    if floor:
        skin = np.unique(mesh.facets[mesh.facet_tags == fm.SKIN])
        y0 = float(mesh.points[skin, 1].min()) - 1e-4
        foot.floor = af.PlaneContact(tissue, (0.0, y0, 0.0), (0.0, 1.0, 0.0), mu=mu,
                                     points=skin, tolerance=1e-4, margin=5e-3, name="floor")
        scene.add(foot.floor)
    if load:
        foot.load = TibiaLoad(tibia, load, ramp)
        scene.add(foot.load)
    return foot
