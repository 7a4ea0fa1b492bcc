"""The styloglossus as two external point-to-point muscles on the tongue (Lloyd et al. 2019,
section 3.1, Figs. 9-10): 4 versus 24 support nodes, signed or non-negative weights, equal
excitation or equal tension, full or reduced tongue, and the resulting stress fields.

Scene. The level-0 ArtiSynth hex tongue (models.tongue: Mooney-Rivlin C10 = 1037 Pa,
C20 = 486 Pa, kappa = 10370 Pa, element-wise incompressibility penalty 100 C10
(:data:`~artifem.models.tongue.model.PENALTY`, not the tongue's default hard constraint:
this study's reduced tongue has no reduced pressure space and its von Mises stress is that
of the penalty's energy), Rayleigh
40 M + 0.03 K, jaw and hyoid attachment nodes fixed; internal muscles unexcited) in a
:class:`~artifem.scene.Scene` without gravity, and two
:class:`~artifem.scene.PointPath` elements (left, right) from the styloid points of
ArtiSynth's HexTongueDemo, (0.14984, +-0.035891, 0.125) m (19 mm behind, 3.3 mm lateral to
and 11 mm above the tongue's bounding box), to attachment points on the tongue: the centroid
of the free boundary facet nearest to each styloid point (ArtiSynth's choice not found), on
the lateral-posterior surface.

Supports (:data:`SUPPORTS`): the 4 or 24 nearest nodes (``nearest_nodes``) with the
minimum-norm weights (``support_weights``: sum w = 1, sum w_j X_j = X_a; signed, down to
-0.106 for 4 and -0.080 for 24 nodes), or the 24 nearest with the minimum-norm non-negative
weights (``support_weights(..., nonnegative=True)``). The attachment point lies on a face of
the convex hull of its nearest nodes, and non-negative weights of a point on a hull face can
only use the nodes of that face: 97% of the weight lands on the facet's own 4 nodes.

Loads: a Thelen 2003 muscle (rigid tendon, F0 = 3 N per side, optimal fiber length 0.8 L,
tendon slack 0.2 L, L the initial styloid-attachment distance) at excitation e(t) (ramp
0 -> 1 over 0.5 s, held to 1 s), or, for equal tension, :class:`PrescribedTension`
T = 1.5 N e(t) along the path (f = -T dL/dx, K = -T d2L/dx2, D = 0). h = 0.01 s.

Reduced tongue (:func:`reduce_tongue`, through the reductor): each support is its own model
(:func:`reducible`: the scene at the prescribed tension 2 N, above the test's 1.5 N, whose
path excitations ``left`` and ``right`` are load inputs, ``PathExcitation``). Training: each
side alone, ramped and held (2 runs); POD (r = 20, mass-weighted) and ECSW points (tol
1e-3, reached at 105-131 points before the 300 asked for), cached. The tongue study's basis,
trained on the internal muscles, does not contain point loads on the lateral surface, and
linear modes miss the large local strains at the attachment. The comparison pulls both
sides at once: combinations not in the training set. The reductor carries each path onto
the reduced tongue (``PointPath.onto_reduced``): ``FemPoint(reduced, w)``,
G = sum_j w_j U_j; u = U q is rebuilt on the full mesh only for the stress and the picture.

Stress: Cauchy sigma = (1/J) P F^T with P = d psi/dF (ufl.diff) of the passive energy, at cell
centres (DG0), von Mises; "near the attachment" = cells with a node within 12 mm of the
attachment's rest position.

``artifem simulate styloglossus --case C`` runs one support through the runner
(:mod:`artifem.models.runner`); ``artifem study styloglossus``
(:mod:`artifem.models.styloglossus.study`) compares them, full and reduced
(docs/styloglossus.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
import numpy as np
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from mpi4py import MPI
from scipy.spatial import cKDTree

from artifem.arguments import nonnegative_float
from artifem.errors import InputError
from artifem.models.tongue.model import PENALTY, Tongue, TongueConfig
from artifem.multibody.attachments import FemPoint
from artifem.multibody.point_paths import PointPath
from artifem.models.runner import Built, Model, command
from artifem.scene import Scene
from artifem.multibody.muscles import PathForces, PathGeometry, ThelenMuscle, ThelenParameters
from artifem.multibody.point_attachments import nearest_nodes, support_weights
from artifem.reduction.reductor import (
    ReducibleScene,
)
from artifem.scene.inputs import PathExcitation
from artifem.stress import von_mises

STYLOID = {
    "left": np.array([0.14984, 0.035891, 0.125]),
    "right": np.array([0.14984, -0.035891, 0.125]),
}
MAX_FORCE = 3.0
TENSION = 1.5
RAMP, DURATION, DT = 0.5, 1.0, 0.01
#: configuration -> (support nodes k, non-negative weights)
SUPPORTS = {"4": (4, False), "24": (24, False), "24+": (24, True)}
LABELS = {"4": "4 nodes", "24": "24 nodes, min-norm", "24+": "24 nodes, w >= 0"}


@dataclass(frozen=True)
class ReducedConfig:
    r: int = 20  # POD vectors
    points: int = 300  # trained integration points (ECSW)
    training_tension: float = 2.0  # N, each side alone, each support of SUPPORTS
    snapshot_every: int = 2
    force_snapshots: int = 120
    cubature_tol: float = 1e-3


class PrescribedTension:
    """A force-controlled path element: T = max_force * e(t), independent of L and Ldot, so
    f = -T dL/dx, K = df/dx = -T H (the follower term), D = 0 (muscles.PathForces)."""

    def __init__(self, max_force: float):
        if not np.isfinite(max_force) or max_force < 0:
            raise InputError(
                f"PrescribedTension: max_force must be finite and >= 0, got {max_force!r}"
            )
        self.max_force, self.excitation = float(max_force), 0.0

    def set_excitation(self, value: float) -> None:
        self.excitation = float(value)

    def evaluate(self, positions, velocities=None, dt=None) -> PathForces:
        return PathForces.from_tension(
            PathGeometry.of(positions, velocities), self.max_force * self.excitation, 0.0, 0.0
        )

    def commit(self, result: PathForces) -> None:
        """Stateless."""


def boundary_facet_centroids(body, exclude_dofs=()):
    """(centroids (m, 3), facet node dofs (m, 4)) of the exterior facets of the body's mesh
    that touch none of ``exclude_dofs`` (vertices matched to P1 dofs by coordinates)."""
    msh = body.mesh
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, 0)
    msh.topology.create_connectivity(tdim - 1, tdim)
    msh.topology.create_connectivity(0, tdim)
    facets = dmesh.exterior_facet_indices(msh.topology)
    f2v = msh.topology.connectivity(tdim - 1, 0)
    X = body.V.tabulate_dof_coordinates()
    vert_nodes = dmesh.entities_to_geometry(
        msh, 0, np.arange(msh.topology.index_map(0).size_local, dtype=np.int32)
    ).ravel()
    vert_dof = cKDTree(X).query(msh.geometry.x[vert_nodes])[1]
    excluded = set(int(d) for d in exclude_dofs)
    cents, dofs = [], []
    for f in facets:
        d = vert_dof[f2v.links(f)]
        if not excluded.intersection(d.tolist()):
            cents.append(X[d].mean(axis=0))
            dofs.append(d)
    return np.array(cents), np.array(dofs)


def attachment_points(body) -> dict[str, np.ndarray]:
    """Per side, the centroid of the free boundary facet nearest to its styloid point."""
    cents, _ = boundary_facet_centroids(body, body.fixed_dofs)
    return {
        side: cents[np.argmin(np.linalg.norm(cents - s, axis=1))] for side, s in STYLOID.items()
    }


def excitation(t: float) -> float:
    return float(min(1.0, max(0.0, t / RAMP)))


def von_mises_dg0(body, config: TongueConfig) -> fem.Function:
    """DG0 von Mises stress of the passive energy, with the scene's volumetric penalty."""
    penalty = config.incompressibility
    return von_mises(
        body, None if penalty is None else lambda F: 0.5 * penalty * (ufl.det(F) - 1) ** 2
    )


