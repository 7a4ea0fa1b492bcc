"""The foot's ligaments: tension-only springs between the rigid bone groups.

Each ligament is a straight line between two attachment points on bones of different
groups, with the stiffness of a truss element k = E A / L0 (L0 its length in the neutral
pose, where it is taut and carries no force) and no force when shorter
(:class:`~artifem.AxialSpring` with ``tension_only``). E and A are those of the truss
elements of Cheung et al. (2005, J Biomech 38:1045, "Three-dimensional finite element
analysis of the foot during standing: a material sensitivity study"): every ligament
E = 260 MPa, A = 18.4 mm^2; the plantar fascia E = 350 MPa, A = 58.6 mm^2, shared here by
its five bands.

Modelled (:data:`NAMED`):

- deltoid (medial collateral): tibionavicular, tibiocalcaneal, anterior and posterior
  tibiotalar bands, from the medial malleolus;
- lateral collateral: anterior and posterior talofibular, calcaneofibular, from the
  lateral malleolus;
- spring ligament (plantar calcaneonavicular): sustentaculum tali to the navicular;
- long plantar: calcaneus to the bases of metatarsals 3 and 4; short plantar
  (plantar calcaneocuboid): anterior tubercle of the calcaneus to the cuboid;
- plantar fascia: five bands from the medial process of the calcaneal tuberosity to the
  bases of the proximal phalanges (the windlass);
- the capsule of every other joint of :data:`~artifem.models.foot.model.JOINTS`
  (:func:`capsules`): four springs across its rim (dorsal, plantar and the two sides),
  standing for the dorsal, plantar and interosseous ligaments that hold the tarsal,
  tarsometatarsal, intermetatarsal and metatarsophalangeal joints.

Not modelled: the interosseous talocalcaneal and the tibiofibular ligaments (the tibia and
fibula are one body), the retinacula, the transverse metatarsal ligaments inside a group.

An attachment point is a *landmark* (:class:`Landmark`): the vertex of a bone furthest in
a direction, optionally among the vertices within a depth of one end of the bone (its
distal end, its base): reproducible from the bone meshes, with no coordinates typed in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import bones as fb

#: truss constants of Cheung et al. (2005): (E Pa, A m^2).
LIGAMENT = (260e6, 18.4e-6)
PLANTAR_FASCIA = (350e6, 58.6e-6 / 5)  # per band, five bands


@dataclass(frozen=True)
class Landmark:
    """The vertex of ``bone`` furthest along ``direction`` (frame: x forward, y up, z to the
    right, i.e. lateral), among the vertices within ``depth`` metres of the bone's end
    along ``axis`` (0, 1, 2) on ``side`` (-1 the low end, +1 the high end) when given."""

    bone: str
    direction: tuple[float, float, float]
    axis: int | None = None
    side: int = -1
    depth: float = 0.0

    def point(self, bones: dict[str, fb.Bone]) -> np.ndarray:
        v = bones[self.bone].vertices
        if self.axis is not None:
            end = v[:, self.axis].min() if self.side < 0 else v[:, self.axis].max()
            v = v[np.abs(v[:, self.axis] - end) <= self.depth]
        return v[np.argmax(v @ np.asarray(self.direction, dtype=float))]


def _distal(bone: str, direction) -> Landmark:
    """A landmark on the lowest 2 cm of a leg bone (the malleoli)."""
    return Landmark(bone, direction, axis=1, side=-1, depth=0.02)


def _base(bone: str, direction, depth: float = 0.012) -> Landmark:
    """A landmark on the proximal (posterior) end of a metatarsal or phalanx."""
    return Landmark(bone, direction, axis=0, side=-1, depth=depth)


MEDIAL_MALLEOLUS = _distal("tibia", (0.0, -1.0, -1.0))
LATERAL_MALLEOLUS = _distal("fibula", (0.0, -1.0, 0.0))
SUSTENTACULUM = Landmark("calcaneus", (0.3, 0.3, -1.0))
MEDIAL_PROCESS = Landmark("calcaneus", (-1.0, -1.0, -0.3))

#: name -> (landmark, landmark, (E, A)): the named ligaments (module docstring).
NAMED: dict[str, tuple[Landmark, Landmark, tuple[float, float]]] = {
    "tibionavicular": (
        _distal("tibia", (1.0, -1.0, -1.0)),
        Landmark("navicular", (0.0, -0.3, -1.0)),
        LIGAMENT,
    ),
    "tibiocalcaneal": (MEDIAL_MALLEOLUS, SUSTENTACULUM, LIGAMENT),
    "anterior tibiotalar": (
        _distal("tibia", (1.0, -1.0, -1.0)),
        Landmark("talus", (1.0, 0.0, -1.0)),
        LIGAMENT,
    ),
    "posterior tibiotalar": (
        _distal("tibia", (-1.0, -1.0, -1.0)),
        Landmark("talus", (-1.0, 0.0, -1.0)),
        LIGAMENT,
    ),
    "anterior talofibular": (
        _distal("fibula", (1.0, -0.5, 0.0)),
        Landmark("talus", (1.0, 0.0, 1.0)),
        LIGAMENT,
    ),
    "posterior talofibular": (
        _distal("fibula", (-1.0, 0.0, 0.0)),
        Landmark("talus", (-1.0, 0.0, 1.0)),
        LIGAMENT,
    ),
    "calcaneofibular": (LATERAL_MALLEOLUS, Landmark("calcaneus", (0.0, -0.3, 1.0)), LIGAMENT),
    "spring": (SUSTENTACULUM, Landmark("navicular", (0.0, -1.0, -1.0)), LIGAMENT),
    "long plantar 3": (
        Landmark("calcaneus", (0.5, -1.0, 0.0)),
        _base("metatarsal3", (0.0, -1.0, 0.0)),
        LIGAMENT,
    ),
    "long plantar 4": (
        Landmark("calcaneus", (0.5, -1.0, 0.0)),
        _base("metatarsal4", (0.0, -1.0, 0.0)),
        LIGAMENT,
    ),
    "short plantar": (
        Landmark("calcaneus", (1.0, -1.0, 0.0)),
        Landmark("cuboid", (0.0, -1.0, 0.0)),
        LIGAMENT,
    ),
    **{
        f"plantar fascia {i}": (
            MEDIAL_PROCESS,
            _base(f"prox_phalanx{i}", (0.0, -1.0, 0.0), 0.008),
            PLANTAR_FASCIA,
        )
        for i in range(1, 6)
    },
}


@dataclass(frozen=True)
class LigamentSpec:
    """One ligament: its groups, attachment points (tibia frame, m) and stiffness."""

    name: str
    groups: tuple[str, str]
    points: tuple[np.ndarray, np.ndarray]
    stiffness: float

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.points[1] - self.points[0]))


def _spec(name: str, bones: dict[str, fb.Bone], a: Landmark, b: Landmark, ea) -> LigamentSpec:
    pa, pb = a.point(bones), b.point(bones)
    length = float(np.linalg.norm(pb - pa))
    return LigamentSpec(
        name, (bones[a.bone].group, bones[b.bone].group), (pa, pb), ea[0] * ea[1] / length
    )


def capsules(
    bones: list[fb.Bone], joints, skip=(("tibia", "talus"),), reach: float = 0.005
) -> list[LigamentSpec]:
    """Four springs across the rim of each joint (group pair) of ``joints`` not in ``skip``:
    with n the direction from one side's joint region to the other's (the vertices of each
    within its gap + ``reach`` of the other group), t1 the up direction made normal to n
    and t2 = n x t1, the springs join the two sides' vertices furthest along +-t1 and
    +-t2. Stiffness E A / L0 with :data:`LIGAMENT`."""
    import igl

    def merged(group):
        parts = [b for b in bones if b.group == group]
        offsets = np.cumsum([0] + [len(b.vertices) for b in parts[:-1]])
        return (
            np.vstack([b.vertices for b in parts]),
            np.vstack([b.triangles + o for b, o in zip(parts, offsets)]),
        )

    out = []
    for a, b in joints:
        if (a, b) in skip:
            continue
        (va, fa), (vb, fbt) = merged(a), merged(b)
        da = np.sqrt(igl.point_mesh_squared_distance(va, vb, fbt)[0])
        db = np.sqrt(igl.point_mesh_squared_distance(vb, va, fa)[0])
        near_a, near_b = va[da <= da.min() + reach], vb[db <= db.min() + reach]
        n = near_b.mean(0) - near_a.mean(0)
        n /= np.linalg.norm(n)
        up = np.array([0.0, 1.0, 0.0]) if abs(n[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        t1 = up - (up @ n) * n
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        for label, t in (("dorsal", t1), ("plantar", -t1), ("side +", t2), ("side -", -t2)):
            pa, pb = near_a[np.argmax(near_a @ t)], near_b[np.argmax(near_b @ t)]
            length = float(np.linalg.norm(pb - pa))
            out.append(
                LigamentSpec(
                    f"{a}-{b} capsule {label}", (a, b), (pa, pb), LIGAMENT[0] * LIGAMENT[1] / length
                )
            )
    return out


def ligaments(bones: list[fb.Bone], joints) -> list[LigamentSpec]:
    """Every ligament of the module docstring: :data:`NAMED`, then the joint
    :func:`capsules`."""
    by_name = {b.name: b for b in bones}
    return [_spec(name, by_name, a, b, ea) for name, (a, b, ea) in NAMED.items()] + capsules(
        bones, joints
    )
