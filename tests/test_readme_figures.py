"""The measured figures of the documentation pages are the ones in the JSON
files the commands write (docs/benchmarks/*.json: ``artifem bench fom|tongue|scenes``,
the studies' JSON), and the verification page's mutation figures those of
scripts/mutation-study's report. A figure edited by hand, or a JSON refreshed without the
text, fails here."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def section(page: str, heading: str) -> str:
    """The section of docs/<page> that starts with ``heading``, up to the next ``## ``."""
    text = (ROOT / "docs" / page).read_text()
    start = text.index(heading)
    end = text.find("\n## ", start + 1)
    return text[start:] if end < 0 else text[start:end]


# The README's measurement notes, moved into the pages they belong to when the README
# became a front door (issue 33): each section as it now stands on its page.
#: the suite and its claims in short (the README's "Verification")
SUITE = section("verification.md", "## The suite (`make test`)")
#: the box's and the tongue's step times (the README's "Benchmark")
BENCHMARK = section("benchmarks.md", "## Step times of the default solver")
#: reduced coordinates and the tongue study (the README's section of that name)
REDUCED = section("tongue_study.md", "## Reduced coordinates and the tongue study in short")
#: the multibody layer and the scenes' step times (the README's "Multibody")
MULTIBODY = section("multibody.md", "## In short, and what the scenes cost")
#: the registration's cases (the README's "Registration")
REGISTRATION = section("registration.md", "## In short (`artifem register`")


def load(name):
    return json.loads((ROOT / "docs" / "benchmarks" / name).read_text())


def printed(text: str) -> tuple[float, float]:
    """(value, half a unit of its last printed digit) of '1,136', '61.4' or '**382.1**'."""
    text = text.strip().strip("*").replace(",", "")
    decimals = len(text.split(".")[1]) if "." in text else 0
    return float(text), 0.5 * 10.0**-decimals + 1e-9


def agrees(text: str, value: float) -> bool:
    shown, half = printed(text)
    return abs(shown - value) <= half


def table_after(marker: str, text: str) -> list[list[str]]:
    """The cells of the first Markdown table after ``marker`` in ``text`` (a page)."""
    lines = text[text.index(marker) :].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip("|").split("|")])
    return rows


@pytest.mark.parametrize(
    "name, marker, key",
    [
        ("fom.json", "(`docs/benchmarks/fom.json`)", "nodes"),
        ("tongue.json", "`docs/benchmarks/tongue.json`:", "level"),
    ],
)
def test_step_tables_match_the_benchmark_json(name, marker, key):
    cases = {(c[key], c["ranks"]): c for c in load(name)["cases"]}
    rows = table_after(marker, BENCHMARK)
    assert len(rows) == len(cases)
    for row in rows:
        first = int(printed(row[0])[0])
        ranks = int(row[2] if key == "level" else row[1])
        case = cases[(first, ranks)]
        cols = row[1:] if key == "nodes" else row[2:]
        if key == "level":
            assert agrees(row[1], case["nodes"])
        ms, assembly, solve, its, mb = cols[1:6]
        assert agrees(ms, case["ms_per_step"]), (row, case["ms_per_step"])
        assert agrees(assembly, case["assembly_ms"]) and agrees(solve, case["solve_ms"]), row
        assert abs(printed(its)[0] - case["iterations"]) <= 0.5, row
        assert agrees(mb, case["peak_mb"]), row


def test_scene_step_costs_match_scenes_json():
    scenes = load("scenes.json")["scenes"]
    jt, air, mas = scenes["jaw-tongue"]["cases"], scenes["airway"], scenes["masseter"]["cases"]
    text = re.sub(
        r"\s+", " ", MULTIBODY[MULTIBODY.index("`artifem bench scenes --out FILE.json` times") :]
    )
    m = re.search(
        r"jaw-tongue step takes ([\d.,]+) ms with the full tongue and ([\d.,]+) ms with "
        r"the reduced one \(([\d.]+)x\)",
        text,
    )
    assert m, "the jaw-tongue sentence changed: update this test with it"
    assert agrees(m[1], jt["full"]["ms_per_step"]) and agrees(m[2], jt["reduced"]["ms_per_step"])
    assert agrees(m[3], jt["speedup"])
    m = re.search(
        r"airway costs ([\d.,]+) ms per step with the full tongue and ([\d.,]+) ms with "
        r"its skin and the 1 kPa pressure; with the reduced tongue ([\d.,]+) and "
        r"([\d.,]+) ms \(([\d.]+)x and ([\d.]+)x",
        text,
    )
    assert m, "the airway sentence changed: update this test with it"
    full, red = air["cases"]["full"], air["cases"]["reduced"]
    for shown, value in zip(
        m.groups(),
        [
            full["ms_per_step_without_airway"],
            full["ms_per_step_with_skin_pressure"],
            red["ms_per_step_without_airway"],
            red["ms_per_step_with_skin_pressure"],
            air["speedup"]["ms_per_step_without_airway"],
            air["speedup"]["ms_per_step_with_skin_pressure"],
        ],
    ):
        assert agrees(shown, value), (shown, value)
    m = re.search(
        r"masseter takes ([\d.,]+) ms conforming, ([\d.,]+) ms conforming with embedded "
        r"membranes, ([\d.,]+) ms on the voxel grid with membranes, and ([\d.,]+) ms with "
        r"conforming aponeurosis slabs \(([\d.,]+) masters\)",
        text,
    )
    assert m, "the masseter sentence changed: update this test with it"
    for shown, value in zip(
        m.groups(),
        [
            mas["conforming/none"]["ms_per_step"],
            mas["conforming/embedded"]["ms_per_step"],
            mas["embedding/embedded"]["ms_per_step"],
            mas["conforming/slabs"]["ms_per_step"],
            mas["conforming/slabs"]["masters"],
        ],
    ):
        assert abs(printed(shown)[0] - value) <= max(printed(shown)[1], 0.5), (shown, value)