def cells_near(body, point, radius) -> np.ndarray:
    """Cells with a node within ``radius`` of ``point``."""
    msh = body.mesh
    d = np.linalg.norm(msh.geometry.x[msh.geometry.dofmaps[0]] - point, axis=2).min(axis=1)
    return np.flatnonzero(d <= radius)


def build_scene(
    support: int = 4,
    *,
    nonnegative: bool = False,
    load: str = "thelen",
    tension: float = TENSION,
    sides=tuple(STYLOID),
    excitation=excitation,
    data=None,
    config: TongueConfig = TongueConfig(level=0, incompressibility=PENALTY),
) -> Scene:
    """The full tongue (named ``tongue``) and the styloglossus of ``sides`` on ``support``
    nearest nodes (min-norm or non-negative weights), each a path ``STY_<side>`` of a
    Thelen muscle (``load="thelen"``) or of the prescribed tension T = ``tension`` e
    (``load="tension"``), excited by ``excitation(t)`` (None: by a scene input)."""
    if load not in ("thelen", "tension"):
        raise InputError(f"styloglossus: load must be 'thelen' or 'tension', got {load!r}")
    unknown = set(sides) - set(STYLOID)
    if unknown or not sides:
        raise InputError(f"styloglossus: sides must be among {sorted(STYLOID)}, got {sides!r}")
    body = Tongue(config, comm=MPI.COMM_SELF, data=data).body
    scene = Scene(gravity=(0.0, 0.0, 0.0), integrator=config.integrator)
    scene.add(body)
    for side, p in attachment_points(body).items():
        if side not in sides:
            continue
        w = support_weights(body, p, nearest_nodes(body, p, support), nonnegative=nonnegative)
        L = float(np.linalg.norm(STYLOID[side] - p))
        element = (
            ThelenMuscle(ThelenParameters(MAX_FORCE, 0.8 * L, 0.2 * L), name=f"STY_{side}")
            if load == "thelen"
            else PrescribedTension(tension)
        )
        scene.add(
            PointPath(
                element,
                [STYLOID[side], FemPoint(body, w, name=f"STY_{side}")],
                excitation=excitation,
                name=f"STY_{side}",
            )
        )
    return scene


