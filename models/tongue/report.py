"""The report stage of the reduced-model speed-vs-error study (``artifem study tongue``).

Reads what the study driver wrote to DIR -- study.json (model, timings, runs),
series.npz (mean nodal error over time per run) and frames/<id>.npz (full and
reduced displacements at the time of largest error) -- and writes

    error_<motion>.png   mean error over time, one line per configuration (Figs. 3-5 analogs)
    speed_vs_error.png   ms per step against max error, one marker per run, target box shaded
    render_<id>.png      full and reduced deformed meshes side by side, one colour scale
    report.md            model, training, Table 2 analog, all runs, target checks, figures

``python -m artifem.models.tongue.report DIR`` regenerates them from existing files.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from statistics import median
from typing import NamedTuple

import matplotlib
import numpy as np
import pyvista as pv
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from artifem.reduction.generalization_report import write_markdown

pv.OFF_SCREEN = True

#: Table 2 of the paper: per-step ms by basis and number of trained integration points.
PAPER_MS = {
    "extended-modal": {600: 53.2, 300: 33.0, 200: 23.6},
    "trained-pod": {600: 27.7, 300: 15.2, 200: 12.1},
}
PAPER_FULL_MS = 188.9
#: End of the excitation ramp (models.tongue.model.RAMP_TIME, not imported: it needs dolfinx).
RAMP_END = 0.5
#: Motions in the paper's order; others follow alphabetically.
MOTION_ORDER = ("protrusion", "retroflexion", "retraction")
BASIS_NAMES = {
    "extended-modal": "Extended modal",
    "trained-pod": "Trained",
    "modal-derivatives": "Modal derivatives",
}
BASIS_CMAPS = {"extended-modal": "Blues", "trained-pod": "Oranges", "modal-derivatives": "Greens"}
SAMPLING_LINES = {"trained": "-", "random": "--"}
SAMPLING_MARKERS = {"trained": "o", "random": "^"}
#: Largest number of trained points for which the targets are checked.
TARGET_MAX_POINTS = 300


class Config(NamedTuple):
    """A reduced model's configuration: what a run is, apart from its motion."""

    basis: str
    r: int
    points: int
    sampling: str

    def label(self) -> str:
        return f"{self.basis} r={self.r}, {self.points} pts, {self.sampling}"


def config_of(run: dict) -> Config:
    """The configuration of a run."""
    return Config(run["basis"], int(run["r"]), int(run["points"]), run["sampling"])


def _config_key(config: Config) -> tuple:
    """Sort key: paper basis order, then r, trained before random, most points first."""
    basis_rank = list(BASIS_NAMES).index(config.basis) if config.basis in BASIS_NAMES else 99
    return (basis_rank, config.basis, config.r, config.sampling != "trained", -config.points)


def _motion_key(motion: str) -> tuple:
    return (MOTION_ORDER.index(motion) if motion in MOTION_ORDER else 99, motion)


def _run_key(run: dict) -> tuple:
    return (_config_key(config_of(run)), _motion_key(run["motion"]))


def _failed(run: dict) -> bool:
    return bool(run.get("failed", False))


def _fmt(value, spec: str = ".2f") -> str:
    """A number for the tables; "—" when missing or NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    return format(value, spec)


def _basis_color(basis: str, level: float = 0.8):
    """A colour of the basis' colormap (darker for larger ``level`` in [0, 1])."""
    return matplotlib.colormaps[BASIS_CMAPS.get(basis, "Greys")](level)


def _new_figure(size: tuple[float, float]) -> tuple[Figure, object]:
    """A one-axes Agg figure (no pyplot state)."""
    figure = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(figure)
    return figure, figure.subplots()


def load_study(out_dir: Path) -> tuple[dict, np.ndarray, dict[str, np.ndarray]]:
    """(study.json, times, run id -> mean error series in mm) of a study directory."""
    study = json.loads((out_dir / "study.json").read_text())
    with np.load(out_dir / "series.npz") as series:
        times = series["times"]
        errors = {run["id"]: series[f"error/{run['id']}"] for run in study["runs"]}
    return study, times, errors


