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
cost 76 ms without the airway and 83 ms with the skin and its pressure (G: 5.4 ms, skin
positions 0.08 ms).

Run ``python -m artifem.models.airway --out DIR`` (``artifem simulate airway --out DIR``).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
import numpy as np
import pyvista as pv

from artifem.models import jaw_tongue as jt
from artifem.models.jaw_tongue import JawTongueConfig, _kabsch, close_surface, read_obj
from artifem.models.tongue.model import DATA, MOTIONS, Tongue, load_tongue_data
from artifem.multibody.rigid_body import RigidBody
from artifem.multibody.skin import RigidMaster, SkinMesh, SkinPressure

__all__ = ["AirwayConfig", "AirwayScene", "Sections", "align_airway", "benchmark",
           "build_scene", "read_sections", "simulate"]

#: airway.obj axes -> tongue axes: (x, y, z)_obj -> (-x, -y, z)_tongue (det +1).
AIRWAY_AXES = np.diag([-1.0, -1.0, 1.0])


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
            raise ValueError(f"airway: pressure must be finite, got {self.pressure!r}")
        if not self.pressure_ramp > 0:
            raise ValueError(f"airway: pressure_ramp must be > 0, got {self.pressure_ramp!r}")
        if not 0.1 <= self.trim <= 1.0:
            raise ValueError(f"airway: trim must be in [0.1, 1], got {self.trim!r}")


# ---- geometry ---------------------------------------------------------------------------

