"""The airway: a skin over the tongue, the jaw and the palate, loaded by the air inside it
(Lloyd et al. 2019, section 4.1 and Fig. 13).

Scene
-----
- The jaw-tongue scene of :mod:`artifem.models.jaw_tongue` as it is (level-0 FEM tongue,
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
:mod:`artifem.models.jaw_tongue_reduced` in the scene (same training and cache:
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

Measured (0.6 s, dt = 0.01 s, 1 kPa; docs/airway.md): the air moves the tongue's top 2-8 mm
down and forward (tip 3-13 mm) against the same motion without it, widens the oral airway
by up to 40 % when no muscle resists, and opens the jaw by 0.1-0.2 degrees; its resultants
(1.9 N on the tongue, 0.06 N on the jaw, 1.9 N on the palate at rest) sum to zero. Steps
cost 78 ms without the airway's load and 84 ms with the skin and its pressure (G: 5.4 ms,
skin positions 0.09 ms); with the reduced tongue (20 + 12 columns, 300 points) 5.0 and
6.0 ms, the pressure's loads formed without assembling G (docs/benchmarks/scenes.json). The reduced
airway follows the full one within 0.1-1.0 mm mean skin
error without the air and 0.9-1.3 mm with it (a basis trained without air), jaw angles
within 0.33 degrees.

Run ``python -m artifem.models.airway --out DIR [--reduced]`` (``artifem simulate airway
--out DIR [--reduced]``).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
import numpy as np
import pyvista as pv
from threadpoolctl import threadpool_limits

from artifem.arguments import nonnegative_float, positive_float
from artifem.errors import InputError
from artifem.models import jaw_tongue as jt
from artifem.models.cache import user_cache
from artifem.models import jaw_tongue_reduced as jtr
from artifem.models.jaw_tongue import JawTongueConfig, close_surface, read_obj
from artifem.models.tongue.model import DATA, MOTIONS, Tongue, load_tongue_data
from artifem.multibody.rigid_body import RigidBody
from artifem.multibody.skin import RigidMaster, SkinMesh, SkinPressure
from artifem.reduction.reductor import ReducedModel
from artifem.registration import TriangleSurface, icp
from artifem.scene import simulate as simulate_scene

__all__ = [
    "AirwayConfig",
    "AirwayScene",
    "Sections",
    "align_airway",
    "benchmark",
    "build_scene",
    "compare",
    "read_sections",
    "reduced_table",
    "reduced_tongue",
    "resultants",
    "simulate",
]

#: airway.obj axes -> tongue axes: (x, y, z)_obj -> (-x, -y, z)_tongue (det +1).
AIRWAY_AXES = np.diag([-1.0, -1.0, 1.0])
#: where the reduced tongue's training is cached (shared with jaw_tongue_reduced.benchmark).
DEFAULT_CACHE = user_cache("jaw_tongue_reduced")


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


def _polydata(vertices, triangles):
    return pv.PolyData(
        np.asarray(vertices, dtype=float),
        np.hstack([np.full((len(triangles), 1), 3), triangles]).ravel(),
    )


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
        return _polydata(x, self.triangles)

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
    palate = _polydata(palate_v, palate_t)
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
    airway's jaw-tongue scene: ``jaw_tongue_reduced.train`` with ``base``'s training settings
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
    tongue is the reduced one, u = U q + L g (jaw_tongue_reduced), and the skin's tongue
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


def simulate(
    a: AirwayScene,
    motion: str | None,
    duration: float,
    dt: float = 0.01,
    *,
    snapshots=(),
    progress: bool = False,
    label: str = "airway",
) -> dict:
    """Run a tongue motion (or none) in the airway scene: jaw_tongue.simulate's record plus,
    per step (outside the step timing), the skin's positions ``skin`` (steps + 1, n, 3), the
    section areas, the skin's distance to the tongue, the top landmark and the pressure;
    ``skin_frames``: the skin at the snapshots."""
    top = int(a.jt.tongue.body.local_dofs([a.jt.tongue.data.landmarks["top"]])[0])
    gap0 = a.surface.signed_distance(a.skin.positions()[a.tongue_vertices])

    def gap_drift(scene):
        gap = a.surface.signed_distance(a.skin.positions()[a.tongue_vertices])
        return float(np.abs(gap - gap0).max())

    out = jt.simulate(
        a.jt,
        motion,
        duration,
        dt,
        snapshots=snapshots,
        progress=progress,
        label=label,
        record={
            "skin": lambda scene: a.skin.positions(),
            "gap_drift": gap_drift,
            "pressure": lambda scene: a.pressure.pressure_at(scene.t) if a.pressure_on else 0.0,
        },
    )
    out["areas"] = np.array([a.sections.areas(x) for x in out["skin"]])
    out["top"] = out["u"].reshape(len(out["u"]), -1, 3)[:, top]
    out["skin_frames"] = [out["skin"][int(round(t / dt))] for t, *_ in out["frames"]]
    return out


def resultants(a: AirwayScene, t: float) -> dict:
    """Net force (N) of the air on each master and their sum (zero: closed surface): the
    force part of a rigid master's wrench; sum_v w_v f_v on the tongue (full: the sum of
    its nodal forces G^T f, since sum_j N_j = 1; reduced: the force on its material, which
    its generalized force [U, L]^T N^T (w f) does not show)."""
    f_v = a.pressure.vertex_forces(t)
    net = {}
    for i, (m, (_, f)) in enumerate(zip(a.skin.masters, a.pressure.master_loads(t))):
        net[m.name] = (f[:3] if m.kind == "rigid" else a.skin.weights[:, i] @ f_v).tolist()
    net["sum"] = np.sum([v for v in net.values()], axis=0).tolist()
    return net


def compare(a: AirwayScene, full: dict, reduced: dict) -> dict:
    """Reduced against full run of the same motion and pressure, over all steps: skin vertex
    error e_v(t) = |x_v^red - x_v^full| (mm: max over t of the mean over v, max over t and v,
    mean at the end); section area error 100 |A_red - A_full| / A_full over the interior
    sections (max over t and sections, mean over sections at the end); jaw angles; median
    ms per step of both (same process) and their ratio."""
    if full["skin"].shape != reduced["skin"].shape:
        raise InputError(
            f"airway compare: runs of different length {full['skin'].shape} "
            f"and {reduced['skin'].shape}"
        )
    e = 1e3 * np.linalg.norm(reduced["skin"] - full["skin"], axis=2)
    inner = a.sections.interior
    area = 100 * np.abs(reduced["areas"][:, inner] / full["areas"][:, inner] - 1)
    ms_full, ms_red = float(np.median(full["ms"])), float(np.median(reduced["ms"]))
    return {
        "skin_error_mm": {
            "mean_max_over_t": float(e.mean(1).max()),
            "max": float(e.max()),
            "final_mean": float(e[-1].mean()),
        },
        "max_skin_displacement_mm": float(
            1e3 * np.linalg.norm(full["skin"] - full["skin"][0], axis=2).max()
        ),
        "area_error_percent": {"max": float(area.max()), "final_mean": float(area[-1].mean())},
        "jaw_angle_deg": {
            "full": float(np.degrees(full["angle"][-1])),
            "reduced": float(np.degrees(reduced["angle"][-1])),
            "max_difference": float(np.degrees(np.abs(reduced["angle"] - full["angle"]).max())),
        },
        "ms_per_step": {"full": ms_full, "reduced": ms_red, "speedup": ms_full / ms_red},
        "max_attachment_error_m": float(reduced["attachment_error"].max()),
    }


def reduced_table(comparison: dict) -> str:
    """The Markdown table of :func:`compare`'s results per run."""
    lines = [
        "| run | skin error mean / max (mm) | max skin displacement (mm) | "
        "area error max / final mean (%) | jaw full / reduced (deg) | "
        "ms/step full / reduced | speed-up |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, c in comparison.items():
        e, A, j, ms = (
            c["skin_error_mm"],
            c["area_error_percent"],
            c["jaw_angle_deg"],
            c["ms_per_step"],
        )
        lines.append(
            f"| {key} | {e['mean_max_over_t']:.2f} / {e['max']:.2f} | "
            f"{c['max_skin_displacement_mm']:.1f} | {A['max']:.1f} / "
            f"{A['final_mean']:.1f} | {j['full']:.2f} / {j['reduced']:.2f} | "
            f"{ms['full']:.1f} / {ms['reduced']:.1f} | {ms['speedup']:.1f}x |"
        )
    return "\n".join(lines) + "\n"


# ---- output ---------------------------------------------------------------------------------


def render(png: Path, a: AirwayScene, panels) -> Path:
    """Per panel (title, u, p, R, x): a side view of the tongue (|u|), jaw, palate and airway
    skin, and below it their mid-sagittal section (y = 0) with the rest airway in gray."""
    from dolfinx import fem

    from artifem.render import add_displacement, body_grid

    pv.OFF_SCREEN = True
    body = a.jt.tongue.body
    plotter = pv.Plotter(
        off_screen=True, shape=(2, len(panels)), window_size=[520 * len(panels), 1040]
    )
    u_fun = fem.Function(body.V)
    clim = (
        0.0,
        max(1e-6, 1e3 * max(np.linalg.norm(u.reshape(-1, 3), axis=1).max() for _, u, *_ in panels)),
    )
    jaw_v, jaw_t = a.jt.jaw.surface
    pal_v, pal_t = a.palate.surface
    palate = _polydata(pal_v + a.palate.position, pal_t)
    rest_skin = _polydata(a.skin.rest, a.skin.faces).slice(normal="y", origin=(0, 0, 0))
    side = [(0.10, -0.40, 0.06), (0.10, 0.0, 0.06), (0, 0, 1)]
    try:
        plotter.set_background("white")
        for i, (title, u, p, R, x) in enumerate(panels):
            u_fun.x.array[:] = u
            jaw = _polydata(jaw_v @ R.T + p, jaw_t)
            skin = _polydata(x, a.skin.faces)
            plotter.subplot(0, i)
            add_displacement(plotter, u_fun, clim, scalar_bar=i == 0, rest_opacity=0.1)
            plotter.add_mesh(jaw, color="wheat", opacity=0.35)
            plotter.add_mesh(palate, color="lightpink", opacity=0.5)
            plotter.add_mesh(
                skin,
                color="deepskyblue",
                opacity=0.45,
                show_edges=True,
                edge_color="steelblue",
                line_width=0.5,
            )
            plotter.add_text(title, font_size=10, color="black")
            plotter.camera_position = side
            plotter.reset_camera()
            plotter.camera.zoom(1.35)
            plotter.subplot(1, i)
            grid, _ = body_grid(body.mesh, u_fun)
            plotter.add_mesh(
                grid.slice(normal="y", origin=(0, 0, 0)), color="indianred", opacity=0.8
            )
            plotter.add_mesh(rest_skin, color="gray", line_width=2)
            for mesh, color in ((jaw, "tan"), (palate, "hotpink"), (skin, "blue")):
                plotter.add_mesh(
                    mesh.slice(normal="y", origin=(0, 0, 0)), color=color, line_width=3
                )
            plotter.add_text(
                "mid-sagittal: airway (blue; rest gray), tongue, palate, jaw",
                font_size=8,
                color="black",
            )
            plotter.camera_position = side
            plotter.reset_camera()
            plotter.camera.zoom(1.35)
        png.parent.mkdir(parents=True, exist_ok=True)
        plotter.screenshot(str(png))
    finally:
        plotter.close()
    return png


def plot_sections(png: Path, curves: dict) -> Path:
    """Area along the airway (larynx -> lips): curves name -> (length m, area m^2, style)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.2))
    for name, (s, area, style) in curves.items():
        ax.plot(1e3 * s, 1e6 * area, style, label=name, lw=1.4)
    ax.set_xlabel("distance from the larynx along the airway (mm)")
    ax.set_ylabel("cross-section area (mm$^2$)")
    ax.legend(fontsize=8, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return png


def _summary(a: AirwayScene, rec: dict) -> dict:
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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument("--duration", type=positive_float, default=0.6)
    parser.add_argument("--dt", type=positive_float, default=0.01)
    parser.add_argument(
        "--pressure",
        type=nonnegative_float,
        default=AirwayConfig.pressure,
        help="air pressure inside the airway (Pa)",
    )
    parser.add_argument(
        "--motions",
        nargs="+",
        default=sorted(MOTIONS),
        choices=sorted(MOTIONS),
        help="tongue motions to run",
    )
    parser.add_argument(
        "--reduced",
        action="store_true",
        help="also run every case over the reduced tongue (jaw_tongue_reduced "
        "training) and compare it with the full one",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=DEFAULT_CACHE,
        help="reduced tongue training cache (default: %(default)s)",
    )


def run(args: argparse.Namespace) -> int:
    figures = report(args)
    if "reduced" in figures:
        print(reduced_table(figures["reduced"]["runs"]))
    return 0


def report(args: argparse.Namespace) -> dict:
    """Rest + each motion, with and without the air pressure: renders, section plot, JSON."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    config = AirwayConfig(pressure=args.pressure)
    data = load_tongue_data(0)
    t0 = time.perf_counter()
    rest = build_scene(config, pressure=True, data=data)
    build_s = time.perf_counter() - t0
    skin = rest.skin
    x0 = skin.positions()
    length0 = rest.sections.length(x0)
    rest_u = rest.jt.tongue.body.u.x.array.copy()
    rest_pose = (rest.jt.jaw.position.copy(), rest.jt.jaw.rotation.copy())
    runs = {}
    # no muscles (gravity and the jaw opener only), then each motion; with and without air
    for motion in [None] + list(args.motions):
        for on in (True, False):
            a = rest if motion is None and on else build_scene(config, pressure=on, data=data)
            key = f"{motion or 'none'}/{'pressure' if on else 'no_pressure'}"
            rec = simulate(
                a, motion, args.duration, args.dt, snapshots=(1.0,), progress=True, label=key
            )
            runs[key] = (a, rec)
            print(
                f"{key}: {np.median(rec['ms']):.0f} ms/step, min interior area "
                f"{1e6 * rec['areas'][-1, a.sections.interior].min():.1f} mm^2",
                flush=True,
            )
    panels = [("rest", rest_u, *rest_pose, x0)]
    inner = rest.sections.interior
    curves = {"rest": (length0[inner], rest.sections.areas(x0)[inner], "k-")}
    styles = {"none": "C7", "protrusion": "C0", "retroflexion": "C1", "retraction": "C2"}
    for key, (_, rec) in runs.items():
        motion, p = key.split("/")
        (_, u, pj, Rj), xs = rec["frames"][-1], rec["skin_frames"][-1]
        if p == "pressure" and motion != "none":
            panels.append(
                (
                    f"{motion}, {args.pressure:g} Pa, t = {rec['t'][-1]:.2f} s, "
                    f"jaw {np.degrees(rec['angle'][-1]):.1f} deg",
                    u,
                    pj,
                    Rj,
                    xs,
                )
            )
        curves[f"{motion}, {'p' if p == 'pressure' else 'no p'}"] = (
            length0[inner],
            rec["areas"][-1][inner],
            styles[motion] + ("-" if p == "pressure" else "--"),
        )
    png = render(out / "airway.png", rest, panels)
    sec_png = plot_sections(out / "airway_sections.png", curves)
    al = rest.alignment
    figures = {
        "model": "airway",
        "dt": args.dt,
        "duration": args.duration,
        "pressure_Pa": args.pressure,
        "pressure_ramp_s": config.pressure_ramp,
        "build_seconds": build_s,
        "alignment": {
            "airway": {
                "method": "axes (x,y,z)->(-x,-y,z), mm->m, trimmed point-to-surface "
                "ICP onto tongue boundary + palate, 5x5 starts",
                "linear": al["linear"].tolist(),
                "translation_m": al["translation"].tolist(),
                "residual_rotation_deg": al["residual_rotation_deg"],
                "trim": al["trim"],
                "trimmed_mean_distance_mm": 1e3 * al["trimmed_mean_distance"],
                "median_distance_mm": 1e3 * al["median_distance"],
                "p75_distance_mm": 1e3 * al["p75_distance"],
                "max_distance_mm": 1e3 * al["max_distance"],
                "fraction_inside_tongue": al["fraction_inside_tongue"],
                "max_depth_inside_tongue_mm": 1e3 * al["max_depth_inside_tongue"],
                "holes_capped": al["holes_capped"],
                "volume_cm3": 1e6 * al["volume_m3"],
            },
            "palate": {
                (k[:-2] + "_mm" if k.endswith("_m") else k): (1e3 * v if k.endswith("_m") else v)
                for k, v in al["palate"].items()
            },
        },
        "skin": {
            "vertices": skin.n,
            "faces": int(len(skin.faces)),
            "masters": [m.name for m in skin.masters],
            "dominant_master_vertices": {
                m.name: int((np.argmax(skin.weights, 1) == i).sum())
                for i, m in enumerate(skin.masters)
            },
            "tongue_weight_ge_0.9": int(rest.tongue_vertices.size),
            "weighting": config.weighting,
            "blending": config.blending,
        },
        "sections": {
            "count": int(len(rest.sections.a)),
            "length_mm": (1e3 * length0).tolist(),
            "rest_area_mm2": (1e6 * rest.sections.areas(x0)).tolist(),
        },
        "resultants_N_at_rest_pressure": resultants(rest, 1.0),
        "runs": {key: _summary(a, rec) for key, (a, rec) in runs.items()},
        "png": [str(png), str(sec_png)],
    }
    effect = {}
    for motion in ["none"] + list(args.motions):
        on, off = runs[f"{motion}/pressure"][1], runs[f"{motion}/no_pressure"][1]
        effect[motion] = {
            "tip_mm": (1e3 * (on["tip"][-1] - off["tip"][-1])).tolist(),
            "top_mm": (1e3 * (on["top"][-1] - off["top"][-1])).tolist(),
            "opening_angle_deg": float(np.degrees(on["angle"][-1] - off["angle"][-1])),
            "mean_area_change_percent": float(
                100 * (on["areas"][-1].sum() / off["areas"][-1].sum() - 1)
            ),
        }
    figures["pressure_effect_final"] = effect
    if args.reduced:
        figures["reduced"] = report_reduced(out, config, data, runs, args)
    (out / "airway.json").write_text(json.dumps(figures, indent=2))
    short = {k: v for k, v in figures.items() if k in ("alignment", "pressure_effect_final")}
    print(json.dumps(short, indent=2))
    return figures


def report_reduced(
    out: Path, config: AirwayConfig, data, runs: dict, args: argparse.Namespace
) -> dict:
    """Every run of ``runs`` again over the reduced tongue (:func:`reduced_tongue`, cached in
    ``args.cache``), compared with the full one (:func:`compare`); renders full | reduced at
    the end of each motion with the pressure; ``airway_reduced.md``: the table."""
    tic = time.perf_counter()
    model = reduced_tongue(config, args.cache)
    train_s = time.perf_counter() - tic
    base = jtr.ReducedJawTongueConfig()
    comparison, panels = {}, []
    for key, (full_scene, full) in runs.items():
        motion, p = key.split("/")
        a = build_scene(config, pressure=p == "pressure", data=data, reduced=model)
        with threadpool_limits(limits=1, user_api="blas"):  # r x r algebra
            rec = simulate(
                a,
                None if motion == "none" else motion,
                args.duration,
                args.dt,
                snapshots=(1.0,),
                progress=True,
                label=f"{key} reduced",
            )
        comparison[key] = c = compare(full_scene, full, rec)
        print(
            f"{key} reduced: {c['ms_per_step']['reduced']:.1f} ms/step "
            f"(full {c['ms_per_step']['full']:.1f}), skin error mean "
            f"{c['skin_error_mm']['mean_max_over_t']:.2f} mm",
            flush=True,
        )
        if p == "pressure" and motion != "none":
            t = rec["t"][-1]
            for name, r in (("full", full), (f"reduced {base.r}+12", rec)):
                (_, u, pj, Rj), xs = r["frames"][-1], r["skin_frames"][-1]
                title = f"{motion}, {name}, t = {t:.2f} s, jaw {np.degrees(r['angle'][-1]):.2f} deg"
                if r is rec:
                    title += f", skin error {c['skin_error_mm']['final_mean']:.2f} mm"
                panels.append((title, u, pj, Rj, xs))
    png = render(out / "airway_reduced.png", runs["none/pressure"][0], panels)
    (out / "airway_reduced.md").write_text(reduced_table(comparison))
    return {
        "basis": {
            "pod_vectors": base.r,
            "lift_columns": 12,
            "points": base.points,
            "training": "jaw_tongue_reduced.train (each tongue exciter alone at "
            f"{base.training_excitation}, no air pressure)",
            "snapshots": model.training["snapshots"],
            "cache": str(args.cache),
        },
        "training_seconds": train_s,
        "runs": comparison,
        "png": str(png),
    }


def benchmark(
    steps: int = 10,
    dt: float = 0.01,
    data=None,
    reduced: jtr.ReducedJawTongueConfig | None = None,
    cache: Path | None = None,
    quick: bool = False,
) -> dict:
    """Milliseconds per coupled step (median of ``steps``) of the jaw-tongue scene during
    protrusion, with the full and with the reduced tongue (``reduced`` training, default
    the jaw-tongue one, ``jaw_tongue_reduced.quick_config()`` if ``quick``; cached in
    ``cache``, default $XDG_CACHE_HOME/artifem/jaw_tongue_reduced, ~/.cache when unset):
    without the airway's load, then with its skin and pressure; and the cost of one skin update
    (positions), of G
    (jacobian) and of the pressure's master loads."""
    if steps < 1:
        raise InputError(f"benchmark: steps must be >= 1, got {steps}")
    reduced = reduced or (jtr.quick_config() if quick else jtr.ReducedJawTongueConfig())
    data = data or load_tongue_data(0)
    config = AirwayConfig(pressure_start=(steps + 1) * dt)
    model = reduced_tongue(config, cache or DEFAULT_CACHE, reduced)
    cases = {}
    for name, red in (("full", None), ("reduced", model)):
        with threadpool_limits(limits=1, user_api="blas"):
            cases[name] = _benchmark_case(
                build_scene(config, pressure=False, data=data, reduced=red), steps, dt
            )
    ratio = {
        k: cases["full"][k] / cases["reduced"][k]
        for k in ("ms_per_step_without_airway", "ms_per_step_with_skin_pressure")
    }
    return {
        "benchmark": "airway",
        "steps": steps,
        "dt": dt,
        "skin_vertices": [c.pop("skin_vertices") for c in cases.values()][0],
        "reduced": {"pod_vectors": reduced.r, "lift_columns": 12, "points": reduced.points},
        "cases": cases,
        "speedup": ratio,
    }


def _benchmark_case(a: AirwayScene, steps: int, dt: float) -> dict:
    """benchmark() of one airway scene built without its pressure load (added midway)."""
    s = a.jt
    s.scene.add_controller(
        s.tongue.bundle_schedule(Tongue.motion("protrusion")).controller(s.tongue.body)
    )

    def timed(n):  # the controller included
        return simulate_scene(s.scene, n * dt, dt, progress=False).ms_per_step

    timed(1)  # factorization set-up, compile
    plain = timed(steps)
    s.scene.add(a.pressure)  # ramped from now on
    timed(1)
    loaded = timed(steps)

    def cost(f, n=max(3, steps)):
        t0 = time.perf_counter()
        for _ in range(n):
            f()
        return 1e3 * (time.perf_counter() - t0) / n

    t = s.scene.t
    return {
        "skin_vertices": a.skin.n,
        "masters": s.scene.master_count(),
        "ms_per_step_without_airway": plain,
        "ms_per_step_with_skin_pressure": loaded,
        "ms_skin_positions": cost(a.skin.positions),
        "ms_skin_jacobian": cost(a.skin.jacobian),
        "ms_pressure_master_loads": cost(lambda: a.pressure.master_loads(t)),
    }


if __name__ == "__main__":
    import sys

    cli = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_arguments(cli)
    sys.exit(run(cli.parse_args()))