def plot_error_series(
    study: dict, times: np.ndarray, errors: dict[str, np.ndarray], motion: str, png: Path
) -> Path:
    """Mean nodal error over time of every run of ``motion``: colour by basis (darker
    for more points), line style by sampling, a dashed line at the end of the ramp."""
    runs = sorted((run for run in study["runs"] if run["motion"] == motion), key=_run_key)
    point_counts = sorted({int(run["points"]) for run in runs}, reverse=True)
    levels = dict(zip(point_counts, np.linspace(0.95, 0.5, len(point_counts))))
    figure, axes = _new_figure((8, 4.5))
    for run in runs:
        config = config_of(run)
        label = config.label() + (" (failed)" if _failed(run) else "")
        axes.plot(
            times,
            errors[run["id"]],
            SAMPLING_LINES.get(config.sampling, ":"),
            color=_basis_color(config.basis, levels[config.points]),
            label=label,
        )
    axes.axvline(RAMP_END, color="gray", linestyle="--", linewidth=1, label="end of ramp")
    axes.set(
        title=f"{motion}: mean nodal error of the reduced models",
        xlabel="time (s)",
        ylabel="mean nodal error (mm)",
    )
    axes.set_ylim(bottom=0)
    axes.grid(True, alpha=0.3)
    axes.legend(fontsize="small")
    figure.savefig(png, dpi=120)
    return png


def plot_speed_vs_error(study: dict, png: Path) -> Path:
    """ms per step (log) against max mean error, one marker per run (colour by basis,
    marker by sampling, labelled with the points count); the full model's ms per
    step as a vertical line and the target box shaded."""
    targets, full_ms = study["targets"], study["full"]["ms_per_step"]
    runs = [
        run
        for run in study["runs"]
        if not _failed(run) and np.isfinite([run["ms_per_step"], run["max_error_mm"]]).all()
    ]
    figure, axes = _new_figure((8, 5.5))
    for run in runs:
        config = config_of(run)
        axes.scatter(
            run["ms_per_step"],
            run["max_error_mm"],
            color=_basis_color(config.basis),
            marker=SAMPLING_MARKERS.get(config.sampling, "s"),
            edgecolor="black",
            linewidth=0.5,
            zorder=3,
        )
        axes.annotate(
            str(config.points),
            (run["ms_per_step"], run["max_error_mm"]),
            textcoords="offset points",
            xytext=(5, 4),
            fontsize=8,
        )
    ms = [run["ms_per_step"] for run in runs] + [full_ms, targets["ms_per_step"]]
    errors = [run["max_error_mm"] for run in runs] + [targets["max_error_mm"]]
    xlim = (min(ms) / 2, max(ms) * 2)
    axes.set_xscale("log")
    axes.set_xlim(xlim)
    axes.set_ylim(0, 1.1 * max(errors))
    axes.fill_between(
        [xlim[0], targets["ms_per_step"]],
        0,
        targets["max_error_mm"],
        color="palegreen",
        alpha=0.4,
        zorder=1,
    )
    axes.axvline(full_ms, color="black", linestyle="-", linewidth=1)
    axes.axvline(full_ms / targets["speedup"], color="black", linestyle=":", linewidth=1)
    configs = sorted({config_of(run) for run in runs}, key=_config_key)
    handles = [
        Line2D(
            [],
            [],
            color=_basis_color(basis),
            marker="o",
            linestyle="",
            label=BASIS_NAMES.get(basis, basis),
        )
        for basis in dict.fromkeys(config.basis for config in configs)
    ]
    handles += [
        Line2D(
            [],
            [],
            color="gray",
            marker=SAMPLING_MARKERS.get(sampling, "s"),
            linestyle="",
            label=f"{sampling} points",
        )
        for sampling in sorted({run["sampling"] for run in runs})
    ]
    handles += [
        Line2D([], [], color="black", label=f"full model ({full_ms:.3g} ms)"),
        Line2D([], [], color="black", linestyle=":", label=f"{targets['speedup']:g}x speed-up"),
        Patch(
            color="palegreen",
            alpha=0.4,
            label=f"target: <= {targets['ms_per_step']:g} ms, <= {targets['max_error_mm']:g} mm",
        ),
    ]
    axes.legend(handles=handles, fontsize="small", loc="upper right")
    axes.set(
        title="speed vs error (one marker per run; numbers: integration points)",
        xlabel="ms per step",
        ylabel="max mean nodal error over time (mm)",
    )
    axes.grid(True, which="both", alpha=0.3)
    figure.savefig(png, dpi=120)
    return png


def hex_surface(
    points: np.ndarray, cells: np.ndarray, displacement: np.ndarray, scalars: np.ndarray, name: str
) -> pv.PolyData:
    """Outer surface of the hexahedral mesh displaced by ``displacement``, with
    nodal ``scalars`` as its active scalars ``name`` (all lengths in one unit)."""
    cells = np.asarray(cells, dtype=np.int64)
    grid = pv.UnstructuredGrid({pv.CellType.HEXAHEDRON: cells}, points + displacement)
    grid.point_data[name] = scalars
    return grid.extract_surface(algorithm=None)


