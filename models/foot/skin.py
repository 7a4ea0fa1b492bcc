"""Level sets of the assembled foot bones: the skin envelope and the rigid groups' surfaces.

No redistributable foot skin exists, so the skin is built as an offset of the bones:

1. phi(x) = d(x) - t(y) on a regular grid (``spacing``) around the bones below the cap,
   d the signed distance to the union of the bones (igl, winding-number sign, negative
   inside), t the tissue thickness: ``dorsal`` (6 mm) on the dorsum and around the ankle,
   growing smoothly (smoothstep in the height y above the lowest bone point) to
   ``plantar`` (18 mm) below the calcaneus and the metatarsal heads (the plantar fat pad);
2. phi smoothed by a Gaussian (``smooth``), its zero level contoured (vtkFlyingEdges3D),
   the largest component kept;
3. Taubin-smoothed, decimated to about ``triangles`` triangles (igl: shortest edges
   collapsed first, which evens the triangles; collapses that self-intersect blocked);
4. cut by the plane y = y_cap (``cap_height`` above the ankle joint centre, the talus
   origin) and closed there by a flat cap (vtkClipClosedSurface).

The result is closed, manifold and outward oriented (checked by :func:`~.bones.check_closed`).
A rigid group's surface (:func:`group_surface`) is the level set -``shrink`` of the signed
distance to the union of its bones, on a grid of its own: it fuses the bones of a group
into one closed surface and moves it ``shrink`` inside the bones, which widens the gaps
between groups for the mesher.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artifem.errors import MeshError

from .bones import check_closed, signed_volume

#: the ankle joint centre (talus_r origin) in the tibia frame, metres.
ANKLE = np.array([0.0, -0.43, 0.0])


@dataclass(frozen=True)
class SkinParams:
    """The skin envelope's parameters (module docstring), metres."""

    cap_height: float = 0.07
    dorsal: float = 0.006
    plantar: float = 0.018
    plantar_band: tuple[float, float] = (0.004, 0.03)
    spacing: float = 0.002
    smooth: float = 0.002
    triangles: int = 4000

    @property
    def cap_y(self) -> float:
        return float(ANKLE[1] + self.cap_height)


def _merge(surfaces):
    v = np.vstack([s[0] for s in surfaces])
    offsets = np.cumsum([0] + [len(s[0]) for s in surfaces[:-1]])
    return v, np.vstack([s[1] + o for s, o in zip(surfaces, offsets)])


def _polydata(vertices, triangles):
    import pyvista as pv

    faces = np.hstack([np.full((len(triangles), 1), 3), triangles]).ravel()
    return pv.PolyData(np.asarray(vertices, float), faces)


def _arrays(poly) -> tuple[np.ndarray, np.ndarray]:
    poly = poly.triangulate().clean()
    return np.asarray(poly.points, float), poly.faces.reshape(-1, 4)[:, 1:].astype(np.int64)


def signed_distance(points, vertices, triangles) -> np.ndarray:
    """Signed distance of points to a closed surface, negative inside (winding number)."""
    import igl

    return igl.signed_distance(
        np.ascontiguousarray(points, float),
        vertices,
        triangles,
        igl.SIGNED_DISTANCE_TYPE_FAST_WINDING_NUMBER,
    )[0]


def _level_set(lo, hi, spacing, field, level, smooth=0.0, largest=False):
    """The ``level`` surface of field(points) on a grid over [lo, hi] (closed: the field
    is set positive on the grid's faces), outward, inner voids dropped: pyvista PolyData,
    its largest component if ``largest``."""
    import pyvista as pv
    from scipy.ndimage import gaussian_filter

    n = np.ceil((np.asarray(hi) - lo) / spacing).astype(int) + 1
    image = pv.ImageData(dimensions=n, spacing=(spacing,) * 3, origin=lo)
    values = field(np.asarray(image.points))
    values = values.reshape(n[::-1])
    if smooth > 0:
        values = gaussian_filter(values, smooth / spacing)
    for axis in range(3):  # outside on the grid's faces: closed
        values[(slice(None),) * axis + (0,)] = values[(slice(None),) * axis + (-1,)] = 1.0
    image.point_data["phi"] = values.ravel()
    surface = image.contour([level], scalars="phi", method="flying_edges")
    if surface.n_cells == 0:
        raise MeshError("level set: empty contour")
    if largest:
        surface = surface.connectivity("largest").extract_surface(algorithm=None)
    v, f = _arrays(surface)
    labels = _components(len(v), f)
    parts = [f[labels == i] for i in np.unique(labels)]
    volumes = np.array([signed_volume(v, p) for p in parts])
    sign = np.sign(volumes[np.argmax(np.abs(volumes))])  # voids: the other orientation
    f = np.vstack(
        [p if sign > 0 else p[:, ::-1] for p, vol in zip(parts, volumes) if vol * sign > 0]
    )
    return _polydata(v, f).clean()


