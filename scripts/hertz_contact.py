"""The Hertz check of docs/contact.md on finer meshes than the test's: an FEM hemisphere
(R = 10 mm, E = 100 kPa, nu = 0.45, neo-Hookean) pressed on a rigid plane with 0.05 N
(artifem.models.hertz_sphere), against a = (3 F R / (4 E*))^(1/3), p0 = 3 F / (2 pi a^2).

    OPENBLAS_NUM_THREADS=1 python scripts/hertz_contact.py [h_mm ...]
    OPENBLAS_NUM_THREADS=1 python scripts/hertz_contact.py --json
    python scripts/hertz_contact.py --markdown

prints, per mesh size at the pole, the contact radius (second moment of the forces, fit
of the Hertz profile to the nodal pressures f_n / A, outermost pressing node) and the
fitted and largest nodal pressure, with their errors against the closed form; ``--json``
runs the default sizes and writes docs/benchmarks/contact_hertz.json, whose figures
docs/contact.md quotes; ``--markdown`` prints that file as the table there
(tests/test_contact_hertz.py checks the page against it).
"""

import json
import pathlib
import platform
import sys
import time

import artifem  # noqa: F401  (before dolfinx)
from artifem.models import hertz_sphere as hs

OUT = pathlib.Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "contact_hertz.json"
SIZES_MM = (0.5, 0.35, 0.25, 0.18, 0.125)


def case(h_mm: float) -> dict:
    a0, p0, _ = hs.hertz()
    start = time.perf_counter()
    r = hs.run(h_mm * 1e-3)
    seconds = time.perf_counter() - start
    return {
        "h_pole_mm": h_mm,
        "nodes": r.nodes,
        "pressing_nodes": r.pressing,
        "force_N": r.force,
        "delta_mm": r.delta * 1e3,
        "radius_moment_mm": r.radius_moment * 1e3,
        "radius_moment_error": r.radius_moment / a0 - 1,
        "radius_fit_mm": r.fit_radius * 1e3,
        "radius_fit_error": r.fit_radius / a0 - 1,
        "radius_outer_node_mm": r.radius_outer * 1e3,
        "radius_outer_node_error": r.radius_outer / a0 - 1,
        "pressure_fit_kPa": r.fit_pressure / 1e3,
        "pressure_fit_error": r.fit_pressure / p0 - 1,
        "pressure_scatter_about_fit": r.fit_scatter,
        "pressure_max_node_kPa": r.peak_pressure / 1e3,
        "pressure_max_node_error": r.peak_pressure / p0 - 1,
        "static_solves": r.static_solves,
        "newton_iterations": r.newton_iterations,
        "seconds": seconds,
    }


def show(row: dict) -> None:
    print(
        f"h = {row['h_pole_mm']:.3f} mm, {row['nodes']} nodes, {row['pressing_nodes']} pressing: "
        f"a (moment) {row['radius_moment_mm']:.4f} mm ({row['radius_moment_error']:+.2%}), "
        f"a (fit) {row['radius_fit_mm']:.4f} mm ({row['radius_fit_error']:+.2%}), "
        f"a (outer node) {row['radius_outer_node_mm']:.4f} mm "
        f"({row['radius_outer_node_error']:+.2%}); p0 (fit) {row['pressure_fit_kPa']:.3f} kPa "
        f"({row['pressure_fit_error']:+.2%}), scatter {row['pressure_scatter_about_fit']:.3f}, "
        f"max nodal p {row['pressure_max_node_kPa']:.3f} kPa "
        f"({row['pressure_max_node_error']:+.2%}); delta {row['delta_mm']:.4f} mm; "
        f"{row['static_solves']} solves, {row['newton_iterations']} Newton iterations, "
        f"{row['seconds']:.1f} s",
        flush=True,
    )


HEADER = (
    "| h at the pole (mm) | nodes | pressing | a, moment (mm) | a, fit (mm) "
    "| a, outermost node (mm) | p0, fit (kPa) | largest nodal p (kPa) | s |\n"
    "|---|---|---|---|---|---|---|---|---|"
)


def render(row: dict) -> str:
    """The row of docs/contact.md's Hertz table (errors against the closed form)."""
    return (
        f"| {row['h_pole_mm']:g} | {row['nodes']:,} | {row['pressing_nodes']} "
        f"| {row['radius_moment_mm']:.3f} ({row['radius_moment_error']:+.1%}) "
        f"| {row['radius_fit_mm']:.3f} ({row['radius_fit_error']:+.1%}) "
        f"| {row['radius_outer_node_mm']:.3f} ({row['radius_outer_node_error']:+.1%}) "
        f"| {row['pressure_fit_kPa']:.2f} ({row['pressure_fit_error']:+.1%}) "
        f"| {row['pressure_max_node_kPa']:.2f} ({row['pressure_max_node_error']:+.0%}) "
        f"| {row['seconds']:.1f} |"
    ).replace("%", " %")


def main(argv: list[str]) -> None:
    if "--markdown" in argv:  # the table of the last --json run
        print(HEADER)
        for row in json.loads(OUT.read_text())["meshes"]:
            print(render(row))
        return
    write = "--json" in argv
    sizes = [float(a) for a in argv if not a.startswith("--")] or list(SIZES_MM)
    rows = []
    for h in sizes:
        rows.append(case(h))
        show(rows[-1])
    if write:
        a0, p0, delta0 = hs.hertz()
        OUT.write_text(
            json.dumps(
                {
                    "what": "FEM hemisphere (neo-Hookean, P1 tetrahedra by gmsh, refined within "
                    "2.5 mm of the pole) pressed on a rigid plane (PlaneContact, statics) "
                    "with 0.05 N, against Hertz's closed form (scripts/hertz_contact.py, "
                    "artifem/models/hertz_sphere.py)",
                    "radius_m": hs.R,
                    "young_Pa": hs.E,
                    "poisson": hs.NU,
                    "force_N": hs.FORCE,
                    "closed_form": {
                        "radius_mm": a0 * 1e3,
                        "peak_pressure_kPa": p0 / 1e3,
                        "approach_mm": delta0 * 1e3,
                    },
                    "machine": platform.node(),
                    "meshes": rows,
                },
                indent=2,
            )
            + "\n"
        )
        print(f"wrote {OUT}")


if __name__ == "__main__":
    main(sys.argv[1:])
