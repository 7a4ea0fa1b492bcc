"""The airway: a skin over the tongue, the jaw and the palate, loaded by the air inside it
(Lloyd et al. 2019, section 4.1 and Fig. 13).

Scene
-----
- The jaw-tongue scene of :mod:`artifem.models.jaw_tongue.model` as it is (level-0 FEM tongue,
  rigid jaw on a hinge, opener muscle and closing spring, gravity), built by its
  ``build_scene``.
- The hard palate: ArtiSynth's palate1.obj as a *fixed* rigid body (``motion="fixed"``; a
  nominal mass, never used). Fixed bodies have no dofs: the load the skin puts on the palate
  is the skull's reaction, reported but not simulated.
- The airway surface: ArtiSynth's airway.obj (a tube from the larynx, up the pharynx, over
  the tongue to the lips, with 58 cross-section planes in its ``s`` lines), aligned to the
  tongue (below), its two open ends (glottis, lips) capped by centroid fans, oriented outward.
- The skin (:class:`~artifem.multibody.skin.SkinMesh`): every vertex follows the tongue
  (FemMaster: the shape functions of its rest position, snapped to the nearest element when
  outside), the jaw and the palate (RigidMasters, distances to their surface vertices),
  q_v = q_v0 + sum_i w_vi f_i with inverse-square weights w_vi ~ 1 / d_vi^2 and linear
  blending of the two rigid masters.
- The air: a uniform pressure p(t) (default 1 kPa = 10 cm H2O, about the intra-oral pressure
  of a voiceless stop, ramped over 0.1 s) inside the closed airway (lips and glottis closed),
  a :class:`~artifem.multibody.skin.SkinPressure` load element: f_v = p A_f n_f / 3 per
  face, f_m = G^T f_v onto the tongue's nodes, the jaw's wrench and the palate (virtual
  work), explicit in the coupled step.

Alignment of palate1.obj and airway.obj
---------------------------------------
palate1.obj is already in the tongue's frame: metres, x posterior, y left-right, z up. It
lies over the dorsum and down behind the tongue base without touching it (tongue-to-palate
gap 2.3 mm at its closest, median 10 mm over the dorsum; no palate vertex inside the
tongue). We use it untransformed and write these distances to the JSON.

airway.obj is in millimetres with x anterior, y left-right, z up, the larynx at the origin
side. The map (x, y, z)_obj -> 1e-3 (-x, -y, z) (a rotation by 180 degrees about z, and the
unit) brings it to the tongue's axes; the translation and a residual rotation come from a
trimmed point-to-surface ICP of the airway's vertices against the union of the tongue's
boundary and the palate (each iteration: the closest target point of every vertex, keep the
closest half, Kabsch fit), started from a 5 x 5 grid of translations (+-30 mm in x and z)
around the tongue's top (10 iterations each), the best three run to convergence, keeping
the one with the smallest mean distance of the fitted half. The airway's floor then lies on
the dorsum and its roof under the palate; its pharynx runs below the tongue, where there is
nothing to fit. Measured: residual rotation 2.8 degrees, distance of the fitted half 0.79 mm
mean, all vertices 1.8 mm median (the pharynx below the tongue up to 27 mm), 7 % of the
vertices inside the tongue (at most 2.1 mm deep). It is a best fit of meshes from different
subjects, not a registration.

Reduced tongue
--------------
``build_scene(..., reduced=reduced_tongue(config, cache))`` puts the reduced tongue of
:mod:`artifem.models.jaw_tongue.reduced` in the scene (same training and cache:
u = u_bar + U q + L g, U a trained POD basis, L the 12 jaw-lift columns whose coordinates g
are slaves of the jaw). The skin's tongue master is then that ReducedFemBody
(``ReducedMaster``): x_v = X_v + w_v N(X_v) (u_bar + [U, L] q) + the rigid terms, and the
air's load on it is the generalized force [U, L]^T N^T (w_v f_v); its POD part drives q, its
lift part reaches the jaw as G_g^T f_g (coupled system, P^T). :func:`compare` measures the
reduced airway against the full one run by run; ``--reduced`` adds that to the report.

Measurements
------------
- Cross-section areas along the airway: each of the airway's section planes cut the rest
  surface in a loop of points on its edges, p = (1 - s) x_a + s x_b; the loop moves with the
  skin (material sections, as ArtiSynth's AirwayMesh), its area is
  |1/2 sum (p_i - c) x (p_i+1 - c)| (c its centroid) and
  the length coordinate the cumulative distance of the loop centroids from the larynx.
- The skin's distance to the tongue: the signed distance to the deformed tongue surface of
  the vertices the tongue dominates (weight >= 0.9), minus its rest value.
- Tip and top (ArtiSynth's landmarks) displacements, the jaw's opening angle, with and
  without the pressure, and the load's resultant on each master.

``artifem simulate airway --case C [--pressure P] [--tongue full|reduced --cache DIR]``
runs one tongue motion in the airway through the runner (:mod:`artifem.models.runner`);
``artifem study airway [--reduced]``
(:mod:`artifem.models.airway.study`) runs them all, with and without the air, full and
reduced (docs/airway.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
import numpy as np
import pyvista as pv

from artifem.arguments import nonnegative_float
from artifem.errors import InputError
from artifem.models.jaw_tongue import model as jt
from artifem.models.cache import user_cache
from artifem.models.jaw_tongue import reduced as jtr
from artifem.models.jaw_tongue.model import JawTongueConfig, close_surface, read_obj
from artifem.models.tongue.model import DATA, Tongue, load_tongue_data
from artifem.multibody.rigid_body import RigidBody
from artifem.multibody.skin import RigidMaster, SkinMesh, SkinPressure
from artifem.reduction.reductor import ReducedModel
from artifem.registration import TriangleSurface, icp
from artifem.models.airway.render import polydata, render
from artifem.models.runner import Built, Model, command

__all__ = [
    "AirwayConfig",
    "AirwayScene",
    "Sections",
    "align_airway",
    "build_scene",
    "read_sections",
    "reduced_tongue",
    "run_figures",
    "MODEL",
]

#: airway.obj axes -> tongue axes: (x, y, z)_obj -> (-x, -y, z)_tongue (det +1).
AIRWAY_AXES = np.diag([-1.0, -1.0, 1.0])
#: where the reduced tongue's training is cached (shared with jaw_tongue.study.benchmark).
DEFAULT_CACHE = user_cache("jaw_tongue_reduced")
#: the tongues the airway runs over (``--tongue``).
TONGUES = {
    "full": "the FEM tongue",
    "reduced": f"the jaw-tongue's reduced tongue (POD {jtr.ReducedJawTongueConfig.r} + 12 "
    f"jaw-lift columns, {jtr.ReducedJawTongueConfig.points} points; trained once into --cache)",
}


@dataclass(frozen=True)
class AirwayConfig:
    jaw_tongue: JawTongueConfig = JawTongueConfig()
    #: Air pressure inside the airway (Pa) and its linear ramp time (s).
    pressure: float = 1000.0
    pressure_ramp: float = 0.1
    pressure_start: float = 0.0
    weighting: str = "inverse_square"
    blending: str = "linear"
    #: Fraction of the airway's vertices the trimmed ICP fits.
    trim: float = 0.5

    def __post_init__(self):
        if not np.isfinite(self.pressure):
            raise InputError(f"airway: pressure must be finite, got {self.pressure!r}")
        if not self.pressure_ramp > 0:
            raise InputError(f"airway: pressure_ramp must be > 0, got {self.pressure_ramp!r}")
        if not 0.1 <= self.trim <= 1.0:
            raise InputError(f"airway: trim must be in [0.1, 1], got {self.trim!r}")


# ---- geometry ---------------------------------------------------------------------------


def read_sections(path: Path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The ``s nx ny nz d [name]`` lines of a sectioned OBJ (ArtiSynth's SectionedMesh): the
    planes n . x = d, as (normals (k, 3), offsets (k,), names)."""
    normals, offsets, names = [], [], []
    for lineno, line in enumerate(Path(path).read_text().splitlines(), 1):
        parts = line.split()
        if parts and parts[0] == "s":
            if len(parts) < 5:
                raise InputError(f"{path}:{lineno}: expected 's nx ny nz d [name]', got {line!r}")
            n = np.array([float(v) for v in parts[1:4]])
            if not np.isclose(np.linalg.norm(n), 1.0, atol=1e-3):
                raise InputError(f"{path}:{lineno}: section normal {n} is not a unit vector")
            normals.append(n / np.linalg.norm(n))
            offsets.append(float(parts[4]))
            names.append(" ".join(parts[5:]))
    if not normals:
        raise InputError(f"{path}: no section planes ('s' lines)")
    return np.array(normals), np.array(offsets), names


