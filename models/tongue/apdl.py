"""Readers for the two ANSYS APDL macros of the ArtiSynth tongue (CreateMuscles.mac, Fibers.mac).

Only the small subset of APDL these files use is understood; anything else
that could change what they define is refused with a ValueError naming file
and line, rather than silently misread.

CreateMuscles.mac
    ``ESEL,Type,ELEM,,VMIN[,VMAX[,VINC]]`` selections (Type S = new set,
    A = add, R = reselect from the current set, U = unselect; ``ESEL,NONE``,
    and ``ESEL,ALL`` / ``ESEL,INVE`` / ``ALLSEL`` when the caller passes the
    mesh's element ids), ``CMSEL`` of element components already defined, and
    ``CM,NAME,ELEM`` which names the current selection.  An empty selection
    does not define a component (ANSYS refuses to create an empty component):
    the file's trailing ``ESEL,NONE`` / ``CM,NEW_TISSUE,ELEM`` therefore yields
    no bundle.  ``CMGRP`` groups are returned by :func:`read_muscle_groups`.
Fibers.mac
    ``FIBER(node_k, fiber_j, muscle_i) = node id``, ``NB_NODES_FIBER(fiber_j,
    muscle_i)``, ``NB_FIBERS(muscle_i)`` and, if present, ``muscleName(i)``.

The shipped Fibers.mac has **no** muscleName array (its header announces one
but the file never defines it).  Its muscles are therefore named by index
with a list of names: ArtiSynth's ``AnsysMuscleFiberReader`` gives Fibers.mac
muscle i to the i-th bundle of CreateMuscles.mac, so pass
``names=read_muscle_names("CreateMuscles.mac")``; tests/test_tongue_data.py
checks geometrically that this pairing is right (each fiber muscle runs
through the elements of the bundle of the same name).

Comments (``!`` to the end of the line), blank lines, ``/`` commands
(``/NOPR``...), ``*DIM`` and scalar parameter assignments are skipped.
Both files contain latin-1 bytes in their comments and are read as latin-1.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from artifem.errors import InputError, InputFileNotFoundError

#: Commands that change the element selection (or control flow) and that this
#: reader cannot follow; meeting one is an error, not a silent misreading.
_UNSUPPORTED_SELECTING = {
    "ESLN",
    "ESLV",
    "ESLA",
    "ESLL",
    "ESLS",
    "ESOL",
    "EDELE",
    "ECLEAR",
    "ENSYM",
    "EGEN",
    "E",
    "EN",
    "EMODIF",
    "NUMMRG",
    "NUMCMP",
    "CMDELE",
    "CMMOD",
    "CMEDIT",
    "CPLGEN",
    "*DO",
    "*ENDDO",
    "*IF",
    "*ELSEIF",
    "*ELSE",
    "*ENDIF",
    "*GO",
    "*REPEAT",
    "*USE",
    "*CYCLE",
    "*EXIT",
    "/INPUT",
    "/EOF",
    "*VGET",
    "*GET",
    "ESEL,INVE",
}


def _require(path: str | Path, what: str) -> Path:
    path = Path(path)
    if not path.is_file():
        raise InputFileNotFoundError(f"{what} not found: {path}")
    return path


def _statements(path: Path):
    """Yield (line number, statement) with comments and blank lines removed.

    APDL comments start at ``!``; ``$`` separates several commands on a line.
    """
    with open(path, encoding="latin-1") as f:
        for lineno, line in enumerate(f, start=1):
            text = line.split("!", 1)[0].strip()
            for stmt in text.split("$"):
                stmt = stmt.strip()
                if stmt:
                    yield lineno, stmt


def _fields(stmt: str) -> list[str]:
    return [f.strip() for f in stmt.split(",")]


def _int(text: str, path: Path, lineno: int, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        try:
            value = float(text)
        except ValueError:
            value = None
        if value is not None and value == int(value):
            return int(value)
        raise InputError(
            f"{path}:{lineno}: {what} must be an integer literal "
            f"(parameters and expressions are not evaluated), got {text!r}"
        ) from None


_ASSIGN = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*(\(([^)]*)\))?\s*=\s*(.*)$")


def read_muscle_names(path: str | Path) -> list[str]:
    """The ``muscleName(k) = 'NAME'`` array of a macro, in index order (empty if absent)."""
    path = _require(path, "APDL macro")
    names: dict[int, str] = {}
    for lineno, stmt in _statements(path):
        m = _ASSIGN.match(stmt)
        if m and m.group(1).lower() == "musclename" and m.group(2):
            k = _int(m.group(3), path, lineno, "muscleName index")
            value = m.group(4).strip().strip("'\"").strip()
            if k in names:
                raise InputError(f"{path}:{lineno}: muscleName({k}) defined twice")
            names[k] = value
    if names and sorted(names) != list(range(1, len(names) + 1)):
        raise InputError(f"{path}: muscleName indices are not 1..{len(names)}: {sorted(names)}")
    return [names[k] for k in sorted(names)]


def _esel_ids(fields: list[str], path: Path, lineno: int) -> set[int]:
    """Element ids of ``ESEL,Type,ELEM,,VMIN[,VMAX[,VINC]]``."""
    item = fields[2].upper() if len(fields) > 2 and fields[2] else "ELEM"
    if item != "ELEM":
        raise InputError(
            f"{path}:{lineno}: ESEL by {item!r} is not supported "
            f"(only ELEM ranges): {','.join(fields)}"
        )
    if len(fields) > 3 and fields[3]:
        raise InputError(f"{path}:{lineno}: ESEL component field {fields[3]!r} is not supported")
    if len(fields) < 5 or not fields[4]:
        raise InputError(f"{path}:{lineno}: ESEL without an element id: {','.join(fields)}")
    if len(fields) > 7 and any(fields[7:]):
        raise InputError(
            f"{path}:{lineno}: ESEL KABS/extra fields are not supported: {','.join(fields)}"
        )
    first = _int(fields[4], path, lineno, "ESEL VMIN")
    last = _int(fields[5], path, lineno, "ESEL VMAX") if len(fields) > 5 and fields[5] else first
    inc = _int(fields[6], path, lineno, "ESEL VINC") if len(fields) > 6 and fields[6] else 1
    if inc <= 0 or last < first:
        raise InputError(
            f"{path}:{lineno}: ESEL range {first}..{last} step {inc} is empty or reversed"
        )
    return set(range(first, last + 1, inc))


def _parse_components(path: str | Path, all_elements=None):
    """Run the selection commands of a macro; return (components, groups) in file order."""
    path = _require(path, "APDL macro")
    universe = None if all_elements is None else {int(i) for i in np.asarray(all_elements).ravel()}
    selection: set[int] = set()
    components: dict[str, set[int]] = {}
    groups: dict[str, list[str]] = {}

    def need_universe(what: str, lineno: int) -> set[int]:
        if universe is None:
            raise InputError(
                f"{path}:{lineno}: {what} needs the mesh's element ids; pass all_elements="
            )
        return universe

    for lineno, stmt in _statements(path):
        fields = _fields(stmt)
        cmd = fields[0].upper()
        if cmd == "ESEL":
            kind = fields[1].upper() if len(fields) > 1 else ""
            if kind == "NONE":
                selection = set()
            elif kind == "ALL":
                selection = set(need_universe("ESEL,ALL", lineno))
            elif kind == "INVE":
                selection = need_universe("ESEL,INVE", lineno) - selection
            elif kind in ("S", "A", "R", "U"):
                ids = _esel_ids(fields, path, lineno)
                if universe is not None:
                    ids &= universe  # ANSYS selects only elements that exist
                if kind == "S":
                    selection = ids
                elif kind == "A":
                    selection |= ids
                elif kind == "R":
                    selection &= ids
                else:
                    selection -= ids
            else:
                raise InputError(
                    f"{path}:{lineno}: ESEL type {kind!r} is not supported "
                    f"(S, A, R, U, NONE, ALL, INVE): {stmt}"
                )
        elif cmd == "ALLSEL":
            selection = set(need_universe("ALLSEL", lineno))
        elif cmd == "CM":
            if len(fields) < 2 or not fields[1]:
                raise InputError(f"{path}:{lineno}: CM without a component name: {stmt}")
            entity = fields[2].upper() if len(fields) > 2 and fields[2] else ""
            if entity.startswith("ELEM"):
                if selection:  # ANSYS does not create empty components
                    components[fields[1]] = set(selection)
            elif entity in ("NODE", "KP", "LINE", "AREA", "VOLU"):
                pass  # a component of other entities: no effect on elements
            else:
                raise InputError(f"{path}:{lineno}: CM entity {entity!r} not understood: {stmt}")
        elif cmd == "CMSEL":
            kind = fields[1].upper() if len(fields) > 1 else ""
            if kind == "NONE":
                selection = set()
                continue
            if kind == "ALL":
                selection = set().union(*components.values())
                continue
            name = fields[2] if len(fields) > 2 else ""
            if name not in components:
                raise InputError(
                    f"{path}:{lineno}: CMSEL of unknown element component {name!r}: {stmt}"
                )
            ids = components[name]
            if kind == "S":
                selection = set(ids)
            elif kind == "A":
                selection |= ids
            elif kind == "R":
                selection &= ids
            elif kind == "U":
                selection -= ids
            else:
                raise InputError(f"{path}:{lineno}: CMSEL type {kind!r} is not supported: {stmt}")
        elif cmd == "CMGRP":
            if len(fields) < 3:
                raise InputError(f"{path}:{lineno}: CMGRP without members: {stmt}")
            groups[fields[1]] = [f for f in fields[2:] if f]
        elif cmd in _UNSUPPORTED_SELECTING:
            raise InputError(
                f"{path}:{lineno}: command {fields[0]} changes elements or the "
                f"flow of the macro and is not supported by this reader: {stmt}"
            )
        # everything else (/NOPR, *DIM, parameter assignments, ...) does not select elements
    return components, groups


def read_muscle_elements(path: str | Path, all_elements=None) -> dict[str, np.ndarray]:
    """Element components of an APDL macro: name -> sorted ANSYS element ids, in file order.

    ``all_elements`` (the mesh's element ids) is optional; with it, selections
    keep only existing elements (as ANSYS does) and ``ESEL,ALL``, ``ESEL,INVE``
    and ``ALLSEL`` are allowed.  Without it, ids are returned as written and
    the caller checks them against the mesh.
    """
    components, _ = _parse_components(path, all_elements)
    return {name: np.array(sorted(ids), dtype=np.int64) for name, ids in components.items()}


def read_muscle_groups(path: str | Path) -> dict[str, list[str]]:
    """``CMGRP,NAME,member1,member2,...`` groups of a macro (e.g. GGP -> [GGP_L, GGP_R])."""
    _, groups = _parse_components(path)
    return groups


def read_fibers(path: str | Path, names: list[str] | None = None) -> dict[str, list[np.ndarray]]:
    """Fiber polylines of Fibers.mac: muscle name -> list of fibers (ANSYS node ids in order).

    Muscle i takes its name from the file's own ``muscleName(i)`` array when
    it has one (then ``names``, if given, must agree with it), otherwise from
    ``names[i-1]``; a file without names and no ``names`` is an error.  Only
    the first NB_FIBERS(i) fibers of muscle i and the first NB_NODES_FIBER(j, i)
    nodes of fiber j are used (APDL arrays are zero-filled beyond them); a
    missing entry within those counts is an error.  Node ids are returned as
    written: the styloglossus fibers end on two ids (4037, 4042) that are not
    tongue nodes (see :data:`artifem.models.tongue.fibers.EXTRA_NODES`).
    """
    path = _require(path, "fiber macro")
    fiber: dict[tuple[int, int, int], int] = {}
    nb_nodes: dict[tuple[int, int], int] = {}
    nb_fibers: dict[int, int] = {}
    file_names: dict[int, str] = {}
    nb_muscles = None
    for lineno, stmt in _statements(path):
        m = _ASSIGN.match(stmt)
        if not m:
            cmd = _fields(stmt)[0].upper()
            if cmd in _UNSUPPORTED_SELECTING:
                raise InputError(
                    f"{path}:{lineno}: command {cmd} is not supported by this reader: {stmt}"
                )
            continue  # /NOPR, *DIM, ...
        name, index, value = m.group(1).upper(), m.group(3), m.group(4).strip()
        if name == "NB_MUSCLES" and index is None:
            nb_muscles = _int(value, path, lineno, "nb_muscles")
            continue
        if index is None:
            continue  # other scalar parameters (nb_max_fibres, ...)
        idx = tuple(_int(t.strip(), path, lineno, f"{name} index") for t in index.split(","))
        if name == "MUSCLENAME":
            file_names[idx[0]] = value.strip("'\"").strip()
            continue
        if name == "FIBERS_LOCATION":
            continue
        target, size = {
            "FIBER": (fiber, 3),
            "NB_NODES_FIBER": (nb_nodes, 2),
            "NB_FIBERS": (nb_fibers, 1),
        }.get(name, (None, 0))
        if target is None:
            continue
        if len(idx) != size:
            raise InputError(f"{path}:{lineno}: {name} takes {size} indices, got {len(idx)}")
        key = idx if size > 1 else idx[0]
        if key in target:
            raise InputError(f"{path}:{lineno}: {name}{index} assigned twice")
        target[key] = _int(value, path, lineno, f"{name}({index})")

    muscles = sorted(nb_fibers)
    if not muscles:
        raise InputError(f"{path}: no NB_FIBERS(i) entries")
    if muscles != list(range(1, len(muscles) + 1)):
        raise InputError(f"{path}: NB_FIBERS defined for muscles {muscles}, not 1..{len(muscles)}")
    if nb_muscles is not None and nb_muscles != len(muscles):
        raise InputError(f"{path}: nb_muscles = {nb_muscles} but NB_FIBERS has {len(muscles)}")
    if file_names:
        labels = [file_names.get(i) for i in muscles]
        if None in labels:
            raise InputError(f"{path}: muscleName missing for some of muscles {muscles}")
        if names is not None and list(names) != labels:
            raise InputError(f"{path}: its muscleName array {labels} differs from names={names}")
    elif names is None:
        raise InputError(
            f"{path} has no muscleName array: pass names= (e.g. the muscleName "
            f"array of CreateMuscles.mac, which ArtiSynth pairs with it by index)"
        )
    else:
        labels = list(names)
        if len(labels) != len(muscles):
            raise InputError(f"{path}: {len(muscles)} muscles but {len(labels)} names given")
    if len(set(labels)) != len(labels):
        raise InputError(f"{path}: repeated muscle names {labels}")

    result: dict[str, list[np.ndarray]] = {}
    for i, label in zip(muscles, labels):
        fibers = []
        for j in range(1, nb_fibers[i] + 1):
            if (j, i) not in nb_nodes:
                raise InputError(f"{path}: NB_NODES_FIBER({j},{i}) missing (muscle {label})")
            count = nb_nodes[(j, i)]
            missing = [k for k in range(1, count + 1) if (k, j, i) not in fiber]
            if missing:
                raise InputError(
                    f"{path}: FIBER({missing[0]},{j},{i}) missing (muscle {label}, "
                    f"fiber {j} has NB_NODES_FIBER = {count})"
                )
            if count < 2:
                raise InputError(f"{path}: fiber {j} of muscle {label} has {count} node(s)")
            fibers.append(np.array([fiber[(k, j, i)] for k in range(1, count + 1)], dtype=np.int64))
        result[label] = fibers
    return result
