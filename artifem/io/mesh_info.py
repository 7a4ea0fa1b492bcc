"""`artifem mesh info PATH... [--json]`: sizes, volume and validity of mesh files."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from artifem.io.mesh_checks import (
    classify_orientation,
    corner_jacobians,
    degenerate_elements,
    volume,
)
from artifem.errors import MeshError
from artifem.io.mesh_data import MeshData
from artifem.io.readers import read_mesh

_ID_LIST_LIMIT = 50


def _blocks(mesh: MeshData) -> list[MeshData]:
    """One single-type MeshData per volume cell block (ids/tags are row numbers/0 for
    the non-primary blocks of a mixed mesh)."""
    blocks = [mesh]
    for cell_type, cells in mesh.cells_by_type.items():
        if cell_type != mesh.cell_type:
            blocks.append(
                replace(
                    mesh,
                    cell_type=cell_type,
                    cells=cells,
                    cell_ids=np.arange(len(cells)),
                    cell_tags=np.zeros(len(cells), dtype=np.int32),
                    cells_by_type={cell_type: cells},
                )
            )
    return blocks


def describe(mesh: MeshData) -> dict:
    """Summary of a mesh: counts, tags, volume, bounding box, det J and bad elements.

    min_det_j is the smallest corner det J (reference cells of mesh_checks);
    min_det_j_ratio the smallest per-element ratio min/max |corner det J|
    (1 for a parallelepiped, <= 0 for inverted or tangled elements).
    """
    used = np.unique(np.concatenate([c.ravel() for c in mesh.cells_by_type.values()]))
    lo, hi = mesh.points[used].min(axis=0), mesh.points[used].max(axis=0)
    tags, tag_counts = np.unique(mesh.cell_tags, return_counts=True)
    info = {
        "source": mesh.source,
        "nodes": len(mesh.points),
        "unused_nodes": len(mesh.points) - len(used),
        "elements": {t: len(c) for t, c in mesh.cells_by_type.items()},
        "skipped_cells": dict(mesh.skipped_cells),
        "cell_tags": {int(t): int(n) for t, n in zip(tags, tag_counts)},
        "volume": volume(mesh),
        "bounding_box": {"min": lo.tolist(), "max": hi.tolist(), "size": (hi - lo).tolist()},
    }
    min_det, min_ratio, inverted, tangled, degenerate = None, None, [], [], []
    for block in _blocks(mesh):

        def label(rows, block=block):
            ids = block.cell_ids[rows].tolist()
            return ids if block is mesh else [f"{block.cell_type} {i}" for i in ids]

        dets = corner_jacobians(block.points, block.cell_type, block.cells)
        smallest = dets.min(axis=1)
        ratio = smallest / np.abs(dets).max(axis=1)
        if min_det is None or smallest.min() < min_det["value"]:
            row = int(smallest.argmin())
            min_det = {"value": float(smallest[row]), "element": label([row])[0]}
        if min_ratio is None or ratio.min() < min_ratio["value"]:
            row = int(ratio.argmin())
            min_ratio = {"value": float(ratio[row]), "element": label([row])[0]}
        inv, tan = classify_orientation(block.points, block.cell_type, block.cells)
        inverted += label(inv)
        tangled += label(tan)
        degenerate += [
            {"element": label([row])[0], "collapses_to": what}
            for row, what in degenerate_elements(block)
        ]
    info["min_det_j"] = min_det
    info["min_det_j_ratio"] = min_ratio
    info["inverted"] = {"count": len(inverted), "elements": inverted[:_ID_LIST_LIMIT]}
    info["tangled"] = {"count": len(tangled), "elements": tangled[:_ID_LIST_LIMIT]}
    info["degenerate"] = {"count": len(degenerate), "elements": degenerate[:_ID_LIST_LIMIT]}
    return info


def _unique_meshes(paths: list[str]) -> list[Path]:
    """Paths with the two halves of an ANSYS .node/.elem pair counted once."""
    seen, unique = set(), []
    for p in map(Path, paths):
        key = p.with_suffix("") if p.suffix.lower() in (".node", ".elem") else p
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def mesh_info(paths: list[str]) -> dict[str, dict]:
    """describe() of every mesh file in ``paths`` (keyed by path); raises MeshError."""
    return {str(p): describe(read_mesh(p, allow_degenerate=True)) for p in _unique_meshes(paths)}


def _format(path: str, info: dict) -> str:
    """Readable multi-line table of one describe() result."""

    def vec(v):
        return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"

    def bad(entry):
        shown = [
            f"{e['element']} -> {e['collapses_to']}" if isinstance(e, dict) else str(e)
            for e in entry["elements"]
        ]
        more = " ..." if entry["count"] > len(shown) else ""
        return f"{entry['count']}" + (f": {', '.join(shown)}{more}" if shown else "")

    box = info["bounding_box"]
    rows = [
        ("nodes", f"{info['nodes']} ({info['unused_nodes']} not used by any element)"),
        ("elements", ", ".join(f"{n} {t}" for t, n in info["elements"].items())),
        (
            "skipped cells",
            ", ".join(f"{n} {t}" for t, n in info["skipped_cells"].items()) or "none",
        ),
        ("cell tags", ", ".join(f"{t}: {n}" for t, n in info["cell_tags"].items())),
        ("volume", f"{info['volume']:.6g}"),
        ("bounding box", f"min {vec(box['min'])}  max {vec(box['max'])}"),
        ("box size", vec(box["size"])),
        ("min det J", f"{info['min_det_j']['value']:.4g} (element {info['min_det_j']['element']})"),
        (
            "min det ratio",
            f"{info['min_det_j_ratio']['value']:.4g} "
            f"(element {info['min_det_j_ratio']['element']})",
        ),
        ("inverted", bad(info["inverted"])),
        ("tangled", bad(info["tangled"])),
        ("degenerate", bad(info["degenerate"])),
    ]
    return "\n".join([path] + [f"  {name:<14} {value}" for name, value in rows])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the `mesh info` arguments (paths, --json) to ``parser``."""
    parser.add_argument(
        "paths",
        nargs="+",
        metavar="PATH",
        help="mesh files (.node/.elem, .msh, .geo, .vtu, .inp, ...)",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args: argparse.Namespace) -> int:
    """Print info on each mesh in ``args.paths``; return 0, or 1 if any could not be read."""
    results, failed = {}, False
    for path in _unique_meshes(args.paths):
        try:
            results[str(path)] = describe(read_mesh(path, allow_degenerate=True))
        except (MeshError, OSError) as exc:
            failed = True
            results[str(path)] = {"error": str(exc)}
            if not args.json:
                print(f"error: {exc}", file=sys.stderr)
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        print("\n\n".join(_format(p, i) for p, i in results.items() if "error" not in i))
    return 1 if failed else 0