class TongueSurface:
    """The tongue's boundary triangles, deformable: points X + u of the surface nodes, u the
    scene's tongue displacement (full, or u_bar + U q of a reduced tongue)."""

    def __init__(self, s: jt.JawTongueScene, points: np.ndarray, hexes: np.ndarray):
        grid = pv.UnstructuredGrid({pv.CellType.HEXAHEDRON: hexes}, points)
        surf = grid.extract_surface(algorithm="dataset_surface").triangulate()
        self.rows = np.asarray(surf.point_data["vtkOriginalPointIds"], dtype=np.int64)
        self.rest = surf.points.copy()
        self.dofs = s.tongue.body.local_dofs(self.rows).astype(np.int64)
        self.triangles = surf.faces.reshape(-1, 4)[:, 1:]
        self.scene = s

    def polydata(self, deformed: bool = True):
        x = self.rest.copy()
        if deformed:
            x += self.scene.tongue_displacement().reshape(-1, 3)[self.dofs]
        return polydata(x, self.triangles)

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (negative inside) of points to the deformed surface."""
        probe = pv.PolyData(np.asarray(points, dtype=float))
        return np.asarray(probe.compute_implicit_distance(self.polydata())["implicit_distance"])


def align_airway(vertices_mm: np.ndarray, tongue, palate, trim: float = 0.5) -> dict:
    """x_tongue = linear x_obj + translation for airway.obj (module docstring): the axis map
    AIRWAY_AXES, mm -> m, then a trimmed ICP onto the tongue surface and the palate
    (pyvista PolyData, tongue frame): 25 starts, 10 iterations each, then the best three
    to convergence. Returns the transform and the residuals."""
    base = 1e-3 * np.asarray(vertices_mm, dtype=float) @ AIRWAY_AXES.T
    target = TriangleSurface.from_polydata(
        tongue.merge(palate).extract_surface(algorithm="dataset_surface")
    )
    lo, hi = np.array(tongue.bounds).reshape(3, 2).T
    # the palate's open border keeps its pairs: the trim already drops the far ones, and
    # the documented airway (docs/airway.md, scenes.json) was aligned so
    tols = dict(trim=trim, rotation_tol=1e-7, translation_tol=1e-8, drop_border=False)
    starts = []
    for dx in np.linspace(-0.03, 0.03, 5):
        for dz in np.linspace(-0.03, 0.03, 5):
            t = np.array([0.5 * (lo[0] + hi[0]) + dx, 0.0, hi[2] + dz]) - base.mean(0)
            starts.append(icp(base, target, np.eye(3), t, iterations=10, **tols))
    starts.sort(key=lambda start: start.score)
    fit = min(
        (icp(base, target, s.R, s.t, iterations=60, **tols) for s in starts[:3]),
        key=lambda fit: fit.score,
    )
    R, t, score, r = fit.R, fit.t, fit.score, fit.distances
    x = base @ R.T + t
    depth = np.asarray(pv.PolyData(x).compute_implicit_distance(tongue)["implicit_distance"])
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    return {
        "linear": 1e-3 * R @ AIRWAY_AXES,
        "translation": t,
        "distances": r,
        "trimmed_mean_distance": float(score),
        "median_distance": float(np.median(r)),
        "p75_distance": float(np.quantile(r, 0.75)),
        "max_distance": float(r.max()),
        "fraction_inside_tongue": float((depth < 0).mean()),
        "max_depth_inside_tongue": float(max(0.0, -depth.min())),
        "residual_rotation_deg": float(angle),
        "trim": trim,
    }


@lru_cache(maxsize=2)
def _aligned_airway(trim: float):
    """Aligned, capped, outward airway (vertices, triangles, sections, alignment), cached
    per process (the ICP takes seconds and depends only on the data files)."""
    data = load_tongue_data(0)
    vertices_mm, triangles = read_obj(DATA / "airway.obj")
    normals, offsets, names = read_sections(DATA / "airway.obj")
    palate_v, palate_t = read_obj(DATA / "palate1.obj")
    grid = pv.UnstructuredGrid({pv.CellType.HEXAHEDRON: data.mesh.cells}, data.mesh.points)
    tongue_poly = grid.extract_surface(algorithm="dataset_surface").triangulate()
    palate = polydata(palate_v, palate_t)
    alignment = align_airway(vertices_mm, tongue_poly, palate, trim)
    closed_mm, closed_t, holes, flipped = close_surface(vertices_mm, triangles)
    _check_closed(closed_t)
    x = closed_mm @ alignment["linear"].T + alignment["translation"]
    volume = _volume(x, closed_t)
    if volume < 0:
        closed_t = closed_t[:, ::-1]
        volume = -volume
    sections = Sections.cut(closed_mm, closed_t, normals, offsets, names, len(vertices_mm))
    gap_pal = np.asarray(
        pv.PolyData(palate_v).compute_implicit_distance(tongue_poly)["implicit_distance"]
    )
    alignment.update(
        holes_capped=holes,
        triangles_flipped=flipped,
        volume_m3=float(volume),
        palate={
            "transform": "identity (already in the tongue frame, metres)",
            "min_gap_to_tongue_m": float(gap_pal.min()),
            "median_gap_to_tongue_m": float(np.median(gap_pal)),
            "vertices_inside_tongue": int((gap_pal < 0).sum()),
        },
    )
    return x, closed_t, sections, alignment, (palate_v, palate_t)


def _check_closed(triangles: np.ndarray) -> None:
    """Every directed edge once and its opposite once: closed and consistently oriented."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    keys = {(int(a), int(b)) for a, b in e}
    if len(keys) != len(e) or any((b, a) not in keys for a, b in keys):
        raise InputError("airway: the capped surface is not closed and consistently oriented")