def test_fom_targets_sentence_matches_fom_json():
    cases = {(c["nodes"], c["ranks"]): c["ms_per_step"] for c in load("fom.json")["cases"]}
    m = re.search(r"both are met \((\d+) and (\d+) ms\)", BENCHMARK)
    assert m and agrees(m[1], cases[(3025, 2)]) and agrees(m[2], cases[(13284, 2)])


def test_jaw_tongue_reduced_table_matches_its_study_json():
    """| full | 78-83 |; | reduced | 4.5-4.8 (17x) | 0.82-1.06 mm; jaw angle within 0.15 deg |:
    ranges over the three motions of docs/jaw_tongue_reduced/jaw_tongue_reduced.json."""
    study = json.loads(
        (ROOT / "docs" / "jaw_tongue_reduced" / "jaw_tongue_reduced.json").read_text()
    )["motions"].values()
    rows = {
        r[0].split(" (")[0]: r
        for r in table_after("DIR`; POD of full jaw-tongue training", MULTIBODY)
    }

    def span(text):
        lo, hi = text.split(" ")[0].split("-")
        return lo, hi

    full, reduced = (
        [m["full_ms_per_step"] for m in study],
        [m["reduced_ms_per_step"] for m in study],
    )
    lo, hi = span(rows["full"][1])
    assert agrees(lo, min(full)) and agrees(hi, max(full))
    lo, hi = span(rows["reduced"][1])
    assert agrees(lo, min(reduced)) and agrees(hi, max(reduced))
    speedup = re.search(r"\((\d+)x\)", rows["reduced"][1])[1]
    assert agrees(speedup, sum(f / r for f, r in zip(full, reduced)) / len(full))
    errors = [m["max_mean_error_mm"] for m in study]
    lo, hi = re.match(r"([\d.]+)-([\d.]+) mm", rows["reduced"][2]).groups()
    assert agrees(lo, min(errors)) and agrees(hi, max(errors))
    angle = float(re.search(r"within ([\d.]+) deg", rows["reduced"][2])[1])
    assert max(m["max_angle_difference_deg"] for m in study) <= angle


def test_mutation_runs_on_the_verification_page_match_mutation_json():
    """The table of the mutation study's runs (before, and after the tests written against
    its survivors) is the report's: commits, how much of the sample ran, counts and rates;
    the page names the tool and the sample."""
    report = load("mutation.json")
    page = (ROOT / "docs" / "verification.md").read_text()
    section = page[page.index("## Mutation study") :]
    tool, version = report["tool"].split()
    assert f"{tool} {version}" in section
    assert f"draws {report['sample']['mutants']} of them (seed {report['sample']['seed']})" in (
        re.sub(r"\s+", " ", section)
    )
    rows = {row[0]: row for row in table_after("| run | commit |", section)}
    assert set(rows) == set(report["runs"]), "a run of mutation.json is missing from the page"
    for label, run in report["runs"].items():
        t, row = run["totals"], rows[label]
        assert row[1].strip("`") == run["commit"][:7], label
        done = f"{t['mutants']} of {report['sample']['mutants']}"
        assert row[2] == (done if not run["complete"] else str(t["mutants"])), label
        counts = [int(c) for c in row[3:8]]
        assert counts == [
            t["killed"],
            t["timeout"],
            t["survived"],
            t["not_executed"],
            t["equivalent"],
        ], label
        assert agrees(row[8].removesuffix(" %"), 100 * t["kill_rate"]), label
        assert agrees(row[9].removesuffix(" %"), 100 * t["kill_rate_non_equivalent"]), label


def test_hand_written_mutation_figures_on_the_verification_page_match_their_json():
    totals = load("mutation_hand_written.json")["totals"]
    page = (ROOT / "docs" / "verification.md").read_text()
    text = re.sub(r"\s+", " ", page[page.index("## Mutation study") :])
    m = re.search(
        r"(\d+) scripted mutations .*?: (\d+) killed, (\d+) survived, a kill rate of "
        r"(\d+) % \((\d+) % of the (\d+) non-equivalent mutants",
        text,
    )
    assert m, "the mutation sentence changed: update this test with it"
    mutants, killed, survived, rate, rate_relevant, relevant = (int(g) for g in m.groups())
    assert (mutants, killed, survived) == (totals["mutants"], totals["killed"], totals["survived"])
    assert relevant == totals["mutants"] - totals["equivalent"] - totals["stale"] - totals["error"]
    assert agrees(str(rate), 100 * totals["kill_rate"])
    assert agrees(str(rate_relevant), 100 * totals["kill_rate_non_equivalent"])


def test_suite_figures_match_the_durations_json():
    """The size and time of the suite on docs/verification.md are those of the run that wrote
    tests/durations.json (``make test-durations``: a passing run, empty JIT cache)."""
    run = json.loads((ROOT / "tests" / "durations.json").read_text())
    m = re.search(
        r"The run that wrote `tests/durations.json` .*? ran ([\d,]+) tests in "
        r"([\d.]+) minutes of pytest",
        re.sub(r"\s+", " ", SUITE),
    )
    assert m, "docs/verification.md's section on the suite must quote tests/durations.json"
    assert int(m.group(1).replace(",", "")) == run["tests"]
    assert agrees(m.group(2), run["wall_s"] / 60.0)
    slowest = max(run["seconds_per_file"], key=run["seconds_per_file"].get)
    assert slowest in SUITE, "the section on the suite names the longest test file of that run"


