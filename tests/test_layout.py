"""The package layout: imports go downward only, and no two modules import each other.

Layers, lowest first: the base modules (errors, guards, profiling, boundary, ...) <
geometry < discretization < mechanics < timestepping < scene < io < the entry points
(cli, commands, run, sweep).  Checked statically on every import statement of the
package, lazy ones inside functions included.  Not collective.
"""

import ast
from pathlib import Path

import parefg

PACKAGE = Path(parefg.__file__).parent
SCRIPTS = PACKAGE.parent / "scripts"
LAYERS = ("geometry", "discretization", "mechanics", "timestepping", "scene", "io")
ENTRY_POINTS = ("cli", "commands", "run", "sweep")


def _module_name(path: Path) -> str:
    parts = ["parefg", *path.relative_to(PACKAGE).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports() -> dict[str, set[str]]:
    """Module name -> the parefg modules it imports (any depth, any place in the file)."""
    modules = {_module_name(path): path for path in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                candidates = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                candidates = [alias.name for alias in node.names]
            else:
                continue
            targets |= {c for c in candidates if c in modules and c != name}
        graph[name] = targets
    return graph


def _layer(module: str) -> int:
    """0 for the base modules, 1 + index in LAYERS for a subpackage, top for entry points."""
    parts = module.split(".")
    if len(parts) > 1 and parts[1] in LAYERS:
        return 1 + LAYERS.index(parts[1])
    if len(parts) > 1 and parts[1] in ENTRY_POINTS:
        return 1 + len(LAYERS)
    return 0


def test_no_upward_imports():
    graph = _imports()
    upward = [
        f"{module} -> {target}"
        for module, targets in sorted(graph.items())
        for target in sorted(targets)
        if _layer(target) > _layer(module)
    ]
    assert upward == []


def test_no_import_cycles():
    graph = _imports()
    # A package __init__ importing its own modules is not a cycle of concepts.
    graph = {m: {t for t in ts if not t.startswith(m + ".")} for m, ts in graph.items()}
    cycles, done = [], set()

    def visit(module, path):
        if module in path:
            cycles.append(" -> ".join(path[path.index(module) :] + [module]))
            return
        if module in done:
            return
        for target in sorted(graph[module]):
            visit(target, [*path, module])
        done.add(module)

    for module in sorted(graph):
        visit(module, [])
    assert cycles == []


def test_scripts_do_not_import_test_modules():
    """Benchmarks take shared scenes from the package (parefg.scene.library), not from tests."""
    offenders = []
    for path in sorted(SCRIPTS.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            else:
                continue
            top = {name.split(".")[0] for name in names}
            if any(n.startswith("test_") or n in ("conftest", "tests") for n in top):
                offenders.append(f"{path.relative_to(SCRIPTS)}:{node.lineno}")
    assert offenders == []