def render_frame(
    frame: Path,
    run: dict,
    png: Path,
    camera: str = "xz",
    window_size: tuple[int, int] = (1600, 700),
) -> Path:
    """Full (coloured by |u|) and reduced (coloured by nodal error) meshes of ``frame``
    side by side, in mm, with linked cameras and one colour range."""
    with np.load(frame) as data:
        points, cells, time = 1e3 * data["points"], data["cells"], float(data["time"])
        u_full, u_reduced = 1e3 * data["u_full"], 1e3 * data["u_reduced"]
    panels = [
        (
            hex_surface(points, cells, u_full, np.linalg.norm(u_full, axis=1), "displacement (mm)"),
            f"full model\n{run['motion']}, t = {time:.3f} s",
        ),
        (
            hex_surface(
                points,
                cells,
                u_reduced,
                np.linalg.norm(u_reduced - u_full, axis=1),
                "nodal error (mm)",
            ),
            f"{config_of(run).label()}\n{run['motion']}, t = {time:.3f} s",
        ),
    ]
    clim = (0.0, max(surface.get_data_range()[1] for surface, _ in panels))
    boxes = np.array([surface.bounds for surface, _ in panels]).reshape(2, 3, 2)
    bounds = np.column_stack([boxes[:, :, 0].min(axis=0), boxes[:, :, 1].max(axis=0)]).ravel()
    plotter = pv.Plotter(off_screen=True, shape=(1, 2), window_size=list(window_size))
    try:
        plotter.set_background("white")
        for column, (surface, title) in enumerate(panels):
            plotter.subplot(0, column)
            name = surface.active_scalars_name
            plotter.add_mesh(
                surface,
                scalars=name,
                cmap="viridis",
                clim=clim,
                show_edges=True,
                edge_color="black",
                scalar_bar_args={
                    "title": name,
                    "color": "black",
                    "fmt": "%.3g",
                    "position_x": 0.2,
                    "width": 0.6,
                },
            )
            plotter.add_text(title, font_size=10, color="black")
        plotter.link_views()
        plotter.subplot(0, 0)
        plotter.camera_position = camera
        plotter.reset_camera(bounds=bounds)
        plotter.screenshot(str(png))
    finally:
        plotter.close()
    return png


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """Markdown table lines (cells with "|" or newlines made safe)."""

    def clean(cell) -> str:
        return str(cell).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(map(clean, header)) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(map(clean, row)) + " |" for row in rows]


def _training_lines(training: dict, prefix: str = "") -> list[str]:
    """One bullet per scalar entry of the (possibly nested) training dict."""
    lines = []
    for key, value in training.items():
        if isinstance(value, dict):
            lines += _training_lines(value, f"{prefix}{key}.")
        elif isinstance(value, (str, int, float, bool)) or value is None:
            text = _fmt(value, ".4g") if isinstance(value, float) else value
            lines.append(f"- {prefix}{key}: {text}")
    return lines


def table2_lines(study: dict) -> list[str]:
    """Table 2 analog: per basis (and r) and trained points count, our median ms per
    step over motions, with the paper's value in brackets."""
    trained = [run for run in study["runs"] if run["sampling"] == "trained"]
    rows_of = sorted(
        {(c.basis, c.r) for c in map(config_of, trained)},
        key=lambda row: _config_key(Config(*row, 0, "trained")),
    )
    point_counts = sorted({int(run["points"]) for run in trained}, reverse=True)
    rows = []
    for basis, r in rows_of:
        row = [f"{BASIS_NAMES.get(basis, basis)} (r={r})"]
        for points in point_counts:
            runs = [
                run
                for run in trained
                if (run["basis"], int(run["r"]), int(run["points"])) == (basis, r, points)
            ]
            paper = PAPER_MS.get(basis, {}).get(points)
            row.append(_table2_cell(runs) + (f" ({paper:.1f})" if paper is not None else ""))
        rows.append(row)
    full = study["full"]["ms_per_step"]
    return _md_table(["basis"] + [f"{p} points" for p in point_counts], rows) + [
        "",
        f"Full model: ours {_fmt(full)} ms per step, paper {PAPER_FULL_MS:.1f} ms. "
        f"Cells: our median ms per step over motions (paper's Table 2 value).",
    ]


def _table2_cell(runs: list[dict]) -> str:
    """Median ms over the successful runs; "failed" when none succeeded, "—" when none ran."""
    if not runs:
        return "—"
    ok = [run["ms_per_step"] for run in runs if not _failed(run)]
    if not ok:
        return "failed"
    failed = len(runs) - len(ok)
    return _fmt(median(ok)) + (f" [{failed} failed]" if failed else "")