def test_held_out_figures_match_the_generalization_jsons():
    """The train/test split table of docs/tongue_study.md and its summary's sentence: ranges
    of the max error per set and of the estimate ratio on the held-out set, from
    docs/tongue_study/level0_generalization{_each_alone,}/, level0_greedy/ and
    level1_generalization/generalization.json."""
    page = (ROOT / "docs" / "tongue_study.md").read_text()
    for label, folder in (
        ("each exciter alone", "level0_generalization_each_alone"),
        ("and 20 random schedules", "level0_generalization"),
        ("and 20 greedy of a pool of 30", "level0_greedy"),
        ("level 1, and 20 random schedules", "level1_generalization"),
    ):
        split = json.loads(
            (ROOT / "docs" / "tongue_study" / folder / "generalization.json").read_text()
        )
        row = next(line for line in page.splitlines() if line.startswith(f"| {label}"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert int(cells[1]) == split["reduced"]["runs"]
        assert agrees(cells[2].removesuffix(" s"), sum(split["reduced"]["seconds"].values()))
        for cell, name in zip(cells[3:6], ("training", "motions", "held-out")):
            errors = [r["max_error_mm"] for r in split["sets"][name]]
            lo, hi = cell.split("-")
            assert agrees(lo, min(errors)) and agrees(hi, max(errors))
            quoted = {
                "each exciter alone": ("motions", "held-out"),
                "and 20 random schedules": ("held-out",),
                "and 20 greedy of a pool of 30": (),
                "level 1, and 20 random schedules": (),
            }[label]
            if name in quoted:  # the summary's sentence
                assert f"{min(errors):.2f}-{max(errors):.2f} mm" in REDUCED.replace("\n", " ")
        ratios = [r["estimate_ratio"] for r in split["sets"]["held-out"]]
        lo, hi = cells[6].split("-")
        assert agrees(lo, min(ratios)) and agrees(hi, max(ratios))


def test_distributed_training_table_matches_its_jsons():
    """docs/tongue_study.md's table of training on 1 and 2 ranks, from
    docs/tongue_study/distributed_training/ranks{1,2}/training.json."""
    page = (ROOT / "docs" / "tongue_study.md").read_text()
    one = None
    for ranks in (1, 2):
        run = json.loads(
            (
                ROOT
                / "docs"
                / "tongue_study"
                / "distributed_training"
                / f"ranks{ranks}"
                / "training.json"
            ).read_text()
        )
        assert run["ranks"] == ranks and run["missing"] == run["runs"]
        row = next(line for line in page.splitlines() if line.startswith(f"| {ranks} |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[1] == ", ".join(str(len(names)) for names in run["by_rank"])
        assert agrees(cells[2].removesuffix(" s"), run["wall_seconds"])
        assert agrees(cells[3].removesuffix(" s"), run["compute_seconds"])
        one = one or run["wall_seconds"]
        assert agrees(cells[4], one / run["wall_seconds"])


def test_reduced_step_table_matches_the_bench_json():
    """docs/tongue_study.md's table of a reduced step's parts, from
    docs/benchmarks/reduced.json (artifem bench reduced)."""
    page = (ROOT / "docs" / "tongue_study.md").read_text()
    penalty, hard = json.loads((ROOT / "docs" / "benchmarks" / "reduced.json").read_text())["cases"]
    assert (penalty["incompressibility"], hard["incompressibility"]) == ("penalty", "hard")
    labels = {
        "stresses": "| stresses",
        "tangent": "| tangent",
        "force": "| force",
        "kinematics": "| kinematics",
        "rest": "| rest",
    }
    for part, label in labels.items():
        row = next(line for line in page.splitlines() if line.startswith(label))
        cells = [c.strip() for c in row.strip("|").split("|")]
        for case, first in ((penalty, 1), (hard, 4)):
            figures = case["parts"][part]
            assert agrees(cells[first], figures["ms"])
            assert agrees(cells[first + 1], figures["flops"] / 1e6)
            assert agrees(cells[first + 2], figures["gflops_per_s"])
    row = next(line for line in page.splitlines() if line.startswith("| step (median"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    for case, first in ((penalty, 1), (hard, 4)):
        assert agrees(cells[first], case["ms_per_step"])
        assert agrees(cells[first + 1], case["flops_per_step"] / 1e6)
        assert agrees(cells[first + 2], case["gflops_per_s"])
    flops = ", ".join(f"{k['flops_per_point']:,}" for k in penalty["kernels"][2:])
    assert flops.replace(", 7", " and 7") in page.replace("\n", " ")
    assert f"{penalty['ms_per_step']:.3f} ms per step at r = 20, m = 300" in page
    assert (
        f"{penalty['ms_per_step']:.3f} ms per step with the penalty and "
        f"{hard['ms_per_step']:.3f} ms with the"
    ) in REDUCED.replace("\n", " ")
    assert (
        f"{penalty['max_step_over_median']:.2f}x the median (penalty) and "
        f"{hard['max_step_over_median']:.2f}x (hard)"
    ) in page.replace("\n", " ")


def test_level1_split_figures_match_their_jsons():
    """The level-1 bullet of docs/tongue_study.md's split: held-out errors, steps, the
    slowest step, the estimate, the training's wall and compute seconds."""
    page = (ROOT / "docs" / "tongue_study.md").read_text().replace("\n  ", " ")
    folder = ROOT / "docs" / "tongue_study" / "level1_generalization"
    held = json.loads((folder / "generalization.json").read_text())["sets"]["held-out"]
    training = json.loads((folder / "training.json").read_text())
    assert training["ranks"] == 2 and training["level"] == 1
    errors = sorted(r["max_error_mm"] for r in held)
    below = [e for e in errors if e <= 1.0]
    above = [e for e in errors if e > 1.0]
    assert " and ".join(f"{e:.2f}" for e in below) + " mm)" in page
    assert f"({min(above):.2f}-{max(above):.2f} mm)" in page
    ms = [r["reduced_ms_per_step"] for r in held]
    assert f"{min(ms):.2f}-{max(ms):.2f} ms" in page
    assert f"at most {max(r['max_step_over_median'] for r in held):.1f}x" in page
    ratios = [r["estimate_ratio"] for r in held]
    assert f"within {min(ratios):.2f}-{max(ratios):.2f} of the error" in page
    assert f"{training['wall_seconds']:,.0f} s on two ranks" in page
    text = REDUCED.replace("\n", " ")
    assert (
        f"{errors[0]:.2f}-{errors[-1]:.2f} mm on the held-out schedules at "
        f"{min(ms):.2f}-{max(ms):.2f} ms" in text
    )
    assert f"{training['compute_seconds']:,.0f} s of computation" in page
    best = [r["projection_mm"] for r in held]
    every = [r["every_point_mm"] for r in held]
    assert f"within {min(best):.2f}-{max(best):.2f} mm of the r = 20 basis" in page
    assert f"is off by {min(every):.2f}-{max(every):.2f} mm, as much as" in page
    ratio = [e / b for e, b in zip(every, best)]
    assert f"error, {min(ratio):.1f}-{max(ratio):.1f}x the best approximation" in page
    assert f"basis holds those runs within {max(best):.2f} mm" in text
    r30 = json.loads(
        (ROOT / "docs" / "tongue_study" / "level1_r30" / "generalization.json").read_text()
    )
    assert r30["reduced"]["basis"]["r"] == 30 and r30["reduced"]["points"]["count"] == 300
    held = r30["sets"]["held-out"]
    for pattern, key in (
        ("lie within {}-{} mm", "projection_mm"),
        ("is off by {}-{} mm", "max_error_mm"),
        ("({}-{} mm with every point)", "every_point_mm"),
        ("at {}-{} ms per step", "reduced_ms_per_step"),
    ):
        values = [r[key] for r in held]
        assert pattern.format(f"{min(values):.2f}", f"{max(values):.2f}") in page, key


def test_styloglossus_reduced_sentence_matches_its_json():
    table = json.loads((ROOT / "docs" / "img" / "styloglossus.json").read_text())["table"]
    errors = [r["error_vs_full"] for r in table if "error_vs_full" in r]
    speedups = [e["speedup"] for e in errors]
    attachment = [e["attachment_mm"] for e in errors]
    found = re.search(
        r"runs it (\d+)-(\d+)x faster with ([\d.]+)-([\d.]+) mm attachment error", MULTIBODY
    )
    assert found, "docs/multibody.md's styloglossus sentence is gone"
    assert agrees(found[1], min(speedups)) and agrees(found[2], max(speedups))
    assert agrees(found[3], min(attachment)) and agrees(found[4], max(attachment))


def test_jaw_tongue_split_figures_match_their_jsons():
    """The jaw-tongue split sentence of docs/tongue_study.md and the table of
    docs/reduction.md, from docs/jaw_tongue_split/{generalization,training}.json."""
    root = ROOT / "docs" / "jaw_tongue_split"
    split = json.loads((root / "generalization.json").read_text())["sets"]
    training = json.loads((root / "training.json").read_text())
    held = split["held-out"]
    text = re.sub(r"\s+", " ", REDUCED)
    found = re.search(
        r"\((\d+) training runs shared over two ranks in ([\d.]+) s\) the reduced "
        r"model stays within ([\d.]+)-([\d.]+) mm of the full one on six held-out "
        r"schedules, (\d+)-(\d+)x faster, its estimate within ([\d.]+)-([\d.]+)",
        text,
    )
    assert found, "docs/tongue_study.md's jaw-tongue split sentence is gone"
    assert int(found[1]) == training["runs"] == training["missing"] and training["ranks"] == 2
    assert agrees(found[2], training["wall_seconds"])
    errors = [r["max_error_mm"] for r in held]
    speedups = [r["speedup"] for r in held]
    ratios = [r["estimate_ratio"] for r in held]
    assert len(held) == 6
    assert agrees(found[3], min(errors)) and agrees(found[4], max(errors))
    assert agrees(found[5], min(speedups)) and agrees(found[6], max(speedups))
    assert agrees(found[7], min(ratios)) and agrees(found[8], max(ratios))
    page = (ROOT / "docs" / "reduction.md").read_text()
    rows = {
        line.split("|")[1].strip(): [c.strip() for c in line.strip().strip("|").split("|")]
        for line in page[page.index("| set | runs |") :].splitlines()[2:5]
    }
    for label, name in (
        ("training", "training"),
        ("the three", "motions"),
        ("held-out", "held-out"),
    ):
        row = next(v for k, v in rows.items() if k.startswith(label))
        runs = split[name]
        assert int(row[1]) == len(runs)
        for col, key in ((2, "max_error_mm"), (3, "estimate_ratio"), (4, "reduced_ms_per_step")):
            lo, hi = row[col].split("-")
            values = [r[key] for r in runs]
            assert agrees(lo, min(values)) and agrees(hi, max(values)), (name, key)


def test_hard_against_penalty_bullet_matches_its_jsons():
    """docs/tongue_study.md: the same each-alone training, hard and penalty, with the
    error's sources."""
    page = (ROOT / "docs" / "tongue_study.md").read_text().replace("\n  ", " ")
    held = {
        inc: json.loads(
            (
                ROOT / "docs" / "tongue_study" / f"level0_sources_{inc}" / "generalization.json"
            ).read_text()
        )["sets"]["held-out"]
        for inc in ("hard", "penalty")
    }

    def span(values, unit=""):
        return f"{min(values):.2f}-{max(values):.2f}{unit}"

    def gap(runs):
        ratios = [r["every_point_mm"] / r["projection_mm"] for r in runs]
        return f"{min(ratios):.1f}-{max(ratios):.1f}x"

    hard, penalty = held["hard"], held["penalty"]
    assert (
        f"off by {span([r['max_error_mm'] for r in hard], ' mm')} on the held-out "
        f"schedules, against {span([r['max_error_mm'] for r in penalty], ' mm')} with "
        "the penalty"
    ) in page
    assert (
        f"at {span([r['reduced_ms_per_step'] for r in hard], ' ms')} per step against "
        f"{span([r['reduced_ms_per_step'] for r in penalty], ' ms')}"
    ) in page
    assert f"its error is {gap(hard)} the best" in page and f"against {gap(penalty)} with" in page
    lower = sum(h["max_error_mm"] < p["max_error_mm"] for h, p in zip(hard, penalty))
    assert (
        f"lowers the error on {['no', 'one', 'two', 'three', 'four', 'five', 'all'][lower]} "
        "of the six" in page
    )
    assert [r["name"] for r in hard if r["full_failed"]] == ["held-out-1000-2"]


def test_robustness_page_matches_its_jsons():
    """docs/robustness.md's table: each row is docs/robustness/<directory>/robustness.json
    (``artifem study robustness``)."""
    page = (ROOT / "docs" / "robustness.md").read_text()
    lines = page[page.index("| model (directory) |") :].splitlines()[2:]
    rows = [
        [c.strip() for c in line.strip("|").split("|")] for line in lines if line.startswith("|")
    ]
    assert len(rows) >= 3
    for name, finished, median, worst, fallbacks, halvings, det, volume in rows:
        s = json.loads((ROOT / "docs" / "robustness" / name / "robustness.json").read_text())[
            "summary"
        ]
        assert finished.replace(" ", "") == f"{s['finished']}/{s['schedules']}", name
        assert agrees(median, s["median_cost"]) and agrees(worst, s["worst_cost"]), name
        assert (int(fallbacks), int(halvings)) == (s["fallbacks"], s["halvings"]), name
        assert agrees(det, s["min_det_F"]), name
        shown, exponent = volume.split("e")
        assert agrees(shown, s["max_volume_change"] / 10.0 ** int(exponent)), name


def test_static_newton_counts_on_the_verification_page_match_their_json():
    """docs/verification.md's table of static Newton iterations: the "now" column is
    scripts/static_newton_counts.py's rendering of docs/benchmarks/static_newton.json, and
    the membrane's first-increment deflections are that file's."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "static_newton_counts", ROOT / "scripts" / "static_newton_counts.py"
    )
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    results = load("static_newton.json")
    page = (ROOT / "docs" / "verification.md").read_text()
    section = page[page.index("## Static Newton") :]
    section = section[: section.index("\n## ")] if "\n## " in section else section
    rows = [line for line in section.splitlines() if line.startswith("| ")][1:]
    now = {line.strip("|").split("|")[-1].strip() for line in rows}
    for name in script.CASES:
        assert script.render(results[name]) in now, name
    first = results["membrane16_first_increment"]
    text = re.sub(r"\s+", " ", section)
    m = re.search(
        r"deflects it ([\d.]+) m \(16 x 16\), (\w+) times its equilibrium "
        r"deflection of ([\d.]+) m",
        text,
    )
    assert m, "the membrane sentence changed: update this test with it"
    assert agrees(m[1], -first["linear_step_min_uz"])
    assert agrees(m[3], -first["equilibrium_min_uz"])
    assert m[2] == "four" and 3.5 <= first["linear_step_min_uz"] / first["equilibrium_min_uz"] < 4.5
    m = re.search(
        r"The loaded solve takes ([\d.]+) s \(the JSON's `seconds`; the unloaded one ([\d.]+) s\)",
        text,
    )
    assert m, "the foot's solve-time sentence changed: update this test with it"
    assert agrees(m[1], results["foot_standing"]["seconds"])
    assert agrees(m[2], results["foot_unloaded"]["seconds"])
    smaller = first["first_increment_at_a_fraction_of_40_pa"]
    m = re.search(r"takes (\d+) iterations at 1/16 of the 40 Pa load and (\d+) at 1/64", text)
    assert m, "the smaller load steps' sentence changed: update this test with it"
    assert (int(m[1]), int(m[2])) == (smaller["1/16"], smaller["1/64"])


def test_the_tongue_drop_on_the_contact_page_matches_its_json():
    """docs/contact.md's tongue dropped on a floor: the figures of
    ``artifem bench contact --tongue`` (docs/benchmarks/contact_tongue.json)."""
    case = load("contact_tongue.json")["cases"][0]
    page = (ROOT / "docs" / "contact.md").read_text()
    text = re.sub(r"\s+", " ", page[page.index("## The tongue dropped on a floor") :])
    m = re.search(
        r"\*\*([\d.]+) ms per step\*\* \(median, ([\d.]+)x the free fall\), up to "
        r"(\d+) contact rows, the deepest node ([\d.e+-]+) mm below the floor",
        text,
    )
    assert m, "the tongue sentence changed: update this test with it"
    assert agrees(m[1], case["step_ms"]) and agrees(m[2], case["ratio_to_no_contact"])
    assert int(m[3]) == case["max_rows"]
    assert float(m[4]) == pytest.approx(case["deepest_below_floor_mm"], rel=0.06)
    assert case["deepest_below_floor_mm"] <= case["tolerance_mm"]
    assert abs(case["normal_over_weight_at_end"] - 1.0) < 0.01 and case["halvings"] == 0


def test_the_contact_scale_figure_of_the_python_api_page_matches_the_bench_json():
    """docs/python_api.md's contact cost at 500 active rows: the rule's path for the 484
    points of ``artifem bench contact`` (docs/benchmarks/contact.json) on its largest
    block."""
    cases = [
        c
        for c in load("contact.json")["cases"]
        if c["kind"] == "fem" and c["points"] == 484 and c["mu"] == 0 and "forced_path" not in c
    ]
    assert len(cases) == 1
    m = re.search(
        r"500 active rows on a ([\d,]+)-node block cost ([\d.]+)x the step without "
        r"contact",
        re.sub(r"\s+", " ", (ROOT / "docs" / "python_api.md").read_text()),
    )
    assert m, "the Python API page's contact sentence changed: update this test with it"
    assert int(m[1].replace(",", "")) == cases[0]["nodes"]
    assert agrees(m[2], cases[0]["ratio_to_no_contact"])
    assert cases[0]["active_rows"] >= 480


def test_the_foot_figures_match_its_json():
    """docs/foot.md's table and sentences and docs/multibody.md's foot sentence: the figures of
    ``artifem study foot --level 1 --reduced --no-vtx --out docs/foot``
    (docs/foot/standing/foot.json)."""
    figures = json.loads((ROOT / "docs" / "foot" / "standing" / "foot.json").read_text())
    ms, standing = figures["ms_per_step"], figures["standing"]
    paper, red = figures["reduced"]["paper"], figures["reduced"]["trained"]
    page = (ROOT / "docs" / "foot.md").read_text()
    rows = {r[0]: r for r in table_after("| ms per step |", page)}
    assert agrees(rows["FEM alone (bone surfaces fixed)"][1], ms["fem_alone"])
    assert agrees(rows["with the bones (no contact)"][1], ms["with_bones"])
    assert agrees(rows["with bones and contact"][1], ms["with_bones_and_contact"])
    for name, config in (("random", paper), ("trained", red)):
        row = next(r for k, r in rows.items() if k.startswith("reduced") and name in k)
        assert agrees(row[1], config["reduced_ms_per_step"]), name
    text = re.sub(r"\s+", " ", page)
    m = re.search(
        r"floor carries ([\d.]+) N against ([\d.]+) N of load and weight "
        r"\(relative difference ([\d.e+-]+)\)",
        text,
    )
    assert m, "the foot page's balance sentence changed: update this test with it"
    assert agrees(m[1], standing["floor_normal_N"])
    assert agrees(m[2], standing["load_plus_weight_N"])
    assert float(m[3]) == pytest.approx(standing["relative_error"], rel=0.06)
    m = re.search(
        r"against one full run of (\d+) ms per step, on 100 trained points: max "
        r"mean node error ([\d.]+) mm \(largest node error ([\d.]+) mm; largest "
        r"displacement ([\d.]+) mm\), (\d+) ms per step, ([\d.]+)x; on the paper's "
        r"100 random points: ([\d.]+) mm, (\d+) ms per step, ([\d.]+)x",
        text,
    )
    assert m, "the foot page's reduced sentence changed: update this test with it"
    for shown, value in zip(
        m.groups(),
        (
            red["full_ms_per_step"],
            red["max_mean_node_error_mm"],
            red["max_node_error_mm"],
            red["max_displacement_mm"],
            red["reduced_ms_per_step"],
            red["speedup"],
            paper["max_mean_node_error_mm"],
            paper["reduced_ms_per_step"],
            paper["speedup"],
        ),
    ):
        assert agrees(shown, value), (shown, value)
    m = re.search(
        r"These are medians; the means are (\d+) ms \(trained\) and (\d+) ms "
        r"\(random\) against (\d+) ms",
        text,
    )
    assert m, "the foot page's sentence on the means changed: update this test with it"
    for shown, value in zip(
        m.groups(), (red["reduced_ms_mean"], paper["reduced_ms_mean"], red["full_ms_mean"])
    ):
        assert agrees(shown, value), (shown, value)
    m = re.search(r"last 20 steps, the load settled, take (\d+) ms \(median\)", text)
    assert m and agrees(m[1], np.median(red["full_ms"][-20:]))
    m = re.search(r"peak ([\d,.]+) kPa under the heel and ([\d.]+) kPa under the forefoot", text)
    assert m and agrees(m[1], standing["peak_pressure_by_region_kPa"]["rearfoot"])
    assert agrees(m[2], standing["peak_pressure_by_region_kPa"]["forefoot"])
    m = re.search(
        r"The foot \(.*?\): ([\d,]+) nodes, ([\d,]+) ms per step with bones and "
        r"contact .*?; reduced on 100 trained points ([\d.]+) ms per step "
        r"\(median; mean ([\d.]+) ms.*?\), max mean node error ([\d.]+) mm .*?the "
        r"paper's 100 random points: ([\d.]+) mm\)",
        re.sub(r"\s+", " ", MULTIBODY),
    )
    assert m, "docs/multibody.md's foot sentence changed: update this test with it"
    assert int(m[1].replace(",", "")) == figures["nodes"]
    assert agrees(m[2], ms["with_bones_and_contact"])
    assert agrees(m[3], red["reduced_ms_per_step"])
    assert agrees(m[4], red["reduced_ms_mean"])
    assert agrees(m[5], red["max_mean_node_error_mm"])
    assert agrees(m[6], paper["max_mean_node_error_mm"])


def test_the_foot_lift_figures_match_its_json():
    """docs/foot.md's lift: ``artifem study foot --case lift --level 1 --reduced --no-vtx
    --out docs/foot`` (docs/foot/lift/foot.json)."""
    figures = json.loads((ROOT / "docs" / "foot" / "lift" / "foot.json").read_text())
    lift, reduced = figures["lift"], figures["reduced"]
    text = re.sub(r"\s+", " ", (ROOT / "docs" / "foot.md").read_text())
    m = re.search(r"0.3 s, at (\d+) ms per step with bones and contact", text)
    assert m and agrees(m[1], figures["ms_per_step"]["with_bones_and_contact"])
    m = re.search(
        r"against one full run \((\d+) ms per step\): on 100 trained points the max "
        r"mean node error is ([\d.]+) mm \(largest node error ([\d.]+) mm; largest "
        r"displacement ([\d.]+) mm\), (\d+) ms per step; on the paper's 100 random "
        r"points ([\d.]+) mm, (\d+) ms",
        text,
    )
    assert m, "the foot page's reduced lift sentence changed: update this test with it"
    trained, paper = reduced["trained"], reduced["paper"]
    for shown, value in zip(
        m.groups(),
        (
            trained["full_ms_per_step"],
            trained["max_mean_node_error_mm"],
            trained["max_node_error_mm"],
            trained["max_displacement_mm"],
            trained["reduced_ms_per_step"],
            paper["max_mean_node_error_mm"],
            paper["reduced_ms_per_step"],
        ),
    ):
        assert agrees(shown, value), (shown, value)
    m = re.search(
        r"The talus turns ([\d.]+) degrees in dorsiflexion and the first metatarsal "
        r"rises by ([\d.]+) mm; the tibialis anterior pulls with (\d+) N and the "
        r"stretched soleus resists with (\d+) N",
        text,
    )
    assert m, "the foot page's lift sentence changed: update this test with it"
    for shown, key in zip(
        m.groups(),
        ("talus_dorsiflexion_deg", "first_metatarsal_rise_mm", "tibialis_anterior_N", "soleus_N"),
    ):
        assert agrees(shown, lift[key]), key


def test_the_foot_reduced_configurations_match_their_json():
    """docs/foot.md's table of reduced configurations: scripts/foot_reduced_configs.py
    (docs/foot/reduced_configs_level0.json)."""
    configs = json.loads((ROOT / "docs" / "foot" / "reduced_configs_level0.json").read_text())[
        "configs"
    ]
    rows = table_after(
        "| POD vectors | integration points |", (ROOT / "docs" / "foot.md").read_text()
    )
    assert len(rows) == len(configs)
    for row, config in zip(rows, configs):
        assert int(row[0]) == config["pod_vectors"]
        assert row[1] == f"{config['points']} {config['sampling']}"
        if "failure" in config:
            shown = re.search(r"stops at t = ([\d.]+) s", row[2])[1]
            assert agrees(
                shown, float(re.search(r"step failed at t = ([\d.]+) s", config["failure"])[1])
            )
        else:
            assert agrees(row[2], config["max_mean_node_error_mm"])
            assert agrees(row[3].split()[0], config["reduced_ms_per_step"])


def test_registration_figures_match_their_jsons():
    """docs/registration.md holds each case's table as summary_table writes it from
    docs/registration/CASE/registration.json (``artifem study registration``), and the
    sentence of its summary quotes the synthetic and femur cases."""
    from artifem.registration.skeletal import summary_table

    page = (ROOT / "docs" / "registration.md").read_text()
    reports = {
        case: json.loads((ROOT / "docs" / "registration" / case / "registration.json").read_text())
        for case in ("rigid", "synthetic", "complete", "femur")
    }
    for case, report in reports.items():
        assert summary_table(report) in page, case
    text = re.sub(r"\s+", " ", REGISTRATION)
    methods = reports["synthetic"]["methods"]
    for method in ("jointed", "rigid", "affine", "single"):
        means = sorted(1e3 * r["mean"] for r in methods[method]["bones"].values())
        assert f"{means[0]:.3f} to {means[-1]:.3f}" in text, method
    assert f"{methods['jointed']['joint_constraint_error']:.0e} m" in text
    assert f"in {sum(m['seconds'] for m in methods.values()):.0f} s" in text
    femur = reports["femur"]["methods"]
    for method in ("jointed", "rigid", "affine"):
        assert f"{1e3 * femur[method]['bones']['femur']['mean']:.3f}" in text
    angles = reports["rigid"]["methods"]["jointed"]["joint_angles_deg"]
    worst = max(abs(angles[j] - a) for j, a in reports["rigid"]["truth_angles_deg"].items())
    assert worst < 0.002 and "within 0.002 degrees" in text


def test_galerkin_gap_tables_and_figures_match_their_jsons():
    """docs/tongue_study.md's Galerkin-gap section: each table is the one its JSON makes
    (``artifem study tongue --galerkin-gap``), and the level-0 bullets' ranges are its."""
    from artifem.reduction.galerkin_gap import write_markdown

    raw = (ROOT / "docs" / "tongue_study.md").read_text()
    page = raw.replace("\n  ", " ")
    folders = sorted(
        f.parent for f in (ROOT / "docs" / "tongue_study").glob("level*_gap/galerkin_gap.json")
    )
    assert [f.name for f in folders][:1] == ["level0_gap"]
    for folder in folders:
        figures = json.loads((folder / "galerkin_gap.json").read_text())
        assert write_markdown(figures["runs"]) in raw, folder.name
    runs = json.loads((folders[0] / "galerkin_gap.json").read_text())["runs"]

    def span(values, unit=""):
        return f"{min(values):.2f}-{max(values):.2f}{unit}"

    assert (
        "within "
        + span([abs(r["static_mm"] - r["reduced_mm"]) for r in runs], " mm")
        + " of the reduced run's error on every run"
        in page
    )
    ratios = [r["galerkin_static_mm"] / r["best_static_mm"] for r in runs]
    assert f"{min(ratios):.1f}-{max(ratios):.1f}x the mass-weighted best" in page
    volumetric = [
        r["residual_share"]["volumetric"]
        for r in runs
        if max(r["residual_share"], key=r["residual_share"].get) == "volumetric"
    ]
    assert f"({span(volumetric)} of its norm, but for" in page
    assert "still " + span([r["full_lag_mm"] for r in runs], " mm") + " from its own" in page
    converged = [r for r in runs if np.isfinite(r["oracle_pg_mm"])]
    assert (
        f"from {span([r['galerkin_static_mm'] for r in converged])} mm to "
        f"{span([r['oracle_pg_mm'] for r in converged])} mm against a best approximation "
        f"of {span([r['best_static_mm'] for r in converged], ' mm')}"
    ) in page
    closer = [r for r in runs if r["without_volumetric_mm"] < r["static_mm"]]
    assert len(closer) == 1 and "further from the full run on five of the six" in page
    learned = {r["run"]: r["learned_pg_mm"] for r in runs}
    helped = [
        r
        for r in runs
        if np.isfinite(learned[r["run"]]["80"])
        and learned[r["run"]]["80"] < r["galerkin_static_mm"]
    ]
    assert (
        len(helped) == 4
        and (
            f"brings the equilibrium error of four runs from "
            f"{span([r['galerkin_static_mm'] for r in helped])} mm to "
            f"{span([learned[r['run']]['80'] for r in helped])} mm (best "
            f"{span([r['best_static_mm'] for r in helped])})"
        )
        in page
    )
    five = learned["held-out-1000-5"]
    assert f"worse than Galerkin ({five['20']:.2f} at p = 20 and 40" in page
    assert f"{five['40']:.2f}" == f"{five['20']:.2f}" and not np.isfinite(five["80"])
    assert not any(np.isfinite(v) for v in learned["held-out-1000-4"].values())
    summary = REDUCED.replace("\n", " ")
    count = ["no", "one", "two", "three", "four", "five", "six"][len(helped)]
    assert f"closes most of the gap on {count} of six held-out runs at level 0" in summary


def test_quick_split_table_matches_its_json():
    """The verification page's quick splits: each command, the range of the largest error
    per set and of the held-out estimate ratio, and the training described, from
    docs/benchmarks/quick_splits.json (scripts/quick_splits.py)."""
    splits = load("quick_splits.json")["splits"]
    text = section("verification.md", "## Quick train/test splits")
    rows = {row[0]: row for row in table_after("| split |", text)}
    assert set(rows) == set(splits)

    def span(values):
        return [min(values), max(values)]

    for name, split in splits.items():
        row, sets = rows[name], split["sets"]
        assert row[1] == f"`artifem {' '.join(split['argv'])}`"
        cells = [*row[2:5], row[5]]
        figures = [
            *(
                span([r["max_error_mm"] for r in sets[s].values()])
                for s in ("training", "motions", "held-out")
            ),
            span([r["estimate_ratio"] for r in sets["held-out"].values()]),
        ]
        for cell, (lo, hi) in zip(cells, figures):
            shown = cell.split("-")
            assert agrees(shown[0], lo) and agrees(shown[1], hi), (name, cell, lo, hi)
    tongue, jaw = splits["tongue"]["reduced"], splits["jaw-tongue"]["reduced"]
    prose = re.sub(r"\s+", " ", text)
    assert (
        f"The tongue's quick training is {tongue['runs']} runs of "
        f"{splits['tongue']['training_duration']} s (each exciter alone), its split's model "
        f"trained POD r = {tongue['basis']['size']} with {tongue['points']['count']} trained "
        f"points; the jaw-tongue's is {jaw['runs']} runs of "
        f"{splits['jaw-tongue']['training_duration']} s, r = {jaw['basis']['size']} POD "
        "vectors and the jaw's "
        f"{jaw['basis']['lift_columns']} lift columns, {jaw['points']['count']} trained points"
    ) in prose