def _volume(x: np.ndarray, triangles: np.ndarray) -> float:
    a, b, c = (x[triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->", np.cross(b - a, c - a), a) / 6.0)


@dataclass
class Sections:
    """Material cross-sections of a triangle surface: per plane, a loop of edge points
    p = (1 - s) x_a + s x_b cut at rest, that moves with the surface (module docstring)."""

    a: list[np.ndarray]
    b: list[np.ndarray]
    s: list[np.ndarray]
    names: list[str]
    plane_index: np.ndarray
    #: the section's loop runs on the tube only (not over a cap).
    interior: np.ndarray

    @classmethod
    def cut(
        cls, X: np.ndarray, triangles: np.ndarray, normals, offsets, names, caps_from: int
    ) -> Sections:
        """Cut the rest surface X (any frame the planes n . x = d are given in) by each plane;
        where a plane cuts the tube more than once, keep the loop nearest the previous
        section's centroid (the first: the lowest loop, at the larynx). Vertices from
        ``caps_from`` on are cap centres: a loop through them is not ``interior``."""
        A, B, S, kept, prev = [], [], [], [], None
        for k, (n, d) in enumerate(zip(normals, offsets)):
            loops = _plane_loops(X, triangles, n, d)
            if not loops:
                continue
            cents = [((1 - s)[:, None] * X[a] + s[:, None] * X[b]).mean(0) for a, b, s in loops]
            pick = (
                int(np.argmin([c[2] for c in cents]))
                if prev is None
                else int(np.argmin([np.linalg.norm(c - prev) for c in cents]))
            )
            a, b, s = loops[pick]
            A.append(a), B.append(b), S.append(s), kept.append(k)
            prev = cents[pick]
        if not kept:
            raise InputError("airway: no section plane cuts the surface")
        interior = np.array([a.max() < caps_from and b.max() < caps_from for a, b in zip(A, B)])
        return cls(A, B, S, [names[k] for k in kept], np.array(kept), interior)

    def points(self, x: np.ndarray) -> list[np.ndarray]:
        return [
            (1 - s)[:, None] * x[a] + s[:, None] * x[b] for a, b, s in zip(self.a, self.b, self.s)
        ]

    def areas(self, x: np.ndarray) -> np.ndarray:
        """|1/2 sum_i (p_i - c) x (p_i+1 - c)| per section (c: the loop's centroid) at vertex
        positions x."""
        out = []
        for p in self.points(x):
            d = p - p.mean(0)
            out.append(0.5 * np.linalg.norm(np.cross(d, np.roll(d, -1, axis=0)).sum(0)))
        return np.array(out)

    def length(self, x: np.ndarray) -> np.ndarray:
        """Cumulative distance of the section centroids from the first (larynx)."""
        c = np.array([p.mean(0) for p in self.points(x)])
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(c, axis=0), axis=1))])


