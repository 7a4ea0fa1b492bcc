"""The package's import graph (read from the source, every import, lazy ones included):
no cycle, and no import from a lower layer to a higher one (the layers of the design notes:
forms, I/O, bodies, couplings, the scene, the reductor, then models and commands)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {
    "artifem": ROOT / "artifem",
    "artifem.forms": ROOT / "forms",
    "artifem.models": ROOT / "models",
}

#: module prefix -> layer; the longest matching prefix decides.
LAYERS = {
    "artifem": 0,
    "artifem.errors": 0,
    "artifem.arguments": 0,
    "artifem.jit": 0,
    "artifem.forms.errors": 0,  # the exceptions' roots, in forms/: the lowest raiser
    "artifem.forms": 1,
    "artifem.io": 2,
    # 3: bodies and what evaluates them
    "artifem.fem_body": 3,
    "artifem.contact_points": 3,
    "artifem.pointwise": 3,
    "artifem.material_response": 3,
    "artifem.stress": 3,
    "artifem.linear_solver": 3,
    "artifem.excitation": 3,
    "artifem.render": 3,
    "artifem.surface_loads": 3,
    "artifem.incompressibility": 3,
    "artifem.muscle_layers": 3,
    "artifem.reduction.reduced_volume_constraint": 3,
    "artifem.reduction.reduced_body": 3,
    "artifem.reduction.cubature": 3,
    "artifem.reduction.quadrature_points": 3,
    "artifem.reduction.stress_kernel": 3,
    "artifem.reduction.rigid_lift": 3,
    "artifem.embedding.embedded_mesh": 3,
    "artifem.embedding.voxel_fem": 3,
    "artifem.multibody.rigid_body": 3,
    # 4: couplings
    "artifem.multibody": 4,
    "artifem.embedding": 4,
    # 5: the step
    "artifem.scene": 5,
    "artifem.integrators": 5,
    # 6: the reductor
    "artifem.reduction": 6,
    "artifem.registration": 6,
    # 7: models and commands
    "artifem.models": 7,
    "artifem.cli": 7,
    "artifem.bench": 7,
    "artifem.bench_scenes": 7,
    "artifem.bench_reduced": 7,
    "artifem.bench_contact": 7,
    "artifem.scene_study": 7,
    "artifem.robustness_study": 7,
    "artifem.bench_worker": 7,
    "artifem.demo": 7,
    "artifem.material_curves": 7,
}


def modules() -> dict[str, Path]:
    out = {}
    for package, root in PACKAGES.items():
        for path in root.rglob("*.py"):
            parts = [p for p in path.relative_to(root).with_suffix("").parts if p != "__init__"]
            if package == "artifem" and parts and parts[0] in ("forms", "models"):
                continue
            out[".".join([package, *parts])] = path
    return out


def import_graph() -> dict[str, set[str]]:
    mods = modules()
    graph = {name: set() for name in mods}
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    module = ".".join(base + ([node.module] if node.module else []))
                else:
                    module = node.module
                targets = [module] + [f"{module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            graph[name] |= {t for t in targets if t in mods and t != name}
    return graph


def layer(module: str) -> int:
    prefix = max((p for p in LAYERS if module == p or module.startswith(p + ".")), key=len)
    return LAYERS[prefix]


def test_every_module_has_a_layer():
    """Every module is placed by an entry of LAYERS, not by the package root's catch-all:
    ``"artifem"`` is a prefix of every name, so ``layer(m) >= 0``, the check this replaces,
    held for any module, and a new top-level module would silently sit in layer 0."""
    unplaced = [
        m
        for m in modules()
        if m != "artifem"
        and max((p for p in LAYERS if m == p or m.startswith(p + ".")), key=len) == "artifem"
    ]
    assert not unplaced, f"modules without a layer in LAYERS: {unplaced}"


def test_no_import_runs_from_a_lower_layer_to_a_higher_one():
    wrong = [
        f"{a} (layer {layer(a)}) imports {b} (layer {layer(b)})"
        for a, targets in import_graph().items()
        for b in sorted(targets)
        if layer(b) > layer(a)
    ]
    assert not wrong, "\n".join(wrong)


def test_forms_import_nothing_of_artifem():
    graph = import_graph()
    outside = {
        a: sorted(t for t in targets if not t.startswith("artifem.forms"))
        for a, targets in graph.items()
        if a.startswith("artifem.forms")
    }
    assert not any(outside.values()), outside


def test_no_import_cycle():
    graph = import_graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                raise AssertionError(
                    "import cycle: " + " -> ".join(stack[stack.index(nxt) :] + [nxt])
                )
            if nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module)


def test_every_package_is_in_the_wheel():
    """pyproject lists its packages explicitly: a new package left out would be missing
    from the wheel (the wheel test would find it too, but only in CI)."""
    import tomllib

    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    packages = {name for name, path in modules().items() if path.name == "__init__.py"}
    assert packages <= listed, sorted(packages - listed)
