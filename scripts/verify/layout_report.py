"""The package's shape: one line per module, sizes, the longest functions, import layers.

Prints the tree of ``parefg`` with each module's line count and the first line of its
docstring, the modules over MAX_MODULE_LINES and the functions over MAX_FUNCTION_LINES
(STYLE.md: modules under ~400 lines, functions under ~50), the longest functions, every
import that goes upward in the layer order (or forms a cycle), and, for every registry of
REGISTRIES, the modules other than its own that spell one of its names as a string
literal (docstrings excluded): a name registered once is compared nowhere else.  Exits 1
when an import breaks the layering.

    python scripts/verify/layout_report.py [--longest 15]
"""

import argparse
import ast
import importlib
import pathlib
import sys
from enum import Enum

PACKAGE = pathlib.Path(__file__).resolve().parents[2] / "parefg"
MAX_MODULE_LINES = 400
MAX_FUNCTION_LINES = 50
#: module -> its registries of interchangeable parts (dicts by name, or StrEnums)
REGISTRIES = {
    "parefg.boundary": ("BoundaryKind",),
    "parefg.geometry.cells": ("CellType",),
    "parefg.geometry.shapes": ("SHAPES",),
    "parefg.discretization.weights": ("WEIGHTS",),
    "parefg.discretization.dirichlet": ("DIRICHLET_METHODS",),
    "parefg.mechanics.friction": ("FRICTION_LAWS",),
    "parefg.mechanics.normal_force": ("CONTACT_FORCES",),
    "parefg.mechanics.penalty": ("PENALTY_KINDS",),
    "parefg.timestepping.schemes": ("SCHEMES",),
    "parefg.timestepping.linear_solver": ("SOLVER_METHODS",),
    "parefg.scene.schema": ("OUTPUT_FIELDS",),
}

#: lowest first: a module may import from its own layer or a lower one only
LAYERS = (
    ("_env", "errors", "profiling", "parallel", "guards", "petsc_options", "boundary"),
    ("geometry",),
    ("discretization",),
    ("mechanics",),
    ("timestepping",),
    ("scene",),
    ("io",),
    ("run", "sweep", "commands", "cli", "__init__"),
)


def layer_of(module: str) -> int:
    """Layer index of a dotted module name inside parefg (its first component)."""
    top = module.split(".")[1] if module.count(".") else "__init__"
    for index, names in enumerate(LAYERS):
        if top in names:
            return index
    raise KeyError(f"{module}: not in LAYERS (scripts/verify/layout_report.py)")


def module_name(path: pathlib.Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(tree: ast.AST, name: str, is_package: bool) -> set[str]:
    """parefg modules imported anywhere in a module (also inside functions)."""
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.startswith("parefg")}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = name.split(".")
                anchor = anchor if is_package else anchor[:-1]
                base = ".".join(anchor[: len(anchor) - node.level + 1] + ([base] if base else []))
            if base.startswith("parefg"):
                found.add(base)
    return found


def functions_of(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            yield node.name, node.end_lineno - node.lineno + 1, node.lineno


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--longest", type=int, default=15)
    args = parser.parse_args()
    modules, functions, graph = {}, [], {}
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text()
        tree = ast.parse(text)
        name = module_name(path)
        doc = (ast.get_docstring(tree) or "").strip().splitlines()
        modules[name] = (len(text.splitlines()), doc[0] if doc else "(no docstring)")
        graph[name] = imports_of(tree, name, path.name == "__init__.py")
        functions += [(n, length, f"{name}:{line}") for n, length, line in functions_of(tree)]
    for name, (lines, doc) in modules.items():
        indent = "  " * name.count(".")
        print(f"{indent}{name.split('.')[-1]:<{28 - len(indent)}} {lines:5d}  {doc[:80]}")
    long_modules = [m for m, (n, _) in modules.items() if n > MAX_MODULE_LINES]
    print(
        f"\n{len(modules)} modules, {sum(n for n, _ in modules.values())} lines;"
        f" over {MAX_MODULE_LINES} lines: {long_modules or 'none'}"
    )
    long_functions = [f"{n} ({length}, {where})" for n, length, where in functions
                      if length > MAX_FUNCTION_LINES]  # fmt: skip
    print(f"functions over {MAX_FUNCTION_LINES} lines: {long_functions or 'none'}")
    print(f"\nlongest functions (of {len(functions)}):")
    for fname, length, where in sorted(functions, key=lambda f: -f[1])[: args.longest]:
        print(f"  {length:4d}  {fname:<32} {where}")
    upward = [
        f"{src} -> {dst}"
        for src, targets in graph.items()
        for dst in targets
        if dst != "parefg" and layer_of(dst) > layer_of(src)
    ]
    print(f"\nupward imports: {upward or 'none'}")
    cycles = find_cycles(graph)
    print(f"import cycles between modules: {cycles or 'none'}")
    report_registries()
    return 1 if upward or cycles else 0


def string_literals(tree: ast.AST) -> set[str]:
    """The string constants of a module, docstrings (string expression statements) excluded."""
    docstrings = {
        id(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
    }
    return {
        node.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str)
        and id(node) not in docstrings
    }  # fmt: skip


def report_registries() -> None:
    """For each registry: its names, and the other modules spelling one as a literal."""
    literals = {
        module_name(path): string_literals(ast.parse(path.read_text()))
        for path in sorted(PACKAGE.rglob("*.py"))
    }
    print("\nregistries: names, and other modules that spell a name as a string literal")
    for module, registries in REGISTRIES.items():
        for registry in registries:
            entries = getattr(importlib.import_module(module), registry)
            is_enum = isinstance(entries, type) and issubclass(entries, Enum)
            names = [m.value for m in entries] if is_enum else list(entries)
            elsewhere = {
                name: sorted(m for m, found in literals.items() if m != module and name in found)
                for name in names
            }
            spelled = {name: where for name, where in elsewhere.items() if where}
            print(f"  {module}.{registry}: {', '.join(map(str, names))}")
            print(f"      spelled elsewhere: {spelled or 'nowhere'}")


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Module-level cycles (depth-first search over the import graph)."""
    cycles, state = [], {}

    def visit(node, stack):
        state[node] = "open"
        for target in sorted(graph.get(node, ())):
            target = target if target in graph else target.rsplit(".", 1)[0]
            if target not in graph or target == node:
                continue
            if state.get(target) == "open":
                cycles.append(stack[stack.index(target) :] + [target])
            elif target not in state:
                visit(target, stack + [target])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    return cycles


if __name__ == "__main__":
    sys.exit(main())
