"""The ArtiSynth hex tongue as an artifem FEM body with 21 muscle bundles.

Data: ArtiSynth's public hex tongue (models/data/artisynth-tongue, with its
LICENSE), the ancestor of the seed paper's 2,961-node tongue. Material and
set-up as in ArtiSynth's HexTongueDemo: Mooney-Rivlin C10 = 1037 Pa,
C20 = 486 Pa, kappa = 10370 Pa, 1040 kg/m^3, Rayleigh D = 40 M + 0.03 K,
dt = 0.01 s, jaw and hyoid attachment nodes fixed.

Muscles: every bundle of CreateMuscles.mac is a region of the FEM body with a
Blemker fiber energy (artifem.forms.BlemkerFiber) along per-element
directions taken from Fibers.mac (models.tongue.fibers: the nearest fiber
segment to each element centroid). Its maximum fiber stress is the muscle's
maximum force (MuscleMaxForce.txt; ArtiSynth gives half of it to each of the
_L and _R bundles) divided by the bundle's physiological cross-section,
volume / mean fiber length (for the styloglossus, the length of its fibers
inside the tongue). Bilateral exciters drive the _L and _R bundles together.

Incompressibility: ArtiSynth's demo also enforces incompressibility per
element (IncompMethod.AUTO, hard constraints) on top of kappa = 10 C10, and so
does this model by default: ``TongueConfig.incompressibility`` is :data:`HARD`,
the element volumes held by an augmented Lagrangian
(:mod:`artifem.incompressibility`), solved with :data:`HARD_SOLVER`; reduced
tongues hold it in a reduced pressure space (artifem.reduction). The soft
alternative is FemBody's element-wise penalty :data:`PENALTY`, kappa_inc =
100 C10 (Poisson ratio about 0.49, the value the demo's own comment gives for a
nearly incompressible bulk modulus; ``--incompressibility penalty`` on the
command line). Without either the tissue (nu = 0.41) lets the muscles change
its volume instead of its shape, and protrusion, which relies on the
transverse muscles pushing tissue forward, moves the tip backwards (measured:
+6.8 mm in x); the penalty changes the volume by 2-3 % over a motion, the hard
constraint by less than 0.01 % (docs/incompressibility.md).

Fidelity levels: 0 is the mesh as shipped (946 nodes, 740 hexahedra); 1 splits
every hexahedron 2x2x2 (6,699 nodes, 5,920 hexahedra), recomputing element
directions from the same fibers and carrying the fixed node sets over to the
new nodes whose parents are all fixed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mpi4py import MPI

from artifem.errors import InputError, UnknownNameError
from artifem.excitation import ExcitationSchedule
from artifem.fem_body import FemBody
from artifem.incompressibility import Incompressible
from artifem.forms import BlemkerFiber, MooneyRivlin
from artifem.io.ansys import read_ansys
from artifem.io.mesh_data import MeshData
from artifem.io.refine import carry_cell_set, carry_node_set, refine_hexahedra
from artifem.io.to_dolfinx import to_dolfinx
from artifem.linear_solver import DEFAULT_METHOD
from artifem.models.tongue.apdl import read_fibers, read_muscle_elements, read_muscle_groups
from artifem.models.tongue.fibers import bundle_geometry, element_directions, fiber_points
from artifem.models.runner import Built, Model, command
from artifem.scene import Scene

DATA = Path(__file__).resolve().parents[1] / "data" / "artisynth-tongue"

#: The seed paper's Table 1: peak excitations of the three speech motions.
MOTIONS = {
    "protrusion": {"GGP": 0.4, "TRANS": 0.4, "SL": 0.1},
    "retroflexion": {"TRANS": 0.4, "SL": 0.6},
    "retraction": {"HG": 0.6, "IL": 0.4},
}
#: ArtiSynth's named nodes (ANSYS node ids of tongue.node).
LANDMARKS = {"tip": 920, "top": 870, "base": 928}
RAMP_TIME, DURATION, DT = 0.5, 1.0, 0.01
#: The hard constraint: element volumes to 1e-4, augmentation 100 C10 (the answer does not
#: depend on it; with HARD_SOLVER a larger one only saves pressure iterations: a median of
#: 10, 4 and 2 per level-1 step at 10, 100 and 1000 C10, 1104, 1023 and 969 ms).
HARD = Incompressible(kappa=100 * 1037.0, tol=1e-4)
#: The linear solver for HARD: MUMPS, factored once per step, each pressure iteration a
#: pair of triangular solves (CG + AMG pays a whole CG solve per pressure iteration:
#: docs/incompressibility.md measures both).
HARD_SOLVER = "mumps"
#: The soft alternative: FemBody's element-wise penalty kappa_inc = 100 C10 (Pa), solved
#: with the default linear solver (CG + AMG).
PENALTY = 100 * 1037.0


@dataclass(frozen=True)
class TongueConfig:
    level: int = 0
    C10: float = 1037.0
    C20: float = 486.0
    kappa: float = 10370.0
    #: Element-wise incompressibility: :data:`HARD` (the default), the penalty kappa_inc
    #: (Pa, e.g. :data:`PENALTY`) or None (module docstring).
    incompressibility: float | Incompressible | None = HARD
    density: float = 1040.0
    rayleigh: tuple[float, float] = (40.0, 0.03)
    integrator: str = "semi-implicit"
    #: The linear solver (artifem.linear_solver); None: :data:`HARD_SOLVER` with a hard
    #: constraint, the default method (CG + AMG) otherwise.
    linear_solver: str | None = None

    def __post_init__(self):
        if self.level not in (0, 1):
            raise InputError(
                f"tongue level must be 0 (as shipped) or 1 (2x2x2 split), got {self.level}"
            )
        if self.linear_solver is None:
            hard = isinstance(self.incompressibility, Incompressible)
            object.__setattr__(self, "linear_solver", HARD_SOLVER if hard else DEFAULT_METHOD)


@dataclass
class TongueData:
    """Everything the model takes from the data files, at one fidelity level."""

    mesh: MeshData
    bundles: dict[str, np.ndarray]  # bundle -> element rows
    directions: dict[str, np.ndarray]  # bundle -> (elements, 3) unit fiber directions
    max_stress: dict[str, float]  # bundle -> Pa
    exciters: dict[str, list[str]]  # exciter -> bundles
    fixed_nodes: np.ndarray  # rows of jaw and hyoid attachment nodes
    landmarks: dict[str, int]  # name -> node row
    geometry: dict[str, dict] = field(default_factory=dict)


def read_max_forces(path: Path) -> dict[str, float]:
    """MuscleMaxForce.txt: ``NAME force_N`` per line."""
    forces = {}
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 2:
            raise InputError(f"{path}:{lineno}: expected 'NAME force', got {line!r}")
        forces[parts[0]] = float(parts[1])
    return forces


def load_tongue_data(level: int = 0, data_dir: Path = DATA) -> TongueData:
    """Read mesh, bundles, fibers, forces and attachment sets; refine for level 1."""
    coarse = read_ansys(data_dir / "tongue.node")
    elements = read_muscle_elements(data_dir / "CreateMuscles.mac")
    groups = read_muscle_groups(data_dir / "CreateMuscles.mac")
    fiber_ids = read_fibers(data_dir / "Fibers.mac", list(elements))
    fibers = fiber_points(coarse, fiber_ids)
    forces = read_max_forces(data_dir / "MuscleMaxForce.txt")
    geometry = bundle_geometry(coarse, elements, fiber_ids)
    exciters = dict(groups)
    for bundle in elements:  # unpaired bundles (SL) excite themselves
        if not any(bundle in members for members in exciters.values()):
            exciters[bundle] = [bundle]
    max_stress = {}
    for exciter, members in exciters.items():
        if exciter not in forces:
            raise InputError(f"MuscleMaxForce.txt has no force for exciter {exciter!r}")
        for bundle in members:
            area = geometry[bundle]["cross_section_inside_m2"]
            max_stress[bundle] = forces[exciter] / len(members) / area
    # The attachment files hold ArtiSynth's 0-based node numbers, i.e. rows.
    fixed = np.unique(
        np.concatenate(
            [
                np.loadtxt(data_dir / f, dtype=np.int64).ravel()
                for f in ("jawAttachments.txt", "hyoidAttachments.txt")
            ]
        )
    )
    bundles = {name: coarse.cell_rows(ids) for name, ids in elements.items()}
    mesh = coarse
    if level == 1:
        refined = refine_hexahedra(coarse)
        mesh = refined.mesh
        fixed = carry_node_set(refined, fixed)
        bundles = {name: carry_cell_set(refined, rows) for name, rows in bundles.items()}
    directions = {
        name: element_directions(mesh.points, mesh.cells, rows, fibers[name])[0]
        for name, rows in bundles.items()
    }
    landmarks = {name: int(mesh.node_rows([node_id])[0]) for name, node_id in LANDMARKS.items()}
    return TongueData(mesh, bundles, directions, max_stress, exciters, fixed, landmarks, geometry)


class Tongue:
    """The tongue FEM body in its scene (no gravity, as ArtiSynth's tongue), with exciters
    and motions.

    >>> tongue = Tongue(TongueConfig(level=0))
    >>> tongue.set_excitations({"GGP": 0.4, "TRANS": 0.4})
    """

    def __init__(
        self,
        config: TongueConfig = TongueConfig(),
        comm=MPI.COMM_WORLD,
        data: TongueData | None = None,
    ):
        self.config = config
        self.data = data or load_tongue_data(config.level)
        domain, _ = to_dolfinx(self.data.mesh, comm)
        material = MooneyRivlin(config.C10, C20=config.C20, kappa=config.kappa)
        self.body = FemBody(
            domain,
            material,
            config.density,
            rayleigh=config.rayleigh,
            gravity=(0.0, 0.0, 0.0),
            incompressibility=config.incompressibility,
            name="tongue",
        )
        self.body.fix_nodes(self.data.fixed_nodes)
        for name, rows in self.data.bundles.items():
            self.body.add_muscle(
                name,
                rows,
                self.data.directions[name],
                BlemkerFiber(max_stress=self.data.max_stress[name]),
            )
        self.scene = Scene(
            gravity=(0.0, 0.0, 0.0),
            integrator=config.integrator,
            linear_solver=config.linear_solver,
        )
        self.scene.add(self.body)

    @property
    def exciters(self) -> list[str]:
        return sorted(self.data.exciters)

    def _bundles_of(self, exciter: str) -> list[str]:
        if exciter not in self.data.exciters:
            raise UnknownNameError(
                f"unknown muscle {exciter!r}; the tongue's exciters are {', '.join(self.exciters)}"
            )
        return self.data.exciters[exciter]

    def landmark_records(self) -> dict:
        """name -> f(scene): the landmark's displacement (m), for ``simulate(record=...)``."""
        body = self.body
        return {
            name: (lambda scene, n=node: body.displacement_at([n])[0])
            for name, node in self.data.landmarks.items()
        }

    def set_excitations(self, excitations: dict[str, float]) -> None:
        """Set exciters (both bundles of a bilateral muscle) to the given levels."""
        for exciter, value in excitations.items():
            for bundle in self._bundles_of(exciter):
                self.body.set_excitation(bundle, value)

    def bundle_schedule(self, schedule: ExcitationSchedule) -> ExcitationSchedule:
        """The schedule of exciters expanded to the bundles they drive."""
        values = {}
        for exciter, vals in schedule.values.items():
            for bundle in self._bundles_of(exciter):
                values[bundle] = vals
        return ExcitationSchedule(schedule.times, values)

    def reset(self) -> None:
        """Back to rest: zero displacement, velocity, pressures, excitations and time."""
        self.body.u.x.array[:] = 0.0
        self.body.v.x.array[:] = 0.0
        if self.body.volume_constraint is not None:
            self.body.volume_constraint.p.x.array[:] = 0.0
        for name in self.body.muscles:
            self.body.set_excitation(name, 0.0)
        self.scene.t = 0.0
        self.scene.min_det_F = np.inf
        self.scene.halvings = 0
        self.scene.fallbacks = 0

    def drive(self, schedule: ExcitationSchedule) -> None:
        """Apply an exciter schedule at every step (replacing earlier ones)."""
        self.scene.controllers.clear()
        self.scene.add_controller(self.bundle_schedule(schedule).controller(self.body))

    @staticmethod
    def motion(name: str) -> ExcitationSchedule:
        """A speech motion of the seed paper: ramp over [0, 0.5] s, then hold."""
        if name not in MOTIONS:
            raise UnknownNameError(f"unknown motion {name!r}; choose one of {sorted(MOTIONS)}")
        return ExcitationSchedule.ramp_and_hold(MOTIONS[name], RAMP_TIME)


# ---- the runner's tongue (``artifem simulate tongue``) -------------------------------------


def build(
    case: str,
    level: int = 0,
    integrator: str = "semi-implicit",
    incompressibility: str = "hard",
    schedule: Path | None = None,
) -> Built:
    """The tongue driven by the speech motion ``case`` (or by the exciter ``schedule``
    file), for :mod:`artifem.models.runner`: the landmarks' displacements and the volume
    change recorded, the element pressures reported with the hard constraint."""
    hard = incompressibility == "hard"
    tongue = Tongue(
        TongueConfig(
            level=level, integrator=integrator, incompressibility=HARD if hard else PENALTY
        )
    )
    motion = Tongue.motion(case) if schedule is None else ExcitationSchedule.from_file(schedule)
    tongue.drive(motion)  # an unknown exciter fails here, before any work
    body = tongue.body
    rest_volume = body.volume()
    record = tongue.landmark_records()
    record["volume_change"] = lambda scene: body.volume() / rest_volume - 1.0

    def figures(run) -> dict:
        def mm(name, t):
            k = int(np.argmin(abs(run.times - t)))
            return np.round(1e3 * run.records[name][k], 3).tolist()

        volume = np.asarray(run.records["volume_change"], dtype=float)
        end, ramp_end = run.times[-1], min(RAMP_TIME, run.times[-1])
        vc = body.volume_constraint
        return {
            "data": "artisynth_hex_tongue",
            "motion": case if schedule is None else schedule.stem,
            "linear_solver": tongue.config.linear_solver,
            "incompressibility": incompressibility,
            "volume_change": float(volume[-1]),
            "max_volume_change": float(np.abs(volume).max()),
            "pressure_range_Pa": list(vc.pressure_range()) if vc is not None else None,
            "landmarks": {name: mm(name, end) for name in LANDMARKS},
            "landmarks_at_ramp_end": {name: mm(name, ramp_end) for name in LANDMARKS},
            "units": {
                "landmarks": "mm, displacement from rest",
                "ms_per_step": "median wall ms",
                "volume_change": "V / V0 - 1 at the end; max_volume_change: max |V / V0 - 1|",
                "pressure_range_Pa": "element pressures (> 0 in compression), hard only",
            },
        }

    name = None if schedule is None else schedule.stem
    return Built(tongue.scene, record=record, figures=figures, name=name)


def _options(group) -> None:
    group.add_argument(
        "--incompressibility",
        default="hard",
        choices=("hard", "penalty"),
        help="element volumes held to 1e-4 (augmented Lagrangian; the default), "
        "or the element-wise penalty 100 C10",
    )
    group.add_argument(
        "--schedule",
        type=Path,
        help='drive this exciter schedule JSON instead of the case\'s motion: {"times": '
        '[...], "excitations": {"GGP": [...], ...}}',
    )


MODEL = Model(
    name="tongue",
    summary="ArtiSynth hex tongue: protrusion, retroflexion, retraction",
    build=build,
    cases={name: "+".join(f"{k} {v:g}" for k, v in e.items()) for name, e in MOTIONS.items()},
    levels={0: "as shipped (946 nodes)", 1: "every hexahedron split 2x2x2 (6,699 nodes)"},
    dt=DT,
    duration=DURATION,
    camera="xz",
    options=_options,
)
add_arguments, run = command(MODEL)
