"""An FEM beam carrying a rigid ellipsoid at its free end (Lloyd et al. 2019, Fig. 11, right).

A 300 x 50 x 50 mm neo-Hookean beam (E = 5 MPa, nu = 0.3, 1000 kg/m^3, 24 x 4 x 4
hexahedra) is clamped at x = 0. A rigid ellipsoid (semi-axes 50, 35, 35 mm,
1000 kg/m^3; mass and inertia analytic, m = rho 4/3 pi a b c,
I = m/5 diag(b^2 + c^2, a^2 + c^2, a^2 + b^2)) sits beyond the free end, its
centre at (L + a, W/2, H/2). Gravity acts on both. Two couplings
(``build_scene(attach=...)``):

- ``"frame"``, the paper's: the ellipsoid follows a frame on the beam's end face
  (:class:`~artifem.scene.FrameAttachment`), a Procrustes frame over
  the face's nodes with its origin at their centroid, so the ellipsoid's weight
  and moment reach the face as G^T [f; tau]: the force spread evenly, the moment
  as forces linear across the face. The face stays deformable.
- ``"face"``: the end-face nodes (x = L) follow the ellipsoid
  (:class:`~artifem.scene.NodeAttachment`), x_i = p + R r_i, which
  makes the face rigid.

Both are the same coupling for a beam whose cross-section stays plane; they differ
by the face's local deformation.

Static check (tests/test_multibody_coupled.py for the face,
tests/test_multibody_frame_coupled.py for the frame): the tip deflection of the
coupled static solve against a full FEM reference (:func:`build_reference`):
the same mesh extended by a 2a-long block of the beam's cross-section beyond
x = L, with the ellipsoid's mass (an extra body force on the block) and a
stiffness ``stiffness_ratio`` (1e4) times the beam's. Same resultant and
same moment about the end face as the ellipsoid's weight (the block's centre
is the ellipsoid's), same discretization of the beam: the two differ only by
the block's compliance, O(1 / stiffness_ratio), for the rigid face (measured
19.7355 mm both, 1.2e-7 apart at 1000x); the end frame leaves the face deformable
and deflects 19.7344 mm, 5e-5 less.

``artifem simulate beam-ellipsoid --case frame|face`` releases the straight beam under
gravity with either coupling (:mod:`artifem.models.runner`); ``artifem study
beam-ellipsoid`` (:mod:`artifem.models.beam_ellipsoid.study`) compares the static tip with
the reference and with Euler-Bernoulli theory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import ufl
from mpi4py import MPI

from dolfinx import mesh as dmesh

from artifem.errors import InputError
from artifem.fem_body import FemBody
from artifem.forms import NeoHookean
from artifem.multibody.attachments import FrameAttachment, NodeAttachment
from artifem.models.beam_ellipsoid.render import render
from artifem.models.runner import Built, Model, command
from artifem.scene import Scene
from artifem.multibody.frame_attachments import FemFrame
from artifem.multibody.rigid_body import RigidBody

__all__ = [
    "BeamEllipsoidConfig",
    "build_scene",
    "build_reference",
    "ellipsoid_mass_properties",
    "euler_bernoulli_tip",
    "tip_deflection",
    "MODEL",
]


@dataclass(frozen=True)
class BeamEllipsoidConfig:
    length: float = 0.3
    width: float = 0.05
    height: float = 0.05
    cells: tuple[int, int, int] = (24, 4, 4)
    young: float = 5.0e6
    poisson: float = 0.3
    density: float = 1000.0
    rayleigh: tuple[float, float] = (0.0, 0.0)
    semi_axes: tuple[float, float, float] = (0.05, 0.035, 0.035)
    ellipsoid_density: float = 1000.0
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)

    @property
    def center(self) -> np.ndarray:
        """The ellipsoid's centre: on the beam's axis, a beyond the end face."""
        return np.array([self.length + self.semi_axes[0], 0.5 * self.width, 0.5 * self.height])


def ellipsoid_mass_properties(config: BeamEllipsoidConfig) -> tuple[float, np.ndarray]:
    """(m, I about the centre in body axes) of the solid ellipsoid, analytic."""
    a, b, c = config.semi_axes
    m = config.ellipsoid_density * 4.0 / 3.0 * np.pi * a * b * c
    return m, m / 5.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


#: mesh levels: cells (x, y, z); 2a is a whole number of cells (build_reference)
LEVELS = {0: (12, 2, 2), 1: (24, 4, 4), 2: (48, 8, 8)}


def _beam_mesh(config: BeamEllipsoidConfig, extra_cells: int = 0, extra_length: float = 0.0):
    nx, ny, nz = config.cells
    return dmesh.create_box(
        MPI.COMM_SELF,
        [np.zeros(3), np.array([config.length + extra_length, config.width, config.height])],
        [nx + extra_cells, ny, nz],
        dmesh.CellType.hexahedron,
    )


def build_scene(
    config: BeamEllipsoidConfig = BeamEllipsoidConfig(),
    *,
    attach: str = "face",
    integrator: str = "semi-implicit",
) -> tuple[Scene, FemBody, RigidBody, NodeAttachment | FrameAttachment]:
    """The clamped beam, the ellipsoid and its attachment (module docstring), in one scene."""
    if attach not in ("face", "frame"):
        raise InputError(f"build_scene: attach must be 'face' or 'frame', got {attach!r}")
    beam = FemBody(
        _beam_mesh(config),
        NeoHookean.from_young_poisson(config.young, config.poisson),
        config.density,
        rayleigh=config.rayleigh,
        name="beam",
    )
    beam.fix_nodes(beam.find_nodes(lambda x: np.isclose(x[0], 0.0)))
    mass, inertia = ellipsoid_mass_properties(config)
    ellipsoid = RigidBody("ellipsoid", mass, inertia, position=config.center)
    scene = Scene(gravity=config.gravity, integrator=integrator)
    scene.add(beam, ellipsoid)
    face = beam.find_nodes(lambda x: np.isclose(x[0], config.length))
    if attach == "face":
        attachment = NodeAttachment(beam, face, ellipsoid, name="end face")
    else:
        frame = FemFrame(beam, method="procrustes", support=face)
        attachment = FrameAttachment(ellipsoid, frame, name="end frame")
    scene.add(attachment)
    return scene, beam, ellipsoid, attachment


class _Isotropic:
    """An isotropic energy in the fiber-material slot of FemBody.add_muscle (a0 and the
    excitation ignored): adds a stiff material to a set of cells."""

    def __init__(self, material):
        self.material = material

    def strain_energy(self, F, a0, excitation):
        return self.material.strain_energy(F)


def build_reference(
    config: BeamEllipsoidConfig = BeamEllipsoidConfig(), *, stiffness_ratio: float = 1.0e4
) -> FemBody:
    """Full FEM reference: the beam extended by a stiff block that stands in for the ellipsoid.

    The block spans x in [L, L + 2a] with the beam's cross-section and cell size
    (2a must be a whole number of beam cells), so its centre is the ellipsoid's
    centre; it weighs what the ellipsoid weighs (a body force
    (rho_block - rho) g on the block, rho_block = m / (2a W H)) and its material
    is the beam's plus a neo-Hookean ``stiffness_ratio`` times stiffer.
    """
    nx = config.cells[0]
    dx = config.length / nx
    block = 2.0 * config.semi_axes[0]
    extra = int(round(block / dx))
    if not np.isclose(extra * dx, block):
        raise InputError(
            f"build_reference: the block length 2a = {block:g} must be a whole "
            f"number of beam cells ({dx:g})"
        )
    material = NeoHookean.from_young_poisson(config.young, config.poisson)
    body = FemBody(
        _beam_mesh(config, extra, block),
        material,
        config.density,
        rayleigh=config.rayleigh,
        gravity=config.gravity,
        name="beam+block",
    )
    body.fix_nodes(body.find_nodes(lambda x: np.isclose(x[0], 0.0)))
    cells = body.find_cells(lambda x: x[0] > config.length)
    stiff = NeoHookean.from_young_poisson(stiffness_ratio * config.young, config.poisson)
    body.add_muscle("block", cells, (1.0, 0.0, 0.0), _Isotropic(stiff))
    mass, _ = ellipsoid_mass_properties(config)
    rho_block = mass / (block * config.width * config.height)
    X = ufl.SpatialCoordinate(body.mesh)
    g = ufl.as_vector([float(v) for v in config.gravity])
    inside = ufl.conditional(ufl.gt(X[0], config.length), 1.0, 0.0)
    body.set_body_force((rho_block - config.density) * inside * g)
    return body


def euler_bernoulli_tip(config: BeamEllipsoidConfig) -> float:
    """Small-deflection Euler-Bernoulli tip deflection (m, downward positive) of the clamped
    beam under its own weight q and the ellipsoid's weight W at lever a beyond the end:
    q L^4 / 8EI + W L^3 / 3EI + W a L^2 / 2EI (no shear, no locking: the mesh's target)."""
    L, W, H = config.length, config.width, config.height
    EI = config.young * W * H**3 / 12.0
    g = float(np.linalg.norm(config.gravity))
    q = config.density * W * H * g
    weight = ellipsoid_mass_properties(config)[0] * g
    a = config.semi_axes[0]
    return q * L**4 / (8 * EI) + weight * L**3 / (3 * EI) + weight * a * L**2 / (2 * EI)


def tip_deflection(body: FemBody, config: BeamEllipsoidConfig) -> float:
    """-u_z at the centre of the end face (x = L)."""
    node = body.nearest_node((config.length, 0.5 * config.width, 0.5 * config.height))
    return -float(body.displacement_at([node])[0, 2])


def build(case: str, level: int = 1, integrator: str = "semi-implicit") -> Built:
    """The straight beam released under gravity with the ellipsoid on its end ``case``
    ("frame" or "face", :func:`build_scene`), for :mod:`artifem.models.runner`: the tip
    deflection, the energy and the ellipsoid's pose recorded; the picture shows the
    ellipsoid with the beam."""
    config = BeamEllipsoidConfig(cells=LEVELS[level])
    scene, beam, ellipsoid, _ = build_scene(config, attach=case, integrator=integrator)
    mass, _ = ellipsoid_mass_properties(config)
    record = {
        "tip": lambda s: tip_deflection(beam, config),
        "energy": lambda s: s.energy(),
        "position": lambda s: ellipsoid.position.copy(),
        "rotation": lambda s: ellipsoid.rotation.copy(),
    }

    def figures(run) -> dict:
        r = run.records
        return {
            "ellipsoid_mass_kg": mass,
            "max_tip_mm": 1e3 * float(r["tip"].max()),
            "final_tip_mm": 1e3 * float(r["tip"][-1]),
            "euler_bernoulli_static_tip_mm": 1e3 * euler_bernoulli_tip(config),
            "energy_J": {
                "initial": float(r["energy"][0]),
                "max": float(r["energy"].max()),
                "final": float(r["energy"][-1]),
            },
        }

    def draw(png, run, shown) -> None:
        frames = []
        for t in shown:
            k = int(np.argmin(abs(run.times - t)))
            u = run.snapshots[t][beam.name].x.array
            pose = run.records["position"][k], run.records["rotation"][k]
            frames.append((f"t = {run.times[k]:.2f} s", u, *pose))
        render(png, config, beam, frames)

    return Built(scene, record=record, figures=figures, render=draw)


MODEL = Model(
    name="beam-ellipsoid",
    summary="FEM beam with a rigid ellipsoid at its end (Fig. 11)",
    build=build,
    cases={
        "frame": "the ellipsoid on a Procrustes frame over the end face (the paper's)",
        "face": "the end face's nodes carried by the ellipsoid (a rigid face)",
    },
    levels={k: " x ".join(map(str, v)) + " hexahedra" for k, v in LEVELS.items()},
    dt=2e-3,
    duration=0.5,
    default_level=1,
    camera="xz",
)
add_arguments, run = command(MODEL)