def read_sections(path: Path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The ``s nx ny nz d [name]`` lines of a sectioned OBJ (ArtiSynth's SectionedMesh): the
    planes n . x = d, as (normals (k, 3), offsets (k,), names)."""
    normals, offsets, names = [], [], []
    for lineno, line in enumerate(Path(path).read_text().splitlines(), 1):
        parts = line.split()
        if parts and parts[0] == "s":
            if len(parts) < 5:
                raise ValueError(f"{path}:{lineno}: expected 's nx ny nz d [name]', "
                                 f"got {line!r}")
            n = np.array([float(v) for v in parts[1:4]])
            if not np.isclose(np.linalg.norm(n), 1.0, atol=1e-3):
                raise ValueError(f"{path}:{lineno}: section normal {n} is not a unit vector")
            normals.append(n / np.linalg.norm(n))
            offsets.append(float(parts[4]))
            names.append(" ".join(parts[5:]))
    if not normals:
        raise ValueError(f"{path}: no section planes ('s' lines)")
    return np.array(normals), np.array(offsets), names


def _polydata(vertices, triangles):
    return pv.PolyData(np.asarray(vertices, dtype=float),
                       np.hstack([np.full((len(triangles), 1), 3), triangles]).ravel())


class TongueSurface:
    """The tongue's boundary triangles, deformable: points X + u of the surface nodes."""

    def __init__(self, body, points: np.ndarray, hexes: np.ndarray):
        grid = pv.UnstructuredGrid({pv.CellType.HEXAHEDRON: hexes}, points)
        surf = grid.extract_surface(algorithm="dataset_surface").triangulate()
        self.rows = np.asarray(surf.point_data["vtkOriginalPointIds"], dtype=np.int64)
        self.rest = surf.points.copy()
        self.dofs = body.local_dofs(self.rows).astype(np.int64)
        self.triangles = surf.faces.reshape(-1, 4)[:, 1:]
        self.body = body

    def polydata(self, deformed: bool = True):
        x = self.rest.copy()
        if deformed:
            x += self.body.u.x.array.reshape(-1, 3)[self.dofs]
        return _polydata(x, self.triangles)

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (negative inside) of points to the deformed surface."""
        probe = pv.PolyData(np.asarray(points, dtype=float))
        return np.asarray(probe.compute_implicit_distance(self.polydata())["implicit_distance"])


def _closest(surface, points: np.ndarray) -> np.ndarray:
    _, closest = surface.find_closest_cell(points, return_closest_point=True)
    return np.asarray(closest)


def _trimmed_icp(source: np.ndarray, target, R: np.ndarray, t: np.ndarray, trim: float,
                 iterations: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, score) after at most ``iterations`` of trimmed point-to-surface ICP of
    ``source`` onto ``target`` from (R, t); score: mean distance of the fitted fraction."""
    for _ in range(iterations):
        moved = source @ R.T + t
        closest = _closest(target, moved)
        r = np.linalg.norm(closest - moved, axis=1)
        keep = r <= np.quantile(r, trim)
        R_new, t_new = _kabsch(source[keep], closest[keep])
        done = np.abs(R_new - R).max() < 1e-7 and np.abs(t_new - t).max() < 1e-8
        R, t = R_new, t_new
        if done:
            break
    moved = source @ R.T + t
    r = np.linalg.norm(_closest(target, moved) - moved, axis=1)
    return R, t, float(r[r <= np.quantile(r, trim)].mean())


def align_airway(vertices_mm: np.ndarray, tongue, palate, trim: float = 0.5) -> dict:
    """x_tongue = linear x_obj + translation for airway.obj (module docstring): the axis map
    AIRWAY_AXES, mm -> m, then a trimmed ICP onto the tongue surface and the palate
    (pyvista PolyData, tongue frame): 25 starts, 10 iterations each, then the best three
    to convergence. Returns the transform and the residuals."""
    base = 1e-3 * np.asarray(vertices_mm, dtype=float) @ AIRWAY_AXES.T
    target = tongue.merge(palate).extract_surface(algorithm="dataset_surface")
    lo, hi = np.array(tongue.bounds).reshape(3, 2).T
    starts = []
    for dx in np.linspace(-0.03, 0.03, 5):
        for dz in np.linspace(-0.03, 0.03, 5):
            t = np.array([0.5 * (lo[0] + hi[0]) + dx, 0.0, hi[2] + dz]) - base.mean(0)
            starts.append(_trimmed_icp(base, target, np.eye(3), t, trim, 10))
    starts.sort(key=lambda start: start[2])
    best = min((_trimmed_icp(base, target, R, t, trim, 60) for R, t, _ in starts[:3]),
               key=lambda fit: fit[2])
    R, t, score = best
    x = base @ R.T + t
    r = np.linalg.norm(_closest(target, x) - x, axis=1)
    depth = np.asarray(pv.PolyData(x).compute_implicit_distance(tongue)["implicit_distance"])
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    return {"linear": 1e-3 * R @ AIRWAY_AXES, "translation": t, "distances": r,
            "trimmed_mean_distance": float(score), "median_distance": float(np.median(r)),
            "p75_distance": float(np.quantile(r, 0.75)), "max_distance": float(r.max()),
            "fraction_inside_tongue": float((depth < 0).mean()),
            "max_depth_inside_tongue": float(max(0.0, -depth.min())),
            "residual_rotation_deg": float(angle), "trim": trim}


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
    gap_pal = np.asarray(pv.PolyData(palate_v).compute_implicit_distance(tongue_poly)
                         ["implicit_distance"])
    alignment.update(holes_capped=holes, triangles_flipped=flipped, volume_m3=float(volume),
                     palate={"transform": "identity (already in the tongue frame, metres)",
                             "min_gap_to_tongue_m": float(gap_pal.min()),
                             "median_gap_to_tongue_m": float(np.median(gap_pal)),
                             "vertices_inside_tongue": int((gap_pal < 0).sum())})
    return x, closed_t, sections, alignment, (palate_v, palate_t)


def _check_closed(triangles: np.ndarray) -> None:
    """Every directed edge once and its opposite once: closed and consistently oriented."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    keys = {(int(a), int(b)) for a, b in e}
    if len(keys) != len(e) or any((b, a) not in keys for a, b in keys):
        raise ValueError("airway: the capped surface is not closed and consistently oriented")


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
    def cut(cls, X: np.ndarray, triangles: np.ndarray, normals, offsets, names,
            caps_from: int) -> Sections:
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
            pick = (int(np.argmin([c[2] for c in cents])) if prev is None
                    else int(np.argmin([np.linalg.norm(c - prev) for c in cents])))
            a, b, s = loops[pick]
            A.append(a), B.append(b), S.append(s), kept.append(k)
            prev = cents[pick]
        if not kept:
            raise ValueError("airway: no section plane cuts the surface")
        interior = np.array([a.max() < caps_from and b.max() < caps_from
                             for a, b in zip(A, B)])
        return cls(A, B, S, [names[k] for k in kept], np.array(kept), interior)

    def points(self, x: np.ndarray) -> list[np.ndarray]:
        return [(1 - s)[:, None] * x[a] + s[:, None] * x[b]
                for a, b, s in zip(self.a, self.b, self.s)]

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
        crossing = [(int(tri[i]), int(tri[(i + 1) % 3])) for i in range(3)
                    if pos[tri[i]] != pos[tri[(i + 1) % 3]]]
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
    tongue_vertices: np.ndarray          # skin vertices with tongue weight >= 0.9
    config: AirwayConfig = field(default_factory=AirwayConfig)

    @property
    def scene(self):
        return self.jt.scene


def build_scene(config: AirwayConfig = AirwayConfig(), *, pressure: bool = True,
                data=None) -> AirwayScene:
    """The jaw-tongue scene, the fixed palate, the airway skin and (``pressure``) its air
    pressure load (module docstring)."""
    data = data or load_tongue_data(0)
    s = jt.build_scene(config.jaw_tongue, data=data)
    x, triangles, sections, alignment, (pal_v, pal_t) = _aligned_airway(config.trim)
    centre = pal_v.mean(0)
    palate = RigidBody("palate", 1e-3, 1e-9 * np.eye(3), position=centre, motion="fixed",
                       surface=(pal_v - centre, pal_t))
    s.scene.add(palate)
    masters = [s.tongue.body, RigidMaster(s.jaw, reference=s.jaw.surface[0]),
               RigidMaster(palate, reference=palate.surface[0])]
    skin = SkinMesh(x, triangles, masters, weighting=config.weighting,
                    blending=config.blending, name="airway")
    P, ramp, t0 = config.pressure, config.pressure_ramp, config.pressure_start
    load = SkinPressure(skin, lambda t: P * min(1.0, max(0.0, t - t0) / ramp), name="air")
    if pressure:
        s.scene.add(load)
    surface = TongueSurface(s.tongue.body, data.mesh.points, data.mesh.cells)
    return AirwayScene(s, palate, skin, load, pressure, sections, alignment, surface,
                       np.flatnonzero(skin.weights[:, 0] >= 0.9), config)


def simulate(a: AirwayScene, motion: str | None, duration: float, dt: float = 0.01, *,
             snapshots=()) -> dict:
    """Run a tongue motion (or none) in the airway scene: jaw_tongue.simulate's record plus,
    per step, the section areas, the skin's distance to the tongue, the top landmark and the
    pressure; frames add the skin's positions."""
    top = a.jt.tongue.data.landmarks["top"]
    body = a.jt.tongue.body
    x0 = a.skin.positions()
    gap0 = a.surface.signed_distance(x0[a.tongue_vertices])
    rec = {"areas": [a.sections.areas(x0)], "gap_drift": [0.0], "top": [np.zeros(3)],
           "pressure": [a.pressure.pressure_at(0.0) if a.pressure_on else 0.0]}
    skins = {}

    def observe(k):
        x = a.skin.positions()
        rec["areas"].append(a.sections.areas(x))
        gap = a.surface.signed_distance(x[a.tongue_vertices])
        rec["gap_drift"].append(float(np.abs(gap - gap0).max()))
        rec["top"].append(body.displacement_at([top])[0])
        rec["pressure"].append(a.pressure.pressure_at(a.scene.t) if a.pressure_on else 0.0)
        skins[k] = x

    out = jt.simulate(a.jt, motion, duration, dt, snapshots=snapshots, callback=observe)
    for key, values in rec.items():
        out[key] = np.array(values)
    out["skin_frames"] = [skins[int(round(t / dt))] for t, *_ in out["frames"]]
    return out


def resultants(a: AirwayScene, t: float) -> dict:
    """Net force (N) of the air on each master and their sum (zero: closed surface)."""
    net = {}
    for body, f in a.pressure.master_loads(t):
        net[body.name] = (f.reshape(-1, 3).sum(0) if f.size != 6 else f[:3]).tolist()
    net["sum"] = np.sum([v for v in net.values()], axis=0).tolist()
    return net


# ---- output ---------------------------------------------------------------------------------

def render(png: Path, a: AirwayScene, panels) -> Path:
    """Per panel (title, u, p, R, x): a side view of the tongue (|u|), jaw, palate and airway
    skin, and below it their mid-sagittal section (y = 0) with the rest airway in gray."""
    from dolfinx import fem

    from artifem.render import add_displacement, body_grid

    pv.OFF_SCREEN = True
    body = a.jt.tongue.body
    plotter = pv.Plotter(off_screen=True, shape=(2, len(panels)),
                         window_size=[520 * len(panels), 1040])
    u_fun = fem.Function(body.V)
    clim = (0.0, max(1e-6, 1e3 * max(np.linalg.norm(u.reshape(-1, 3), axis=1).max()
                                     for _, u, *_ in panels)))
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
            plotter.add_mesh(skin, color="deepskyblue", opacity=0.45, show_edges=True,
                             edge_color="steelblue", line_width=0.5)
            plotter.add_text(title, font_size=10, color="black")
            plotter.camera_position = side
            plotter.reset_camera()
            plotter.camera.zoom(1.35)
            plotter.subplot(1, i)
            grid, _ = body_grid(body.mesh, u_fun)
            plotter.add_mesh(grid.slice(normal="y", origin=(0, 0, 0)), color="indianred",
                             opacity=0.8)
            plotter.add_mesh(rest_skin, color="gray", line_width=2)
            for mesh, color in ((jaw, "tan"), (palate, "hotpink"), (skin, "blue")):
                plotter.add_mesh(mesh.slice(normal="y", origin=(0, 0, 0)), color=color,
                                 line_width=3)
            plotter.add_text("mid-sagittal: airway (blue; rest gray), tongue, palate, jaw",
                             font_size=8, color="black")
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
    return {"ms_per_step_median": float(np.median(rec["ms"])),
            "final_tip_displacement_mm": (1e3 * rec["tip"][-1]).tolist(),
            "final_top_displacement_mm": (1e3 * rec["top"][-1]).tolist(),
            "final_opening_angle_deg": float(np.degrees(rec["angle"][-1])),
            "max_opening_angle_deg": float(np.degrees(rec["angle"]).max()),
            "final_areas_mm2": (1e6 * rec["areas"][-1]).tolist(),
            "min_area_mm2": {"rest": float(1e6 * areas[0].min()),
                             "final": float(1e6 * areas[-1].min()),
                             "final_section": int(sections[np.argmin(areas[-1])])},
            "narrowest_relative": {"area_ratio": float(ratio.min()),
                                   "section": int(sections[np.argmin(ratio)])},
            "widest_relative": {"area_ratio": float(ratio.max()),
                                "section": int(sections[np.argmax(ratio)])},
            "mean_area_change_percent": float(100 * (areas[-1].sum() / areas[0].sum() - 1)),
            "max_skin_gap_drift_mm": float(1e3 * rec["gap_drift"].max()),
            "max_attachment_error_m": float(rec["attachment_error"].max()),
            "min_area_mm2_vs_t": (1e6 * areas.min(axis=1)).tolist(),
            "t": rec["t"].tolist(),
            "opening_angle_deg": np.degrees(rec["angle"]).tolist()}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument("--duration", type=float, default=0.6)
    parser.add_argument("--dt", type=float, default=0.01)
    parser.add_argument("--pressure", type=float, default=AirwayConfig.pressure,
                        help="air pressure inside the airway (Pa)")
    parser.add_argument("--motions", nargs="+", default=sorted(MOTIONS),
                        choices=sorted(MOTIONS), help="tongue motions to run")


def run(args: argparse.Namespace) -> int:
    report(args)
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
            rec = simulate(a, motion, args.duration, args.dt, snapshots=(1.0,))
            key = f"{motion or 'none'}/{'pressure' if on else 'no_pressure'}"
            runs[key] = (a, rec)
            print(f"{key}: {np.median(rec['ms']):.0f} ms/step, min interior area "
                  f"{1e6 * rec['areas'][-1, a.sections.interior].min():.1f} mm^2", flush=True)
    panels = [("rest", rest_u, *rest_pose, x0)]
    inner = rest.sections.interior
    curves = {"rest": (length0[inner], rest.sections.areas(x0)[inner], "k-")}
    styles = {"none": "C7", "protrusion": "C0", "retroflexion": "C1", "retraction": "C2"}
    for key, (a, rec) in runs.items():
        motion, p = key.split("/")
        (_, u, pj, Rj), xs = rec["frames"][-1], rec["skin_frames"][-1]
        if p == "pressure" and motion != "none":
            panels.append((f"{motion}, {args.pressure:g} Pa, t = {rec['t'][-1]:.2f} s, "
                           f"jaw {np.degrees(rec['angle'][-1]):.1f} deg", u, pj, Rj, xs))
        curves[f"{motion}, {'p' if p == 'pressure' else 'no p'}"] = (
            length0[inner], rec["areas"][-1][inner],
            styles[motion] + ("-" if p == "pressure" else "--"))
    png = render(out / "airway.png", rest, panels)
    sec_png = plot_sections(out / "airway_sections.png", curves)
    al = rest.alignment
    figures = {
        "model": "airway", "dt": args.dt, "duration": args.duration,
        "pressure_Pa": args.pressure, "pressure_ramp_s": config.pressure_ramp,
        "build_seconds": build_s,
        "alignment": {
            "airway": {"method": "axes (x,y,z)->(-x,-y,z), mm->m, trimmed point-to-surface "
                                 "ICP onto tongue boundary + palate, 5x5 starts",
                       "linear": al["linear"].tolist(), "translation_m": al["translation"].tolist(),
                       "residual_rotation_deg": al["residual_rotation_deg"],
                       "trim": al["trim"],
                       "trimmed_mean_distance_mm": 1e3 * al["trimmed_mean_distance"],
                       "median_distance_mm": 1e3 * al["median_distance"],
                       "p75_distance_mm": 1e3 * al["p75_distance"],
                       "max_distance_mm": 1e3 * al["max_distance"],
                       "fraction_inside_tongue": al["fraction_inside_tongue"],
                       "max_depth_inside_tongue_mm": 1e3 * al["max_depth_inside_tongue"],
                       "holes_capped": al["holes_capped"],
                       "volume_cm3": 1e6 * al["volume_m3"]},
            "palate": {(k[:-2] + "_mm" if k.endswith("_m") else k):
                       (1e3 * v if k.endswith("_m") else v) for k, v in al["palate"].items()}},
        "skin": {"vertices": skin.n, "faces": int(len(skin.faces)),
                 "masters": [m.name for m in skin.masters],
                 "dominant_master_vertices": {m.name: int((np.argmax(skin.weights, 1) == i).sum())
                                              for i, m in enumerate(skin.masters)},
                 "tongue_weight_ge_0.9": int(rest.tongue_vertices.size),
                 "weighting": config.weighting, "blending": config.blending},
        "sections": {"count": int(len(rest.sections.a)), "length_mm": (1e3 * length0).tolist(),
                     "rest_area_mm2": (1e6 * rest.sections.areas(x0)).tolist()},
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
            "mean_area_change_percent": float(100 * (on["areas"][-1].sum()
                                                     / off["areas"][-1].sum() - 1))}
    figures["pressure_effect_final"] = effect
    (out / "airway.json").write_text(json.dumps(figures, indent=2))
    short = {k: v for k, v in figures.items() if k in ("alignment", "pressure_effect_final")}
    print(json.dumps(short, indent=2))
    return figures


def benchmark(steps: int = 10, dt: float = 0.01, data=None) -> dict:
    """Milliseconds per coupled step of the jaw-tongue scene during protrusion without the
    airway, then with its skin and pressure load; and the cost of one skin update
    (positions), of G (jacobian) and of the pressure's master loads."""
    if steps < 1:
        raise ValueError(f"benchmark: steps must be >= 1, got {steps}")
    a = build_scene(AirwayConfig(pressure_start=(steps + 1) * dt), pressure=False, data=data)
    s = a.jt
    control = s.tongue.bundle_schedule(Tongue.motion("protrusion")).controller(s.tongue.body)

    def timed(n):
        ms = []
        for _ in range(n):
            t0 = time.perf_counter()
            control(s.scene, s.scene.t, s.scene.t + dt)
            s.scene.step(dt)
            ms.append(1e3 * (time.perf_counter() - t0))
        return float(np.median(ms))

    timed(1)                                              # factorization set-up, compile
    plain = timed(steps)
    s.scene.add(a.pressure)                               # ramped from now on
    timed(1)
    loaded = timed(steps)

    def cost(f, n=max(3, steps)):
        t0 = time.perf_counter()
        for _ in range(n):
            f()
        return 1e3 * (time.perf_counter() - t0) / n

    t = s.scene.t
    return {"steps": steps, "dt": dt, "skin_vertices": a.skin.n,
            "ms_per_step_without_airway": plain, "ms_per_step_with_skin_pressure": loaded,
            "ms_skin_positions": cost(a.skin.positions), "ms_skin_jacobian": cost(a.skin.jacobian),
            "ms_pressure_master_loads": cost(lambda: a.pressure.master_loads(t))}


if __name__ == "__main__":
    import sys

    cli = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_arguments(cli)
    sys.exit(run(cli.parse_args()))