def _plane_loops(X, triangles, n, d):
    """Closed loops [(a, b, s)] where the plane n . x = d cuts the surface's edges."""
    h = X @ n - d
    pos = h > 0
    nodes, nbrs = {}, {}
    for tri in triangles:
        crossing = [
            (int(tri[i]), int(tri[(i + 1) % 3]))
            for i in range(3)
            if pos[tri[i]] != pos[tri[(i + 1) % 3]]
        ]
        if len(crossing) != 2:
            continue
        keys = [tuple(sorted(e)) for e in crossing]
        for key in keys:
            if key not in nodes:
                i, j = key
                nodes[key] = (i, j, h[i] / (h[i] - h[j]))
        nbrs.setdefault(keys[0], []).append(keys[1])
        nbrs.setdefault(keys[1], []).append(keys[0])
    loops, seen = [], set()
    for start in nbrs:
        if start in seen:
            continue
        loop, prev, cur = [start], None, start
        seen.add(start)
        while True:
            nxt = [k for k in nbrs[cur] if k != prev]
            if not nxt or nxt[0] == start:
                break
            prev, cur = cur, nxt[0]
            if cur in seen:
                break
            loop.append(cur)
            seen.add(cur)
        if len(loop) >= 3:
            a, b, s = (np.array(v) for v in zip(*(nodes[k] for k in loop)))
            loops.append((a, b, s))
    return loops


