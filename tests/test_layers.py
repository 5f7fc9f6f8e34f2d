"""The package's imports form layers with no cycle: a module imports only modules of its own
layer or below, so nothing in the lower layers (config, geometry and motion, the mapping
kernels) imports the planners, the systems, the mission, the API or the CLI. The graph is
read from the source (every import statement, also those inside functions)."""

import ast
from pathlib import Path

import nbvs_drake

PACKAGE = Path(nbvs_drake.__file__).resolve().parent

#: layer of each module (the longest matching prefix decides), lowest first
LAYERS = [
    ("foundation", ["errors", "files", "resources", "kernel_cache", "stage_clock", "config", "world.state"]),
    ("models", ["world", "perception.registration", "perception.evaluation", "perception.reconstruction", "mapping"]),
    ("planning and outputs", ["planning", "outputs.plots", "outputs.meshcat_draw", "outputs.replay",
                              "outputs.screenshot", "outputs.visual_outputs", "outputs"]),
    ("systems", ["systems"]),
    ("mission", ["app.diagram", "perception.scanning", "perception", "outputs.diagnostics", "outputs.wiring",
                 "app.mission", "app.bench", "app.warmup", "app"]),
    ("api", ["app.api", "experiments", "gym"]),
    ("cli", ["app.cli", ""]),  # "": the package itself (nbvs_drake/__init__.py)
]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def layer_of(name: str) -> int:
    best, level = -1, None
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (name == p or name.startswith(p + ".") or p == "") and len(p) > best:
                best, level = len(p), i
    return level


def import_graph() -> dict[str, set[str]]:
    mods = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in mods.items():
        pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".") if pkg else []
                    base = base[: len(base) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                elif (node.module or "").startswith("nbvs_drake"):
                    target = node.module[len("nbvs_drake") + 1:]
                else:
                    continue
                for a in node.names:  # `from . import replay` imports the module replay
                    sub = f"{target}.{a.name}" if target else a.name
                    deps.add(sub if sub in mods else target)
            elif isinstance(node, ast.Import):
                deps |= {a.name[len("nbvs_drake") + 1:] for a in node.names if a.name.startswith("nbvs_drake.")}
        graph[name] = {d for d in deps if d in mods and d != name}
    return graph


def test_every_module_has_a_layer():
    assert all(layer_of(m) is not None for m in import_graph())


def test_imports_go_down_the_layers():
    bad = [f"{m} ({LAYERS[layer_of(m)][0]}) imports {d} ({LAYERS[layer_of(d)][0]})"
           for m, deps in import_graph().items() for d in sorted(deps) if layer_of(d) > layer_of(m)]
    assert not bad, "\n".join(bad)


def test_no_import_cycle():
    graph = import_graph()
    state, cycles = {}, []

    def visit(m, path):
        state[m] = 1
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                cycles.append(" -> ".join(path[path.index(d):] + [d]) if d in path else f"{m} -> {d}")
            elif d not in state:
                visit(d, path + [d])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert not cycles, "\n".join(cycles)
