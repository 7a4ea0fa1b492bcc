"""The reduced standing foot in several configurations against the full foot, on the
held-out body weight (docs/foot.md, "Reduced configurations"): POD vectors, integration
points random or trained; a configuration whose run stops is recorded with the reason.

    OPENBLAS_NUM_THREADS=1 python scripts/foot_reduced_configs.py [--level 0|1]
                                  [--configs 6:100:random,6:100:trained]

writes docs/foot/reduced_configs_level<L>.json (the full foot runs once). The training
runs are cached in $XDG_CACHE_HOME/artifem/foot-reduced (~/.cache when unset; shared
with ``artifem study foot --reduced``).
"""

import argparse
import json
import pathlib
import time
from dataclasses import replace

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.models.foot import reduced as fr
from artifem.models.foot.study import REDUCED_CACHE

DOCS = pathlib.Path(__file__).resolve().parents[1] / "docs" / "foot"
#: (POD vectors, points, sampling)
CONFIGS = [
    (6, 100, "random"),
    (12, 100, "random"),
    (12, 400, "random"),
    (6, 100, "trained"),
    (20, 200, "trained"),
]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--level", type=int, default=0, choices=(0, 1))
    parser.add_argument(
        "--configs", default=None, help="POD:POINTS:SAMPLING,... (default: all of CONFIGS)"
    )
    args = parser.parse_args()
    level = args.level
    configs = (
        CONFIGS
        if args.configs is None
        else [(int(r), int(p), s) for r, p, s in (c.split(":") for c in args.configs.split(","))]
    )
    tic = time.perf_counter()
    results = fr.compare(
        "standing",
        {
            f"{r}:{points}:{sampling}": replace(
                fr.PAPER, level=level, r=r, points=points, sampling=sampling
            )
            for r, points, sampling in configs
        },
        REDUCED_CACHE,
        progress=False,
    )
    rows = []
    for (r, points, sampling), result in zip(configs, results.values()):
        row = {"pod_vectors": r, "points": points, "sampling": sampling}
        row.update(
            {
                k: result[k]
                for k in (
                    "reduced_ms_per_step",
                    "full_ms_per_step",
                    "max_mean_node_error_mm",
                    "max_node_error_mm",
                    "failure",
                )
                if k in result
            }
        )
        print(row, flush=True)
        rows.append(row)
    out = DOCS / f"reduced_configs_level{level}.json"
    out.write_text(
        json.dumps(
            {
                "case": "standing",
                "held_out_level": fr.HELD_OUT["standing"],
                "level": level,
                "seconds": time.perf_counter() - tic,
                "configs": rows,
            },
            indent=2,
        )
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