# ---- scene --------------------------------------------------------------------------------


@dataclass
class AirwayScene:
    jt: jt.JawTongueScene
    palate: RigidBody
    skin: SkinMesh
    pressure: SkinPressure
    pressure_on: bool
    sections: Sections
    alignment: dict
    surface: TongueSurface
    tongue_vertices: np.ndarray  # skin vertices with tongue weight >= 0.9
    config: AirwayConfig = field(default_factory=AirwayConfig)

    @property
    def scene(self):
        return self.jt.scene


def reduced_tongue(
    config: AirwayConfig,
    cache: Path,
    base: jtr.ReducedJawTongueConfig = jtr.ReducedJawTongueConfig(),
) -> ReducedModel:
    """The jaw-tongue reduced tongue (POD + 12 jaw-lift columns, trained points) for this
    airway's jaw-tongue scene: ``jaw_tongue.reduced.train`` with ``base``'s training settings
    and the airway's jaw-tongue config, cached under ``cache``."""
    return jtr.train(replace(base, jaw=config.jaw_tongue), Path(cache))


def build_scene(
    config: AirwayConfig = AirwayConfig(),
    *,
    pressure: bool = True,
    data=None,
    reduced: ReducedModel | None = None,
) -> AirwayScene:
    """The jaw-tongue scene, the fixed palate, the airway skin and (``pressure``) its air
    pressure load (module docstring). With ``reduced`` (from :func:`reduced_tongue`) the
    tongue is the reduced one, u = U q + L g (jaw_tongue.reduced), and the skin's tongue
    master is that ReducedFemBody: x_v = X_v + w_v N(X_v) (u_bar + [U, L] q) + rigid terms,
    and the air's load on it is the generalized force [U, L]^T N^T (w f_v), its lift part
    reaching the jaw as G_g^T f_g."""
    data = data or load_tongue_data(0)
    s = jt.build_scene(config.jaw_tongue, data=data, reduce=reduced)
    x, triangles, sections, alignment, (pal_v, pal_t) = _aligned_airway(config.trim)
    centre = pal_v.mean(0)
    palate = RigidBody(
        "palate",
        1e-3,
        1e-9 * np.eye(3),
        position=centre,
        motion="fixed",
        surface=(pal_v - centre, pal_t),
    )
    s.scene.add(palate)
    masters = [
        s.reduced or s.tongue.body,
        RigidMaster(s.jaw, reference=s.jaw.surface[0]),
        RigidMaster(palate, reference=palate.surface[0]),
    ]
    skin = SkinMesh(
        x, triangles, masters, weighting=config.weighting, blending=config.blending, name="airway"
    )
    P, ramp, t0 = config.pressure, config.pressure_ramp, config.pressure_start
    load = SkinPressure(skin, lambda t: P * min(1.0, max(0.0, t - t0) / ramp), name="air")
    if pressure:
        s.scene.add(load)
    surface = TongueSurface(s, data.mesh.points, data.mesh.cells)
    return AirwayScene(
        s,
        palate,
        skin,
        load,
        pressure,
        sections,
        alignment,
        surface,
        np.flatnonzero(skin.weights[:, 0] >= 0.9),
        config,
    )