def reducible(
    support: str = "24", rc: ReducedConfig = ReducedConfig(), *, data=None
) -> ReducibleScene:
    """The scene of support ``support`` (a key of :data:`SUPPORTS`) as a reductor's model:
    both sides at the prescribed tension ``rc.training_tension`` e, e the load inputs
    ``left`` and ``right`` (path excitations); the tongue's own muscles are not inputs."""
    if support not in SUPPORTS:
        raise InputError(
            f"styloglossus: unknown support {support!r}; choose one of {sorted(SUPPORTS)}"
        )
    k, nonnegative = SUPPORTS[support]
    return ReducibleScene(
        "styloglossus",
        lambda: build_scene(
            k,
            nonnegative=nonnegative,
            load="tension",
            tension=rc.training_tension,
            excitation=None,
            data=data,
        ),
        "tongue",
        {
            "model": "styloglossus",
            "support": support,
            "tension": rc.training_tension,
            "level": 0,
            "penalty": PENALTY,
        },
        exciters={},
        loads={side: PathExcitation(f"STY_{side}") for side in STYLOID},
    )


# ---- the runner's styloglossus (``artifem simulate styloglossus``) -------------------------

#: case name -> support (a key of :data:`SUPPORTS`)
CASES = {"4-nodes": "4", "24-nodes": "24", "24-nodes-positive": "24+"}


def build(
    case: str,
    level: int = 0,
    integrator: str = "semi-implicit",
    load: str = "thelen",
    tension: float = TENSION,
) -> Built:
    """Both styloglossi on the support of ``case`` (:data:`CASES`), a Thelen muscle
    (``load="thelen"``) or the prescribed ``tension``, excited by e(t), for
    :mod:`artifem.models.runner`; the figures: each side's tension, the attachment's
    displacement and the peak von Mises stress near it (module docstring)."""
    config = TongueConfig(level=level, incompressibility=PENALTY, integrator=integrator)
    k, nonnegative = SUPPORTS[CASES[case]]
    scene = build_scene(k, nonnegative=nonnegative, load=load, tension=tension, config=config)
    body = scene.fem_bodies[0]
    paths = {p.name.removeprefix("STY_"): p for p in scene.paths}
    points = {side: path.points[-1] for side, path in paths.items()}
    rest = {side: p.weights.rest_position for side, p in points.items()}

    def figures(run) -> dict:
        vm = von_mises_dg0(body, config)
        near = {s: float(vm.x.array[cells_near(body, p, 0.012)].max()) for s, p in rest.items()}
        return {
            "support_nodes": k,
            "nonnegative": nonnegative,
            "load": load,
            "tension_N": {s: p.tension() for s, p in paths.items()},
            "attachment_displacement_mm": {
                s: (1e3 * (points[s].position() - rest[s])).tolist() for s in rest
            },
            "peak_von_mises_near_attachment_Pa": near,
            "peak_von_mises_Pa": float(vm.x.array.max()),
            "min_weight": {s: float(p.weights.weights.min()) for s, p in points.items()},
        }

    return Built(scene, figures=figures)


def _options(group) -> None:
    group.add_argument(
        "--load",
        default="thelen",
        choices=("thelen", "tension"),
        help="a Thelen muscle (F0 = 3 N per side) or the prescribed --tension (%(default)s)",
    )
    group.add_argument(
        "--tension",
        type=nonnegative_float,
        default=TENSION,
        help="the prescribed tension per side (N) of --load tension (%(default)s)",
    )


MODEL = Model(
    name="styloglossus",
    summary="external styloglossus on 4 vs 24 support nodes: stress at equal excitation "
    "and tension, w >= 0, reduced tongue",
    build=build,
    cases={
        "4-nodes": "each path's end on the 4 nearest nodes (minimum-norm weights)",
        "24-nodes": "on the 24 nearest nodes (minimum-norm weights)",
        "24-nodes-positive": "on the 24 nearest nodes (non-negative weights)",
    },
    levels={0: "the level-0 tongue (946 nodes)"},
    dt=DT,
    duration=DURATION,
    options=_options,
)
add_arguments, run = command(MODEL)
