"""The Markdown of a train/test split (:mod:`artifem.reduction.generalization`), from its
generalization.json alone (no model, no dolfinx: the study reports import it)."""

from __future__ import annotations

__all__ = ["SETS", "write_markdown"]

#: The sets of a split, in report order.
SETS = ("training", "motions", "held-out")


def write_markdown(figures: dict) -> str:
    """The report's tables (one per set) from generalization.json's content."""
    m = figures["reduced"]
    lines = [
        f"# {figures['model']}: the reduced model on inputs it was not built from",
        "",
        f"Reduced model: {m['basis']['kind']} basis, r = {m['basis']['r']}"
        + (f" ({m['basis']['lift_columns']} lift columns)" if m["basis"]["lift_columns"] else "")
        + ", "
        f"{m['points']['count']} {m['points']['sampling']} points; trained on "
        f"{m['runs']} runs ({m['snapshots']} snapshots), "
        f"{sum(m['seconds'].values()):.0f} s of training computation "
        f"({', '.join(f'{k} {v:.0f} s' for k, v in m['seconds'].items())}). "
        f"Estimate: the difference to a reference reduced model with r = "
        f"{figures['reference']['basis']['r']} and {figures['reference']['points']['count']}"
        f" points (hierarchical estimate, no full run).",
        "",
    ]
    for name in SETS:
        runs = figures["sets"].get(name, [])
        if not runs:
            continue
        lines += [
            f"## {name}",
            "",
            "| schedule | max error (mm) | mean error (mm) | estimate (mm) | estimate / "
            "error | reduced ms/step | slowest / median step (after the first) | speed-up |",
            "|---|---|---|---|---|---|---|---|",
        ]
        sources = all("projection_mm" in r for r in runs)
        if sources:
            lines[-2] += " best in the basis (mm) | every point (mm) |"
            lines[-1] += "---|---|"
        for r in runs:
            failed = " (reduced failed)" if r["failed"] else ""
            failed += " (full model failed: error until then)" if r.get("full_failed") else ""
            lines.append(
                f"| {r['name']}{failed} | "
                f"{r['max_error_mm']:.2f} | {r['mean_error_mm']:.2f} | "
                f"{r['max_estimate_mm']:.2f} | {r['estimate_ratio']:.2f} | "
                f"{r['reduced_ms_per_step']:.2f} | {r['max_step_over_median']:.1f} | "
                f"{'-' if r['speedup'] is None else format(r['speedup'], '.0f') + 'x'} |"
                + (f" {r['projection_mm']:.2f} | {r['every_point_mm']:.2f} |" if sources else "")
            )
        if sources:
            lines += [
                "",
                "Best in the basis: the full run's M-orthogonal projection on the "
                "reduced basis (no reduced model of this basis does better); every "
                "point: the reduced model of the same basis with every integration "
                "point. The reduced model's error beyond the latter is the cubature's; "
                "from the projection to the latter, the reduced dynamics' own.",
            ]
        lines.append("")
    lines += ["![error over time](generalization.png)", ""]
    worst = figures.get("worst")
    if worst:
        lines += [
            f"The worst moment of the {worst['set']} runs: {worst['run']} at t = "
            f"{worst['time']:.2f} s (mean node error {worst['mean_error_mm']:.2f} mm, "
            f"largest {worst['max_node_error_mm']:.2f} mm); left the full body by |u|, "
            "right the reduced one by its error:",
            "",
            f"![the full and the reduced body at the worst moment]({worst['png']})",
            "",
        ]
    return "\n".join(lines)
