"""The ``artifem`` command line.

    artifem mesh info PATH... [--json]       what a mesh holds, and whether it is sound
    artifem material curves NAME --out PNG   stress-stretch curves of a material
    artifem simulate MODEL --out DIR [--case C] [--level L]   a model's scene, run (VTX,
                                             PNG, JSON; artifem.models.runner)
    artifem bench fom --out FILE.json        full-order step timings
    artifem bench tongue --out FILE.json     tongue step timings, levels 0 and 1, 1 and 2 ranks
    artifem bench reduced --out FILE.json    reduced tongue step: parts, FLOPs, GFLOP/s
    artifem bench contact --out FILE.json    ms per step against the contact rows
    artifem study tongue --out DIR           reduced tongue models: speed versus error report
    artifem study scene MODULE:FUNCTION --out DIR   any scene's reduced model: train/test split
    artifem study incompressibility --out DIR   tongue motions, penalty against hard constraint
    artifem study robustness MODEL --out DIR    random valid schedules of the hard kinds: what runs
    artifem study registration --out DIR     skeletal registration cases (synthetic, femur)
    artifem register --reference D --target D --out DIR   register a skeleton to surfaces
    artifem demo --out DIR                   the main job (``make demo``)

Each command lives in its own module, which declares its arguments
(``add_arguments``) and runs (``run``).

Bad input ends in one line on stderr, ``artifem: error: ...``, and exit status 2
(as argparse's own errors); a failed solve in ``artifem: solver failed: ...`` and
status 1. ``ARTIFEM_TRACEBACK=1`` shows the Python traceback as well.

Under ``mpiexec -n N`` (N > 1) each command runs, or refuses, as its entry in
:data:`COMMANDS` says (``tests/test_mpi_cli.py`` launches every ``simulate`` model on
2 ranks):

- ``DISTRIBUTED``: on every rank, its FEM bodies distributed (output from rank 0);
- ``ONE_RANK``: a serial model, on rank 0 alone in a fresh serial process, said on stderr
  before the work; the other ranks sleep until it ends and exit with its status;
- a refusal (any other string, the reason): ``artifem COMMAND: error: ...`` on rank 0 and
  status 2 on every rank, before any work.

An error raised on some ranks only would leave the others waiting in a collective call
for ever, so under ``mpiexec`` an error (after its message) or a crash on any rank of a
distributed command ends every rank (``MPI_Abort``, the exit status of the error).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback

from mpi4py import MPI

from artifem.errors import SolverError
from artifem.reduction.distributed import continue_alone

#: how a command runs under ``mpiexec -n N``, N > 1 (module docstring); any other value
#: of a command's entry is the reason it refuses.
DISTRIBUTED = "distributed"
ONE_RANK = "one rank"
#: the reason of the benchmarks that launch their own ``mpiexec`` runs.
OWN_MPIEXEC = "launches its own mpiexec runs (1 and 2 ranks); run it without mpiexec"
#: the reason of the benchmarks that time one process.
ONE_PROCESS = "times the steps of one process; run it without mpiexec"

#: subcommand path -> (module, help, under mpiexec). The module provides
#: ``add_arguments(parser)`` and ``run(args) -> int``; "module:NAME" names
#: ``add_NAME_arguments`` instead, for modules that serve several subcommands with one
#: ``run``. The third entry: DISTRIBUTED, ONE_RANK or the reason it refuses.
COMMANDS = {
    ("mesh", "info"): (
        "artifem.io.mesh_info",
        "nodes, elements, volume, det J, bounding box",
        ONE_RANK,
    ),
    ("material", "curves"): (
        "artifem.material_curves",
        "uniaxial / equibiaxial / shear stress-stretch curves to PNG",
        ONE_RANK,
    ),
    ("simulate", "beam"): (
        "artifem.models.muscle_beam",
        "muscle-driven cantilever beam",
        DISTRIBUTED,
    ),
    ("simulate", "tongue"): (
        "artifem.models.tongue.model",
        "ArtiSynth hex tongue: protrusion, retroflexion, retraction",
        DISTRIBUTED,
    ),
    ("simulate", "beam-ellipsoid"): (
        "artifem.models.beam_ellipsoid.model",
        "FEM beam with a rigid ellipsoid at its end (Fig. 11)",
        ONE_RANK,
    ),
    ("simulate", "jaw-tongue"): (
        "artifem.models.jaw_tongue.model",
        "tongue on a hinged rigid jaw opened by a Hill muscle",
        ONE_RANK,
    ),
    ("simulate", "styloglossus"): (
        "artifem.models.styloglossus.model",
        "external styloglossus on 4 or 24 support nodes: a Thelen muscle or a prescribed tension",
        ONE_RANK,
    ),
    ("simulate", "airway"): (
        "artifem.models.airway.model",
        "airway skin over tongue, jaw and palate, with air pressure",
        ONE_RANK,
    ),
    ("simulate", "foot"): (
        "artifem.models.foot.model",
        "the foot standing on the floor, or lifted by the tibialis anterior",
        ONE_RANK,
    ),
    ("simulate", "masseter"): (
        "artifem.models.masseter.model",
        "synthetic masseter: embedding vs conforming, aponeuroses",
        ONE_RANK,
    ),
    ("bench", "fom"): ("artifem.bench:fom", "full-order FEM step timings to JSON", OWN_MPIEXEC),
    ("bench", "tongue"): (
        "artifem.bench:tongue",
        "tongue step timings (protrusion, levels 0 and 1) to JSON",
        OWN_MPIEXEC,
    ),
    ("bench", "reduced"): (
        "artifem.bench_reduced",
        "reduced tongue step against its floating-point work to JSON",
        ONE_PROCESS,
    ),
    ("bench", "scenes"): (
        "artifem.bench_scenes",
        "ms per coupled step: jaw-tongue full/reduced, airway, masseter",
        ONE_PROCESS,
    ),
    ("bench", "contact"): (
        "artifem.bench_contact",
        "ms per step against the number of contact rows: rigid, FEM",
        ONE_PROCESS,
    ),
    ("study", "tongue"): (
        "artifem.models.tongue.study",
        "reduced tongue models against the full one: speed versus error",
        DISTRIBUTED,
    ),
    ("study", "beam-ellipsoid"): (
        "artifem.models.beam_ellipsoid.study",
        "Fig. 11's static tip against the stiff-block reference and Euler-Bernoulli, "
        "and an undamped swing",
        ONE_RANK,
    ),
    ("study", "masseter"): (
        "artifem.models.masseter.study",
        "the five masseter models (embedding vs conforming, aponeuroses): jaw force at "
        "equilibrium, masters, ms per step",
        ONE_RANK,
    ),
    ("study", "styloglossus"): (
        "artifem.models.styloglossus.study",
        "the styloglossus on 4 vs 24 support nodes: stress at equal excitation and tension, "
        "w >= 0, full and reduced tongue",
        ONE_RANK,
    ),
    ("study", "airway"): (
        "artifem.models.airway.study",
        "every tongue motion in the airway, with and without the air, and (--reduced) over "
        "the reduced tongue",
        ONE_RANK,
    ),
    ("study", "foot"): (
        "artifem.models.foot.study",
        "a load case of the foot timed against its parts (FEM alone, with bones, with "
        "contact) and, with --reduced, against its reduced model",
        ONE_RANK,
    ),
    ("study", "jaw-tongue"): (
        "artifem.models.jaw_tongue.study",
        "jaw-tongue scene, full against reduced tongue: speed, error",
        ONE_RANK,
    ),
    ("study", "scene"): (
        "artifem.scene_study",
        "any scene's reduced model on training, motions and held-out "
        "schedules (MODULE:FUNCTION returning a ReducibleScene)",
        DISTRIBUTED,
    ),
    ("study", "robustness"): (
        "artifem.robustness_study",
        "how often a model runs on random valid schedules of the hard "
        "kinds (co-activation, pulses, all at once, release): finished, "
        "cost against the semi-implicit step, det F, volume",
        ONE_PROCESS,
    ),
    ("study", "incompressibility"): (
        "artifem.models.tongue.incompressibility",
        "tongue motions with the element penalty and with hard "
        "incompressibility: volume, landmarks, speed",
        DISTRIBUTED,
    ),
    ("study", "registration"): (
        "artifem.models.registration",
        "skeletal registration cases: jointed deformable bones against "
        "per-bone rigid, affine and one jointless grid",
        ONE_PROCESS,
    ),
    ("register",): (
        "artifem.registration.skeletal",
        "register a reference skeleton (jointed deformable bones) to target "
        "surfaces: report, meshes, picture",
        ONE_RANK,
    ),
    ("demo",): ("artifem.demo", "the main job: run it and say where the results are", DISTRIBUTED),
}


class _Parser(argparse.ArgumentParser):
    """argparse, with a usage error in one line (the usage is one ``--help`` away)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="artifem", description=__doc__.split("\n\n")[0])
    top = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    groups: dict[str, argparse._SubParsersAction] = {}
    for path, (module, help_text, under_mpi) in COMMANDS.items():
        if len(path) == 1:
            sub = top.add_parser(path[0], help=help_text, description=help_text)
        else:
            if path[0] not in groups:
                group = top.add_parser(path[0], help=f"{path[0]} commands")
                groups[path[0]] = group.add_subparsers(
                    dest="subcommand", required=True, metavar="SUBCOMMAND"
                )
            sub = groups[path[0]].add_parser(path[1], help=help_text, description=help_text)
        module, _, name = module.partition(":")
        sub.set_defaults(
            _module=module, _name=" ".join((parser.prog,) + path), _under_mpi=under_mpi
        )
        add_arguments = f"add_{name}_arguments" if name else "add_arguments"
        getattr(importlib.import_module(module), add_arguments)(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    args = parser.parse_args(argv)
    args._argv = list(argv)  # the command itself: to run it again (a study under MPI)
    comm = MPI.COMM_WORLD
    if comm.size == 1:
        return _run(args, parser.prog)
    if args._under_mpi == DISTRIBUTED:
        return _run(args, parser.prog, abort=comm)
    if args._under_mpi == ONE_RANK:
        return _run_on_rank_0(args, comm)
    if comm.rank == 0:
        print(
            f"{args._name}: error: refused under mpiexec ({comm.size} ranks): {args._under_mpi}",
            file=sys.stderr,
        )
    return 2


def _run(args: argparse.Namespace, prog: str, abort: MPI.Comm | None = None) -> int:
    """The command's exit status; a bad input or a failed solve in one line on stderr.
    ``abort``: under mpiexec, end every rank of it after an error or a crash on this one
    (the others may be waiting for this rank in a collective call)."""
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except (ValueError, OSError, SolverError) as exc:
        # artifem's InputError (a ValueError) and SolverError, the materials' ValueError
        # (forms/ imports nothing of artifem) and unreadable or unwritable files
        if os.environ.get("ARTIFEM_TRACEBACK"):
            if abort is None:
                raise
            traceback.print_exc()
        kind = "solver failed" if isinstance(exc, SolverError) else "error"
        on = f" (rank {abort.rank})" if abort is not None else ""
        print(f"{prog}: {kind}{on}: {exc}", file=sys.stderr, flush=True)
        status = 1 if isinstance(exc, SolverError) else 2
    except BaseException:
        if abort is None:
            raise
        traceback.print_exc()
        sys.stderr.flush()
        status = 1
    if abort is not None:
        abort.Abort(status)
    return status


def _run_on_rank_0(args: argparse.Namespace, comm: MPI.Comm) -> int:
    """Run a serial command on rank 0, said on stderr, in a fresh serial process while the
    other ranks wait without spinning; every rank exits with its status. Not in rank 0's
    own process: PETSc work done there alone would make the ranks' PETSc cleanups at exit
    differ, and wait for each other for ever (artifem.reduction.distributed)."""
    if comm.rank == 0:
        print(
            f"{args._name}: runs on one MPI rank of {comm.size} (a serial model); the "
            f"others wait idle",
            file=sys.stderr,
            flush=True,
        )
    return continue_alone(args._argv, comm)


if __name__ == "__main__":
    sys.exit(main())