def runs_table_lines(study: dict) -> list[str]:
    """Every run: configuration, motion, timing, speed-up, errors, status."""
    runs = sorted(study["runs"], key=_run_key)
    volumes = all("max_volume_change" in run for run in runs)
    rows = [
        [
            run["basis"],
            run["r"],
            run["points"],
            run["sampling"],
            run["motion"],
            _fmt(run["ms_per_step"]),
            _fmt(run["speedup"], ".1f"),
            _fmt(run["mean_error_mm"]),
            _fmt(run["max_error_mm"]),
            _fmt(run["max_node_error_mm"]),
        ]
        + (
            [
                _fmt(100 * run["max_volume_change"], ".3f"),
                _fmt(100 * run["full_max_volume_change"], ".3f"),
            ]
            if volumes
            else []
        )
        + [f"FAILED: {run.get('error', '')}" if _failed(run) else "ok"]
        for run in runs
    ]
    return _md_table(
        [
            "basis",
            "r",
            "points",
            "sampling",
            "motion",
            "ms/step",
            "speed-up",
            "mean error (mm)",
            "max error (mm)",
            "max node error (mm)",
        ]
        + (["max volume change (%)", "full model's (%)"] if volumes else [])
        + ["status"],
        rows,
    )


def _motion_check(run: dict | None, motion: str, targets: dict) -> tuple[bool, str]:
    """(run meets every target, one line with the numbers and each check)."""
    if run is None:
        return False, f"{motion}: not run"
    if _failed(run):
        return False, f"{motion}: failed ({run.get('error', '')})"
    checks = [
        (
            run["ms_per_step"] <= targets["ms_per_step"],
            f"{_fmt(run['ms_per_step'])} ms/step (<= {targets['ms_per_step']:g})",
        ),
        (
            run["speedup"] >= targets["speedup"],
            f"speed-up {_fmt(run['speedup'], '.1f')}x (>= {targets['speedup']:g})",
        ),
        (
            run["max_error_mm"] <= targets["max_error_mm"],
            f"max error {_fmt(run['max_error_mm'])} mm (<= {targets['max_error_mm']:g})",
        ),
    ]
    text = ", ".join(f"{what} {'ok' if ok else 'MISSED'}" for ok, what in checks)
    return all(ok for ok, _ in checks), f"{motion}: {text}"


def target_checks(study: dict) -> list[tuple[Config, bool, list[str]]]:
    """Per trained-basis configuration with <= TARGET_MAX_POINTS trained points:
    (config, meets every target on every motion, one line per motion)."""
    motions = sorted({run["motion"] for run in study["runs"]}, key=_motion_key)
    by_config: dict[Config, dict[str, dict]] = {}
    for run in study["runs"]:
        config = config_of(run)
        if (
            config.basis == "trained-pod"
            and config.sampling == "trained"
            and config.points <= TARGET_MAX_POINTS
        ):
            by_config.setdefault(config, {})[run["motion"]] = run
    results = []
    for config in sorted(by_config, key=_config_key):
        checks = [
            _motion_check(by_config[config].get(motion), motion, study["targets"])
            for motion in motions
        ]
        results.append((config, all(ok for ok, _ in checks), [line for _, line in checks]))
    return results


def targets_lines(study: dict) -> list[str]:
    """The Targets section: a PASS/FAIL bullet per checked configuration, with the numbers."""
    targets = study["targets"]
    lines = [
        "## Targets",
        "",
        f"Each trained-basis configuration with at most {TARGET_MAX_POINTS} trained points "
        f"must reach <= {targets['ms_per_step']:g} ms per step, a speed-up >= "
        f"{targets['speedup']:g} and a max mean error <= {targets['max_error_mm']:g} mm "
        f"on every motion.",
        "",
    ]
    results = target_checks(study)
    if not results:
        return lines + ["No such configuration was run."]
    for config, passed, motion_lines in results:
        lines.append(f"- **{'PASS' if passed else 'FAIL'}** {config.label()}")
        lines += [f"  - {line}" for line in motion_lines]
    passed = sum(ok for _, ok, _ in results)
    return lines + ["", f"{passed} of {len(results)} configurations meet every target."]


def _full_model_line(full: dict) -> str:
    """The full model's median ms per step, and per motion."""
    by_motion = sorted(full["ms_per_step_by_motion"].items(), key=lambda item: _motion_key(item[0]))
    return (
        f"Full model: {_fmt(full['ms_per_step'])} ms per step (median over motions; "
        + ", ".join(f"{motion} {_fmt(ms)}" for motion, ms in by_motion)
        + ")."
    )


