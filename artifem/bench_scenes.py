"""``artifem bench scenes``: milliseconds per coupled step of the anatomical scenes, to JSON.

Each scene module has a ``benchmark(steps=...) -> dict`` that builds its
variants and times them in this process (medians over the timed steps):

- ``jaw-tongue`` (:mod:`artifem.models.jaw_tongue.study`): the jaw-tongue
  scene during protrusion with the full and with the reduced tongue (the
  reduced tongue's training is cached, under $XDG_CACHE_HOME/artifem by default,
  ~/.cache/artifem when that is unset);
- ``airway`` (:mod:`artifem.models.airway.study`): the jaw-tongue scene with the full
  and with the reduced tongue (the jaw-tongue training, same cache), each
  without and with the airway skin and its pressure, and the skin's own
  update costs;
- ``masseter`` (:mod:`artifem.models.masseter.study`): the embedding and the
  conforming masseter, with and without aponeuroses;
- ``foot`` (:mod:`artifem.models.foot.study`): the standing foot, the FEM alone, with
  the bones, with bones and contact, and reduced (the paper's configuration; its training
  cached, by default in $XDG_CACHE_HOME/artifem/foot-reduced, ~/.cache when unset),
  beside the paper's figures.

``--quick``: a smoke test of the command, not figures to quote: the reduced
tongues of ``artifem study jaw-tongue --quick`` (a small training, seconds when
already in ``--cache``), the coarse masseter and :data:`QUICK_STEPS` timed steps.

Unless already set, OMP_NUM_THREADS and OPENBLAS_NUM_THREADS are 1 (one core
per case, like ``artifem bench fom``).
"""

from __future__ import annotations

import importlib
import os
import time
from pathlib import Path

from artifem.arguments import positive_int
from artifem.errors import UnknownNameError

SCENES = {
    "jaw-tongue": "artifem.models.jaw_tongue.study",
    "airway": "artifem.models.airway.study",
    "masseter": "artifem.models.masseter.study",
    "foot": "artifem.models.foot.study",
}
#: Scenes whose benchmark trains a reduced body (they take ``cache``).
TRAINED = ("jaw-tongue", "airway", "foot")
#: ``--quick``: timed steps per case (unless ``--steps``).
QUICK_STEPS = 2


def add_arguments(parser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="JSON file to write")
    parser.add_argument(
        "--scenes", default=",".join(SCENES), help="comma-separated scenes (default: %(default)s)"
    )
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        help=f"timed steps per case (default: each scene's own; with --quick {QUICK_STEPS})",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=None,
        help="reduced tongue training cache of jaw-tongue and airway "
        "(default: $XDG_CACHE_HOME/artifem/jaw_tongue_reduced, ~/.cache when "
        "unset)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a smoke test: the quick reduced tongue (study jaw-tongue "
        f"--quick), the coarse masseter, {QUICK_STEPS} timed steps",
    )


def run(args) -> int:
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = sorted(set(scenes) - set(SCENES))
    if unknown or not scenes:
        raise UnknownNameError(f"--scenes: unknown scenes {unknown}; choose from {sorted(SCENES)}")
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    from artifem.bench import write_report  # after the thread settings

    results, errors = {}, []
    for name in scenes:
        print(f"[bench scenes] {name} ...", flush=True)
        tic = time.perf_counter()
        module = importlib.import_module(SCENES[name])
        kwargs = {} if args.steps is None else {"steps": args.steps}
        if args.quick:
            kwargs = {"steps": QUICK_STEPS, **kwargs, "quick": True}
        if args.cache is not None and name in TRAINED:
            kwargs["cache"] = args.cache
        try:
            results[name] = module.benchmark(**kwargs)
        except Exception as exc:  # keep the other scenes' figures
            errors.append({"scene": name, "error": f"{type(exc).__name__}: {exc}"})
            print(f"[bench scenes] {name} failed: {exc}", flush=True)
            continue
        results[name]["seconds"] = time.perf_counter() - tic
        print(f"[bench scenes] {name}: {results[name].get('cases', results[name])}", flush=True)
    write_report(
        Path(args.out),
        "scenes",
        __doc__.split("\n\n")[0],
        {"scenes": scenes, "steps": args.steps, "quick": args.quick},
        [],
        errors,
        scenes=results,
    )
    print(f"[bench scenes] wrote {args.out}")
    return 1 if errors else 0
