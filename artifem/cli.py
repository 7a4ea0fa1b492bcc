"""The ``artifem`` command line.

    artifem mesh info PATH... [--json]       what a mesh holds, and whether it is sound
    artifem material curves NAME --out PNG   stress-stretch curves of a material
    artifem simulate beam --out DIR          the muscle-driven beam (VTX, PNG, JSON)
    artifem simulate tongue --motion M --out DIR   a speech motion of the tongue
    artifem bench fom --out FILE.json        full-order step timings
    artifem bench tongue --out FILE.json     tongue step timings, levels 0 and 1, 1 and 2 ranks
    artifem bench reduced --out FILE.json    reduced tongue step: parts, FLOPs, GFLOP/s
    artifem study tongue --out DIR           reduced tongue models: speed versus error report
    artifem study scene MODULE:FUNCTION --out DIR   any scene's reduced model: train/test split
    artifem study incompressibility --out DIR   tongue motions, penalty against hard constraint
    artifem study robustness MODEL --out DIR    random valid schedules of the hard kinds: what runs
    artifem demo --out DIR                   the main job (``make demo``)

Each command lives in its own module, which declares its arguments
(``add_arguments``) and runs (``run``).

Bad input ends in one line on stderr, ``artifem: error: ...``, and exit status 2
(as argparse's own errors); a failed solve in ``artifem: solver failed: ...`` and
status 1. ``ARTIFEM_TRACEBACK=1`` shows the Python traceback as well.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from artifem.errors import SolverError

#: subcommand path -> (module, help). The module provides ``add_arguments(parser)``
#: and ``run(args) -> int``; "module:NAME" names ``add_NAME_arguments`` instead,
#: for modules that serve several subcommands with one ``run``.``
COMMANDS = {
    ("mesh", "info"): ("artifem.io.mesh_info", "nodes, elements, volume, det J, bounding box"),
    ("material", "curves"): ("artifem.material_curves",
                             "uniaxial / equibiaxial / shear stress-stretch curves to PNG"),
    ("simulate", "beam"): ("artifem.models.muscle_beam", "muscle-driven cantilever beam"),
    ("simulate", "tongue"): ("artifem.models.tongue.simulate",
                             "ArtiSynth hex tongue: protrusion, retroflexion, retraction"),
    ("simulate", "beam-ellipsoid"): ("artifem.models.beam_ellipsoid",
                                     "FEM beam with a rigid ellipsoid at its end (Fig. 11)"),
    ("simulate", "jaw-tongue"): ("artifem.models.jaw_tongue",
                                 "tongue on a hinged rigid jaw opened by a Hill muscle"),
    ("simulate", "styloglossus"): ("artifem.models.styloglossus",
                                   "external styloglossus on 4 vs 24 support nodes: stress at "
                                   "equal excitation and tension, w >= 0, reduced tongue"),
    ("simulate", "airway"): ("artifem.models.airway",
                             "airway skin over tongue (full or --reduced), jaw and palate, "
                             "with air pressure"),
    ("simulate", "masseter"): ("artifem.models.masseter",
                               "synthetic masseter: embedding vs conforming, aponeuroses"),
    ("bench", "fom"): ("artifem.bench:fom", "full-order FEM step timings to JSON"),
    ("bench", "tongue"): ("artifem.bench:tongue",
                          "tongue step timings (protrusion, levels 0 and 1) to JSON"),
    ("bench", "reduced"): ("artifem.bench_reduced",
                           "reduced tongue step against its floating-point work to JSON"),
    ("bench", "scenes"): ("artifem.bench_scenes",
                          "ms per coupled step: jaw-tongue full/reduced, airway, masseter"),
    ("study", "tongue"): ("artifem.models.tongue.study",
                          "reduced tongue models against the full one: speed versus error"),
    ("study", "jaw-tongue"): ("artifem.models.jaw_tongue_reduced",
                              "jaw-tongue scene, full against reduced tongue: speed, error"),
    ("study", "scene"): ("artifem.scene_study",
                         "any scene's reduced model on training, motions and held-out "
                         "schedules (MODULE:FUNCTION returning a ReducibleScene)"),
    ("study", "robustness"): ("artifem.robustness_study",
                              "how often a model runs on random valid schedules of the hard "
                              "kinds (co-activation, pulses, all at once, release): finished, "
                              "cost against the semi-implicit step, det F, volume"),
    ("study", "incompressibility"): ("artifem.models.tongue.incompressibility",
                                     "tongue motions with the element penalty and with hard "
                                     "incompressibility: volume, landmarks, speed"),
    ("demo",): ("artifem.demo", "the main job: run it and say where the results are"),
}


class _Parser(argparse.ArgumentParser):
    """argparse, with a usage error in one line (the usage is one ``--help`` away)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="artifem", description=__doc__.split("\n\n")[0])
    top = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    groups: dict[str, argparse._SubParsersAction] = {}
    for path, (module, help_text) in COMMANDS.items():
        if len(path) == 1:
            sub = top.add_parser(path[0], help=help_text, description=help_text)
        else:
            if path[0] not in groups:
                group = top.add_parser(path[0], help=f"{path[0]} commands")
                groups[path[0]] = group.add_subparsers(dest="subcommand", required=True,
                                                       metavar="SUBCOMMAND")
            sub = groups[path[0]].add_parser(path[1], help=help_text, description=help_text)
        module, _, name = module.partition(":")
        sub.set_defaults(_module=module)
        add_arguments = f"add_{name}_arguments" if name else "add_arguments"
        getattr(importlib.import_module(module), add_arguments)(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    args = parser.parse_args(argv)
    args._argv = list(argv)             # the command itself: to run it again (a study under MPI)
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except (ValueError, OSError, SolverError) as exc:
        # artifem's InputError (a ValueError) and SolverError, the materials' ValueError
        # (forms/ imports nothing of artifem) and unreadable or unwritable files
        if os.environ.get("ARTIFEM_TRACEBACK"):
            raise
        kind = "solver failed" if isinstance(exc, SolverError) else "error"
        print(f"{parser.prog}: {kind}: {exc}", file=sys.stderr)
        return 1 if isinstance(exc, SolverError) else 2


if __name__ == "__main__":
    sys.exit(main())