def run_figures(a: AirwayScene, rec: dict) -> dict:
    """The figures of a run recorded in ``rec`` (the keys of
    :func:`artifem.models.jaw_tongue.records`, ``areas``, ``top``, ``gap_drift``, ``t`` and
    the step times ``ms``): displacements, opening angle, section areas, the skin's drift
    from the tongue."""
    areas = rec["areas"][:, a.sections.interior]
    sections = a.sections.plane_index[a.sections.interior]
    ratio = areas[-1] / areas[0]
    return {
        "ms_per_step_median": float(np.median(rec["ms"])),
        "final_tip_displacement_mm": (1e3 * rec["tip"][-1]).tolist(),
        "final_top_displacement_mm": (1e3 * rec["top"][-1]).tolist(),
        "final_opening_angle_deg": float(np.degrees(rec["angle"][-1])),
        "max_opening_angle_deg": float(np.degrees(rec["angle"]).max()),
        "final_areas_mm2": (1e6 * rec["areas"][-1]).tolist(),
        "min_area_mm2": {
            "rest": float(1e6 * areas[0].min()),
            "final": float(1e6 * areas[-1].min()),
            "final_section": int(sections[np.argmin(areas[-1])]),
        },
        "narrowest_relative": {
            "area_ratio": float(ratio.min()),
            "section": int(sections[np.argmin(ratio)]),
        },
        "widest_relative": {
            "area_ratio": float(ratio.max()),
            "section": int(sections[np.argmax(ratio)]),
        },
        "mean_area_change_percent": float(100 * (areas[-1].sum() / areas[0].sum() - 1)),
        "max_skin_gap_drift_mm": float(1e3 * rec["gap_drift"].max()),
        "max_attachment_error_m": float(rec["attachment_error"].max()),
        "min_area_mm2_vs_t": (1e6 * areas.min(axis=1)).tolist(),
        "t": rec["t"].tolist(),
        "opening_angle_deg": np.degrees(rec["angle"]).tolist(),
    }


# ---- the runner's airway (``artifem simulate airway``) -------------------------------------


def records(a: AirwayScene) -> dict:
    """name -> f(scene) an airway run records beside the jaw-tongue's
    (:func:`artifem.models.jaw_tongue.records`): the skin's positions ``skin``, its largest
    drift from the tongue surface ``gap_drift`` (against rest, over the vertices the tongue
    dominates) and the air ``pressure``."""
    gap0 = a.surface.signed_distance(a.skin.positions()[a.tongue_vertices])

    def gap_drift(scene):
        gap = a.surface.signed_distance(a.skin.positions()[a.tongue_vertices])
        return float(np.abs(gap - gap0).max())

    return {
        "skin": lambda scene: a.skin.positions(),
        "gap_drift": gap_drift,
        "pressure": lambda scene: a.pressure.pressure_at(scene.t) if a.pressure_on else 0.0,
    }