def _incompressibility_line(study: dict) -> str:
    """How the volume is kept (a study from before the key: the element penalty)."""
    if study.get("incompressibility") == "hard":
        modes = study.get("config", {}).get("pressure_modes")
        return (
            f"Incompressibility: hard (every element's volume held by the full model; the "
            f"reduced bodies hold {modes} pressure modes, the constant one (the total "
            f"volume) and POD modes of the training pressures, with cubature weights fitted "
            f"to the constraint's Jacobian on the training states)."
        )
    return "Incompressibility: the element penalty (full and reduced)."


def greedy_lines(greedy: dict) -> list[str]:
    """The greedy training's iterations (greedy.json): runs, largest estimate, what was
    added and what was rejected (its full run failed)."""
    lines = [
        "## Greedy training",
        "",
        f"From a pool of {greedy['pool']} random schedules (seed {greedy['seed']}), the "
        f"worst estimated added first; stopped: {greedy['stopped']}, {greedy['runs']} "
        f"runs, {greedy['wall_seconds']:.0f} s.",
        "",
    ]
    rows = [
        [
            str(i),
            str(h["runs"]),
            _fmt(h["max_estimate_mm"]),
            h["added"] or "-",
            ", ".join(h["rejected"]) or "-",
        ]
        for i, h in enumerate(greedy["history"])
    ]
    return lines + _md_table(
        [
            "iteration",
            "training runs",
            "largest estimate (mm)",
            "added",
            "rejected (full run failed)",
        ],
        rows,
    )


def report_markdown(
    study: dict,
    figures: Sequence[Path],
    generalization: dict | None = None,
    greedy: dict | None = None,
) -> str:
    """The whole report.md text; ``figures`` are embedded by file name; ``generalization``:
    the train/test split's figures (generalization.json), ``greedy``: the greedy
    training's (greedy.json), if the study ran them."""
    model = study["model"]
    lines = [
        f"# Reduced {model['name']} model: speed vs error",
        "",
        f"Model: {model['name']}, {model['nodes']} nodes, {model['elements']} elements, "
        f"level {model['level']}, {model['dofs']} dofs; dt = {study['dt']:g} s, "
        f"duration {study['duration']:g} s.",
        "",
        _full_model_line(study["full"]),
        "",
        _incompressibility_line(study),
        "",
        "## Training",
        "",
    ]
    lines += _training_lines(study["training"]) or ["(no scalar entries)"]
    if greedy is not None:
        lines += [""] + [
            "#" + line if line.startswith("## ") else line for line in greedy_lines(greedy)
        ]
    lines += ["", "## Per-step time, trained points (Table 2 analog)", ""] + table2_lines(study)
    lines += ["", "## All runs", ""] + runs_table_lines(study)
    lines += [""] + targets_lines(study)
    lines += ["", "## Figures", ""] + [f"![{png.stem}]({png.name})\n" for png in figures]
    if generalization is not None:  # the train/test split (generalization.json)
        lines += ["", "#" + write_markdown(generalization).replace("\n## ", "\n### ")]
    return "\n".join(lines) + "\n"


def write_report(out_dir: Path) -> Path:
    """Write the figures, renders and report.md of the study in ``out_dir``; return report.md."""
    out_dir = Path(out_dir)
    study, times, errors = load_study(out_dir)
    runs = {run["id"]: run for run in study["runs"]}
    motions = sorted({run["motion"] for run in study["runs"]}, key=_motion_key)
    figures = [
        plot_error_series(study, times, errors, motion, out_dir / f"error_{motion}.png")
        for motion in motions
    ]
    figures.append(plot_speed_vs_error(study, out_dir / "speed_vs_error.png"))
    figures += [
        render_frame(frame, runs[frame.stem], out_dir / f"render_{frame.stem}.png")
        for frame in sorted((out_dir / "frames").glob("*.npz"))
    ]
    found = {
        name: json.loads((out_dir / f"{name}.json").read_text())
        if (out_dir / f"{name}.json").exists()
        else None
        for name in ("generalization", "greedy")
    }
    report = out_dir / "report.md"
    report.write_text(report_markdown(study, figures, **found))
    return report


def add_report_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "out_dir",
        type=Path,
        metavar="DIR",
        help="study directory holding study.json, series.npz and frames/",
    )


def run(args: argparse.Namespace) -> int:
    if not (args.out_dir / "study.json").is_file():
        raise SystemExit(f"{args.out_dir}: no study.json (run `artifem study tongue` first)")
    print(f"wrote {write_report(args.out_dir)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m artifem.models.tongue.report",
        description="Regenerate the study report from existing files.",
    )
    add_report_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
