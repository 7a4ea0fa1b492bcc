"""The foot's muscles, read from the Hamner et al. (2010) osim: the tibialis anterior
(``tib_ant_r``), which lifts the forefoot, and the soleus (``soleus_r``), unexcited, whose
passive force stops the lift where the ankle's dorsiflexion does (the gastrocnemii, the
other heads of the Achilles tendon, start on the femur, outside the model).

From the osim: each muscle's path (origin and via points on tibia_r, insertion on calcn_r,
the lumped foot) and its Thelen (2003) constants (tibialis anterior: F0 = 905 N, l0 = 98 mm,
tendon slack 223 mm, pennation 5 degrees; soleus: 3,549 N, 50 mm, 250 mm, 25 degrees).
The insertion is moved to the nearest surface point of the bone it is on
(:data:`MUSCLES`): the tibialis anterior's tendon inserts on the medial cuneiform and the
base of the first metatarsal (the osim's point lies 0.7 mm from the first and 4.2 mm from
the second), so it is split into two branches of F0 / 2, one to each, driven by the same
excitation; the soleus inserts on the calcaneus.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

import artifem as af
from artifem.errors import InputError

from . import bones as fb

#: muscle -> (its name in the osim, the bones its tendon inserts on).
MUSCLES = {
    "tibialis anterior": ("tib_ant_r", ("medial_cuneiform", "metatarsal1")),
    "soleus": ("soleus_r", ("calcaneus",)),
}
#: osim Thelen2003Muscle tag -> ThelenParameters field
PARAMETERS = {
    "max_isometric_force": "max_isometric_force",
    "optimal_fiber_length": "optimal_fiber_length",
    "tendon_slack_length": "tendon_slack_length",
    "pennation_angle_at_optimal": "pennation_angle",
    "max_contraction_velocity": "max_contraction_velocity",
    "FmaxTendonStrain": "fmax_tendon_strain",
    "FmaxMuscleStrain": "fmax_muscle_strain",
    "KshapeActive": "active_width",
    "KshapePassive": "passive_shape",
    "Af": "af",
    "Flen": "flen",
    "activation_time_constant": "activation_time_constant",
    "deactivation_time_constant": "deactivation_time_constant",
}


@dataclass(frozen=True)
class MuscleSpec:
    """An osim muscle in the tibia frame: path points (m) with the OpenSim body of each,
    and its Thelen parameters."""

    name: str
    points: np.ndarray
    bodies: tuple[str, ...]
    params: af.ThelenParameters


def read_muscle(name: str, osim: Path = fb.OSIM) -> MuscleSpec:
    """The Thelen2003Muscle ``name`` of ``osim``: its path points moved to the tibia frame by
    :func:`~artifem.models.foot.bones.body_transforms`, its constants."""
    node = ET.parse(osim).getroot().find(f".//Thelen2003Muscle[@name='{name}']")
    if node is None:
        raise InputError(f"{osim}: no Thelen2003Muscle {name!r}")
    transforms = fb.body_transforms(osim)
    points, bodies = [], []
    for p in node.iter("PathPoint"):
        body = p.findtext("socket_parent_frame").rsplit("/", 1)[-1]
        if body not in transforms:
            raise InputError(
                f"{osim}: muscle {name} has a path point on {body}, "
                f"not a body of the foot ({sorted(transforms)})"
            )
        m = transforms[body]
        points.append(m[:3, :3] @ np.array(p.findtext("location").split(), dtype=float) + m[:3, 3])
        bodies.append(body)
    values = {
        field: float(node.findtext(tag))
        for tag, field in PARAMETERS.items()
        if node.find(tag) is not None
    }
    return MuscleSpec(name, np.array(points), tuple(bodies), af.ThelenParameters(**values))


@dataclass(frozen=True)
class Branch:
    """One branch of the tendon: its path (tibia frame, m), the group of each point, and
    its share of the muscle's parameters."""

    name: str
    points: np.ndarray
    groups: tuple[str, ...]
    params: af.ThelenParameters


def muscle_branches(bones: list[fb.Bone], muscle: str, osim: Path = fb.OSIM) -> list[Branch]:
    """The branches of ``muscle`` (:data:`MUSCLES`, module docstring): the osim path up to
    its last point, then the nearest surface point of each insertion bone; F0 divided
    among them."""
    import igl

    osim_name, insertions = MUSCLES[muscle]
    spec = read_muscle(osim_name, osim)
    if spec.bodies[:-1] != ("tibia_r",) * (len(spec.bodies) - 1):
        raise InputError(
            f"{osim}: {osim_name} should run from tibia_r to the foot, its path is on {spec.bodies}"
        )
    by_name = {b.name: b for b in bones}
    params = replace(
        spec.params, max_isometric_force=spec.params.max_isometric_force / len(insertions)
    )
    out = []
    for bone in insertions:
        b = by_name[bone]
        _, _, closest = igl.point_mesh_squared_distance(spec.points[-1:], b.vertices, b.triangles)
        name = muscle if len(insertions) == 1 else f"{muscle} to {bone}"
        out.append(
            Branch(
                name,
                np.vstack([spec.points[:-1], closest]),
                ("tibia",) * (len(spec.points) - 1) + (b.group,),
                params,
            )
        )
    return out
