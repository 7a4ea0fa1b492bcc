"""Skeletal registration from files to a report: ``artifem register --reference DIR
--target DIR --out DIR``.

The reference is a :class:`~artifem.registration.skeleton.Skeleton` directory; the target
directory holds ``target.json``: {"units": "m" | "cm" | "mm", "bones": {name: file}}
with one surface per reference bone (open surfaces allowed: a partial target), and
optionally "truth": {"angles": {joint: degrees}, "bones": {name: file}} (the reference's
vertices at their true positions, same order), against which a synthetic case is
checked.

Steps, each bone by the same measures:

1. Checks before any solve: the reference closed and outward with each joint centre
   near both its bones; every bone with a target; the target's size within a factor 2
   of the reference bone's (units); after step 2, target points near every bone.
2. A rigid pre-alignment of the whole reference onto the whole target (ICP with each
   bone's own closest points, from the identity and the principal-axis rotations).
3. The baselines: per-bone rigid ICP and per-bone affine ICP (from the pre-alignment;
   no deformation, no joints), and one deformable structure without joints (every bone
   in one voxel grid); then the jointed deformable bones (:func:`jointed_scene`), both
   by :func:`~artifem.registration.register.register` on the same weights.

Surface distances: model-to-target, each model vertex to the target (the pairs on a
partial target's border left out), mean and RMS; Hausdorff, the larger of the largest
model-vertex and target-vertex distances to the other surface. Writes
``registration.json``, each method's registered bones (``meshes/METHOD_BONE.stl``) and
``registration.png`` (reference, target, and each method's result coloured by distance).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from artifem.errors import InputError
from artifem.registration.forces import RegistrationForces
from artifem.registration.register import register
from artifem.registration.rigid import TriangleSurface, icp, kabsch
from artifem.registration.skeleton import (
    UNITS,
    Skeleton,
    jointed_scene,
    read_surface,
    single_structure_scene,
    write_surface,
    _read_json,
    _units,
)

__all__ = ["Target", "prealign", "register_skeleton", "summary_table", "surface_distances"]

#: the registration weights (N/m per vertex) of the deformable methods, rising; with the
#: grids' Young's modulus E, only w / E matters (statics): the default E = 1 MPa
WEIGHTS = (1e2, 1e3, 1e4)
METHODS = ("rigid", "affine", "single", "jointed")


class Target:
    """A target directory (module docstring): ``surfaces`` bone -> TriangleSurface (m),
    ``truth`` bone -> true vertex positions (m) and ``angles`` joint -> rad, if given."""

    def __init__(self, directory: Path, skeleton: Skeleton):
        directory = Path(directory)
        spec = _read_json(directory / "target.json")
        scale = _units(spec, directory / "target.json")
        files = dict(spec.get("bones", {}))
        missing = [b for b in skeleton.bones if b not in files]
        if missing:
            raise InputError(f"{directory / 'target.json'}: no target for bone(s) {missing}")
        self.surfaces = {
            b: TriangleSurface(*read_surface(directory / files[b], scale)) for b in skeleton.bones
        }
        for bone, surface in self.surfaces.items():
            ref = np.ptp(skeleton.bones[bone][0], axis=0).max()
            size = np.ptp(surface.vertices, axis=0).max()
            if not 0.5 < size / ref < 2.0:
                raise InputError(
                    f"bone {bone!r}: the target spans {size:.4g} m, the "
                    f"reference {ref:.4g} m: units off? (target.json says "
                    f"{spec.get('units')!r}; one of {sorted(UNITS)})"
                )
        truth = spec.get("truth") or {}
        self.truth = {
            b: read_surface(directory / f, scale)[0]
            for b, f in dict(truth.get("bones", {})).items()
        }
        for bone, x in self.truth.items():
            if x.shape != skeleton.bones[bone][0].shape:
                raise InputError(
                    f"{directory / 'target.json'}: the truth of bone {bone!r} "
                    f"has {len(x)} vertices, the reference "
                    f"{len(skeleton.bones[bone][0])}"
                )
        self.angles = {j: float(np.radians(a)) for j, a in dict(truth.get("angles", {})).items()}


def surface_distances(x: np.ndarray, triangles: np.ndarray, target: TriangleSurface) -> dict:
    """Mean, RMS and Hausdorff distance (m) of a model surface to the target (module
    docstring)."""
    d, _, kept = target.closest_kept(x)
    back = TriangleSurface(x, triangles).closest(target.vertices)[0]
    return {
        "mean": float(d[kept].mean()),
        "rms": float(np.sqrt(np.mean(d[kept] ** 2))),
        "hausdorff": float(max(d[kept].max(), back.max())),
    }


def _fit(skeleton: Skeleton, target: Target, names) -> tuple[float, np.ndarray, np.ndarray]:
    """(mean distance, R, t): the rigid ICP of the bones ``names`` together onto their
    targets, each bone to its own, the best of the identity and the principal-axis
    starts."""
    src = np.vstack([skeleton.bones[b][0] for b in names])
    dst = np.vstack([target.surfaces[b].vertices for b in names])

    def axes(p):
        v = np.linalg.eigh(np.cov((p - p.mean(0)).T))[1][:, ::-1]
        return v * np.sign(np.linalg.det(v))

    A, B = axes(src), axes(dst)
    best = None
    for R in [np.eye(3)] + [
        B @ np.diag(s) @ A.T for s in ([1, 1, 1], [-1, -1, 1], [-1, 1, -1], [1, -1, -1])
    ]:
        t = dst.mean(0) - R @ src.mean(0)
        for _ in range(100):
            pairs = [
                (
                    skeleton.bones[b][0],
                    *target.surfaces[b].closest_kept(skeleton.bones[b][0] @ R.T + t)[1:],
                )
                for b in names
            ]
            P = np.vstack([p[k] for p, c, k in pairs])
            C = np.vstack([c[k] for p, c, k in pairs])
            R_new, t_new = kabsch(P, C)
            done = np.abs(R_new - R).max() < 1e-10 and np.abs(t_new - t).max() < 1e-12
            R, t = R_new, t_new
            if done:
                break
        score = float(np.mean(np.linalg.norm(P @ R.T + t - C, axis=1)))
        if best is None or score < best[0]:
            best = (score, R, t)
    return best


def prealign(skeleton: Skeleton, target: Target) -> tuple[np.ndarray, np.ndarray]:
    """(R, t): the rigid map of the whole reference onto the whole target (step 2). If a
    bone then has no target point near it (:func:`_far_bones`), each bone alone is tried
    as the anchor too, and the fit that leaves the fewest bones far is kept (a misplaced
    target then shows as itself, not by the bones it pulled away)."""
    fits = [_fit(skeleton, target, list(skeleton.bones))]
    if _far_bones(skeleton.moved(*fits[0][1:]), target):
        fits += [_fit(skeleton, target, [b]) for b in skeleton.bones]
    _, R, t = min(fits, key=lambda f: (len(_far_bones(skeleton.moved(*f[1:]), target)), f[0]))
    return R, t


def _far_bones(skeleton: Skeleton, target: Target) -> list[tuple[float, str, float]]:
    """(relative, bone, nearest distance) of the bones with no target point within a fifth
    of their size, the farthest (relative to its size) first."""
    far = []
    for bone, (V, T) in skeleton.bones.items():
        size = np.ptp(V, axis=0).max()
        d = TriangleSurface(V, T).closest(target.surfaces[bone].vertices)[0]
        if not np.any(d < 0.2 * size):
            far.append((d.min() / size, bone, d.min()))
    return sorted(far)[::-1]


def _check_near(skeleton: Skeleton, target: Target) -> None:
    """Every bone has target points near it after the pre-alignment, else an error."""
    far = _far_bones(skeleton, target)
    if far:
        raise InputError(
            "no target point within a fifth of the bone's size after the rigid "
            "pre-alignment: "
            + "; ".join(f"bone {b!r} (nearest {d:.3g} m)" for _, b, d in far)
            + ": a target of another bone, or misplaced?"
        )


def _measure(
    skeleton: Skeleton, target: Target, positions: dict, seconds: float, extra: dict
) -> dict:
    out = {"seconds": seconds, "bones": {}, **extra}
    for bone, x in positions.items():
        row = surface_distances(x, skeleton.bones[bone][1], target.surfaces[bone])
        if bone in target.truth:
            e = np.linalg.norm(x - target.truth[bone], axis=1)
            row["truth_mean"], row["truth_max"] = float(e.mean()), float(e.max())
        out["bones"][bone] = row
    return out


def _deformable(builder, skeleton, target, material, cell_size, weights, progress, checkpoint):
    model = builder(skeleton, material, cell_size)
    forces = [
        RegistrationForces(model.skins[b], target.surfaces[b], weights[0], name=b)
        for b in skeleton.bones
    ]
    model.scene.add(*forces)
    result = register(
        model.scene, forces, weights, tol=1e-3 * cell_size, progress=progress, checkpoint=checkpoint
    )
    extra = {
        "weights": result.weights,
        "stage_mean_distance": result.mean_distance,
        "newton_iterations": result.iterations,
        "sweeps": result.sweeps,
        "min_det_F": model.min_det_F(),
        "cells": int(sum(b.mesh.topology.index_map(3).size_local for b in model.bodies)),
    }
    if model.joints:
        extra["joint_angles_deg"] = {j: float(np.degrees(a)) for j, a in model.angles().items()}
        extra["joint_constraint_error"] = float(max(model.scene.constraint_errors().values()))
    return {b: s.positions() for b, s in model.skins.items()}, extra


def register_skeleton(
    reference: Path,
    target_dir: Path,
    out: Path,
    *,
    material,
    cell_size: float,
    weights=WEIGHTS,
    methods=METHODS,
    progress=print,
    resume: bool = False,
) -> dict:
    """Steps 1-3 of the module docstring; returns and writes the report. The deformable
    methods write their state after each weight stage to ``out/METHOD.checkpoint``
    (removed when the method ends); with ``resume`` an interrupted run of the same
    command continues from it, without it an old checkpoint is removed first."""
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InputError(f"register: unknown method(s) {unknown}; choose from {METHODS}")
    skeleton = Skeleton.read(reference)
    skeleton.check(4.0 * cell_size)
    target = Target(target_dir, skeleton)
    R, t = prealign(skeleton, target)
    aligned = skeleton.moved(R, t)
    _check_near(aligned, target)
    out = Path(out)
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    report = {
        "reference": str(reference),
        "target": str(target_dir),
        "cell_size": cell_size,
        "bones": {
            b: {
                "vertices": len(V),
                "triangles": len(T),
                "target_vertices": len(target.surfaces[b].vertices),
            }
            for b, (V, T) in skeleton.bones.items()
        },
        "prealignment": {"R": R.tolist(), "t": t.tolist()},
        "truth_angles_deg": {j: float(np.degrees(a)) for j, a in target.angles.items()},
        "before": _measure(
            skeleton, target, {b: V for b, (V, _) in aligned.bones.items()}, 0.0, {}
        ),
        "methods": {},
    }
    results = {}
    for method in methods:
        progress(f"register: {method} ...")
        start = time.perf_counter()
        if method in ("rigid", "affine"):
            positions, extra = {}, {"iterations": {}}
            for bone, (V, _) in skeleton.bones.items():
                fit = icp(V, target.surfaces[bone], R, t)
                if method == "affine":
                    fit = icp(V, target.surfaces[bone], fit.R, fit.t, affine=True)
                positions[bone] = V @ fit.R.T + fit.t
                extra["iterations"][bone] = fit.iterations
        else:
            builder = jointed_scene if method == "jointed" else single_structure_scene
            with tqdm(
                total=len(weights), desc=f"{method}: weight stages", unit="stage", leave=False
            ) as bar:
                checkpoint = out / f"{method}.checkpoint"
                if not resume:
                    checkpoint.unlink(missing_ok=True)
                positions, extra = _deformable(
                    builder, aligned, target, material, cell_size, list(weights), bar, checkpoint
                )
                checkpoint.unlink(missing_ok=True)
        row = _measure(skeleton, target, positions, time.perf_counter() - start, extra)
        report["methods"][method] = row
        results[method] = positions
        for bone, x in positions.items():
            write_surface(out / "meshes" / f"{method}_{bone}.stl", x, skeleton.bones[bone][1])
        progress(
            f"register: {method}: mean distance "
            + ", ".join(f"{b} {1e3 * r['mean']:.3f} mm" for b, r in row["bones"].items())
            + f" ({row['seconds']:.1f} s)"
        )
    (out / "registration.json").write_text(json.dumps(report, indent=1))
    render(out / "registration.png", aligned, target, results)
    return report


def summary_table(report: dict) -> str:
    """The report as a Markdown table: per method, each bone's mean distance to the target
    (and to the truth, where known) in mm, the largest Hausdorff distance, the seconds."""
    bones = list(report["bones"])
    truth = all("truth_mean" in r for r in report["before"]["bones"].values())
    head = "| method | " + " | ".join(f"{b} (mm)" for b in bones) + " | Hausdorff (mm) | time (s) |"
    lines = [head, "|" + "---|" * (len(bones) + 3)]
    for method, row in {"before": report["before"], **report["methods"]}.items():
        cells = []
        for b in bones:
            r = row["bones"][b]
            cells.append(
                f"{1e3 * r['mean']:.3f}" + (f" ({1e3 * r['truth_mean']:.2f})" if truth else "")
            )
        hausdorff = max(r["hausdorff"] for r in row["bones"].values())
        lines.append(
            f"| {method} | " + " | ".join(cells) + f" | {1e3 * hausdorff:.2f} | "
            f"{row['seconds']:.1f} |"
        )
    return "\n".join(lines)


def render(png: Path, reference: Skeleton, target: Target, results: dict) -> Path:
    """Reference (pre-aligned), target and each method's bones coloured by their distance
    to the target (mm; grey where a partial target does not cover them), side by side."""
    import pyvista as pv

    pv.OFF_SCREEN = True
    panels = [
        ("reference", {b: V for b, (V, _) in reference.bones.items()}, False),
        ("target", None, False),
    ] + [(m, x, True) for m, x in results.items()]
    plotter = pv.Plotter(
        off_screen=True, shape=(1, len(panels)), window_size=[360 * len(panels), 720]
    )
    clim = [0.0, 1.0]
    for i, (title, positions, coloured) in enumerate(panels):
        plotter.subplot(0, i)
        plotter.set_background("white")
        plotter.add_text(title, font_size=11, color="black")
        for bone, (_, T) in reference.bones.items():
            if positions is None:
                s = target.surfaces[bone]
                V, F = s.vertices, s.triangles
            else:
                V, F = positions[bone], T
            mesh = pv.PolyData(V, np.c_[np.full(len(F), 3), F].ravel())
            if coloured:  # grey where the target does not cover the bone
                d, _, kept = target.surfaces[bone].closest_kept(V)
                mesh["distance (mm)"] = np.where(kept, 1e3 * d, np.nan)
                plotter.add_mesh(
                    mesh,
                    scalars="distance (mm)",
                    clim=clim,
                    cmap="viridis",
                    nan_color="lightgray",
                    show_scalar_bar=i == len(panels) - 1,
                )
            else:
                plotter.add_mesh(
                    mesh, color="lightsteelblue" if positions is not None else "salmon"
                )
        plotter.view_xy()
    plotter.link_views()
    plotter.screenshot(str(png))
    plotter.close()
    return Path(png)


def add_arguments(parser) -> None:
    parser.add_argument(
        "--reference",
        required=True,
        type=Path,
        help="skeleton directory (skeleton.json and the bone meshes)",
    )
    parser.add_argument(
        "--target",
        required=True,
        type=Path,
        help="target directory (target.json and one surface per bone)",
    )
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument(
        "--cell-size", type=float, default=0.008, help="voxel grid cell size, m (default 0.008)"
    )
    parser.add_argument(
        "--youngs",
        type=float,
        default=1e6,
        help="the grids' Young's modulus, Pa (neo-Hookean, nu = 0.3)",
    )
    parser.add_argument(
        "--methods",
        default=",".join(METHODS),
        help=f"comma-separated subset of {','.join(METHODS)}",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue an interrupted run from OUT/METHOD.checkpoint",
    )


def run(args) -> int:
    from artifem.forms import NeoHookean

    register_skeleton(
        args.reference,
        args.target,
        args.out,
        material=NeoHookean.from_young_poisson(args.youngs, 0.3),
        cell_size=args.cell_size,
        methods=tuple(args.methods.split(",")),
        resume=args.resume,
    )
    print(f"register: wrote {args.out / 'registration.json'} and registration.png")
    return 0