def _components(n: int, triangles: np.ndarray) -> np.ndarray:
    """Connected component of each triangle (sharing vertices)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = np.repeat(np.arange(len(triangles)), 3)
    graph = coo_matrix(
        (np.ones(rows.size), (rows, len(triangles) + triangles.ravel())),
        shape=(len(triangles) + n,) * 2,
    )
    return connected_components(graph, directed=False)[1][: len(triangles)]


def _decimate(surface, triangles: int):
    """(vertices, triangles) of a surface decimated by shortest-edge collapses (igl, the
    collapses that would make it self-intersect blocked) to about ``triangles``."""
    import igl

    v, f = _arrays(surface)
    if len(f) <= triangles:
        return v, f
    v, f = igl.decimate(
        np.asfortranarray(v), np.asfortranarray(f, dtype=np.int32), int(triangles), True
    )[:2]
    used, f = np.unique(f, return_inverse=True)
    return np.ascontiguousarray(v[used]), f.reshape(-1, 3).astype(np.int64)


def cap(surfaces: list[tuple[np.ndarray, np.ndarray]], cap_y: float):
    """Cut the surfaces by y = cap_y, keep y < cap_y and close the cuts by flat faces
    (vtkClipClosedSurface; inner shells, inward oriented, become holes of the cap)."""
    import pyvista as pv
    import vtk

    planes = vtk.vtkPlaneCollection()
    plane = vtk.vtkPlane()
    plane.SetOrigin(0.0, cap_y, 0.0)
    plane.SetNormal(0.0, -1.0, 0.0)
    planes.AddItem(plane)
    clip = vtk.vtkClipClosedSurface()
    clip.SetClippingPlanes(planes)
    clip.SetInputData(_polydata(*_merge(surfaces)))
    clip.Update()
    v, f = _arrays(pv.wrap(clip.GetOutput()))
    v[np.abs(v[:, 1] - cap_y) < 1e-9, 1] = cap_y
    return v, f


def envelope(bones, params: SkinParams = SkinParams(), capped: bool = True):
    """The skin (vertices, triangles) around the bones (module docstring): closed and
    capped at y = ``params.cap_y`` if ``capped``, else open above the cap (it reaches
    3 grid spacings above it)."""
    v, f = _merge([(b.vertices, b.triangles) for b in bones])
    below = v[:, 1] <= params.cap_y + 0.01
    bottom = float(v[below, 1].min())
    margin = params.plantar + 3 * params.smooth + 2 * params.spacing
    lo = v[below].min(0) - margin
    hi = v[below].max(0) + margin
    hi[1] = params.cap_y + 3 * params.spacing
    a, b = params.plantar_band

    def phi(points):
        s = np.clip((points[:, 1] - bottom - a) / (b - a), 0.0, 1.0)
        s = 1.0 - s * s * (3 - 2 * s)
        return signed_distance(points, v, f) - (
            params.dorsal + (params.plantar - params.dorsal) * s
        )

    surface = _level_set(lo, hi, params.spacing, phi, 0.0, params.smooth, largest=True)
    surface = surface.smooth_taubin(n_iter=30, pass_band=0.1)
    sv, sf = _decimate(surface, params.triangles)
    if not capped:
        return sv, sf
    sv, sf = cap([(sv, sf)], params.cap_y)
    check_closed("skin surface", sv, sf)
    return sv, sf


def group_surface(bones, spacing: float, shrink: float, triangles: int, y_max: float | None = None):
    """One closed surface for a rigid group: the -``shrink`` level set of the signed
    distance to the union of its bones (grid ``spacing``), Taubin-smoothed and decimated to
    about ``triangles`` triangles; the grid stops at ``y_max`` (an open end is closed by
    the contour there, above the cap)."""
    v, f = _merge([(b.vertices, b.triangles) for b in bones])
    lo, hi = v.min(0) - 3 * spacing, v.max(0) + 3 * spacing
    if y_max is not None:
        hi[1] = min(hi[1], y_max)
    surface = _level_set(lo, hi, spacing, lambda p: signed_distance(p, v, f), -shrink)
    surface = surface.smooth_taubin(n_iter=20, pass_band=0.1)
    sv, sf = _decimate(surface, triangles)
    check_closed("group surface " + "+".join(b.name for b in bones), sv, sf)
    return sv, sf