def recorded(a: AirwayScene, rec: dict) -> dict:
    """``rec`` (a run's record) with the section ``areas`` and the ``top`` landmark's
    displacement added, from the recorded ``skin`` and tongue displacement ``u``."""
    top = int(a.jt.tongue.body.local_dofs([a.jt.tongue.data.landmarks["top"]])[0])
    rec["areas"] = np.array([a.sections.areas(x) for x in rec["skin"]])
    rec["top"] = rec["u"].reshape(len(rec["u"]), -1, 3)[:, top]
    return rec


def build(
    case: str,
    level: int = 0,
    integrator: str = "semi-implicit",
    pressure: float = AirwayConfig.pressure,
    tongue: str = "full",
    cache: Path = DEFAULT_CACHE,
) -> Built:
    """The airway scene with the tongue motion ``case`` ("none": the muscles off) and the air
    at ``pressure`` Pa, over the full tongue or (``tongue="reduced"``) the reduced one of
    :func:`reduced_tongue` (trained, or loaded from ``cache``), for
    :mod:`artifem.models.runner`: the picture of the tongue, jaw, palate and skin with the
    airway's mid-sagittal section; :func:`run_figures`."""
    if tongue not in TONGUES:
        raise InputError(f"airway: tongue must be one of {list(TONGUES)}, got {tongue!r}")
    config = AirwayConfig(
        jaw_tongue=replace(
            JawTongueConfig(), tongue=replace(JawTongueConfig.tongue, integrator=integrator)
        ),
        pressure=pressure,
    )
    model = reduced_tongue(config, cache) if tongue == "reduced" else None
    a = build_scene(config, pressure=pressure > 0, reduced=model)
    if case != "none":
        motion = a.jt.tongue.bundle_schedule(Tongue.motion(case))
        a.scene.add_controller(motion.controller(a.jt.tongue.body))
    x0 = a.skin.positions()
    rest = (
        "rest",
        a.jt.tongue.body.u.x.array.copy(),
        a.jt.jaw.position.copy(),
        a.jt.jaw.rotation.copy(),
        x0,
    )

    def figures(run) -> dict:
        rec = recorded(a, {"t": run.times, "ms": run.step_ms, **run.records})
        return {"pressure_Pa": pressure, **run_figures(a, rec)}

    def draw(png, run, shown) -> None:
        r, panels = run.records, [rest]
        for t in shown[1:]:
            k = int(np.argmin(abs(run.times - t)))
            title = f"{case}, t = {run.times[k]:.2f} s, jaw {np.degrees(r['angle'][k]):.1f} deg"
            panels.append(
                (title, r["u"][k], r["jaw_position"][k], r["jaw_rotation"][k], r["skin"][k])
            )
        render(png, a, panels)

    facts = {"tongue": tongue}
    if model is not None:
        lift = sum(c.lift.columns.shape[1] for c in model.carriers)
        facts["reduced"] = {
            "pod_vectors": model.r - lift,
            "lift_columns": lift,
            "points": int(model.points.indices.size),
            "mesh_nodes": int(a.jt.tongue.data.mesh.points.shape[0]),
            "cache": str(cache),
        }
    return Built(
        a.scene,
        record={**jt.records(a.jt), **records(a)},
        figures=figures,
        render=draw,
        facts=facts,
    )


def _options(group) -> None:
    group.add_argument(
        "--pressure",
        type=nonnegative_float,
        default=AirwayConfig.pressure,
        help="air pressure inside the airway (Pa; 0: no air), ramped over 0.1 s (%(default)s)",
    )
    group.add_argument(
        "--tongue",
        default="full",
        choices=list(TONGUES),
        help="; ".join(f"{k}: {v}" for k, v in TONGUES.items()) + " (default: %(default)s)",
    )
    group.add_argument(
        "--cache",
        type=Path,
        default=DEFAULT_CACHE,
        help="the reduced tongue's training cache (default: %(default)s)",
    )


MODEL = Model(
    name="airway",
    summary="airway skin over tongue, jaw and palate, with air pressure",
    build=build,
    cases={
        "protrusion": "the tongue protrudes in the airway",
        "retraction": "the tongue retracts",
        "retroflexion": "the tongue tip curls up",
        "none": "the tongue's muscles off (the jaw opener and the air only)",
    },
    levels={0: "the level-0 tongue (946 nodes)"},
    dt=0.01,
    duration=0.6,
    options=_options,
)
add_arguments, run = command(MODEL)
