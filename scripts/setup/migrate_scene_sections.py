"""One-off migration: rewrite reads of the flat Scene (scene.dt) into its sections (scene.time.dt).

For a branch written against the flat Scene, run from the repository root:

    .venv/bin/python scripts/setup/migrate_scene_sections.py .

It parses every module of parefg/, scripts/ and tests/ and rewrites each attribute read
``RECEIVER.OLD`` whose receiver's text ends in "scene" (scene, sim.scene, self.scene, ...)
or is a ``load_scene(...)`` call; receivers of other names that hold a Scene must be
renamed by hand (grep for the old names).  Prints the files changed and the count.
"""

import ast
import pathlib
import sys

SECTIONS = {
    "discretization": "h degree weight support quadrature cells jitter seed",
    "material": "E nu lam mu rho",
    "time": "scheme T dt beta gamma rho_inf contact_force n_steps dynamic",
    "penalty": "alpha_dirichlet alpha_contact alpha_friction",
}
MOVED = {old: f"{section}.{old}" for section, names in SECTIONS.items() for old in names.split()}
MOVED.update(
    body_force="loads.f",
    initial_u="initial.u",
    initial_v="initial.v",
    initial_grad="initial.grad",
    initial_div_stress="initial.div_stress",
    output_every="output.every",
    output_fields="output.fields",
    solver_method="solver.method",
    solver_options="solver.options",
)
SKIP = ("parefg/scene/loader.py", "parefg/scene/sections.py")


def rewrite(path: pathlib.Path, rel: str) -> int:
    """Rewrite one file in place; returns the number of reads rewritten."""
    source = path.read_text()
    edits = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and node.attr in MOVED:
            receiver = ast.get_source_segment(source, node.value) or ""
            called = isinstance(node.value, ast.Call) and receiver.startswith("load_scene(")
            if receiver.endswith("scene") or called:
                edits.append((node.end_lineno, node.end_col_offset, node.attr))
    lines = source.splitlines(keepends=True)
    for lineno, end, attr in sorted(edits, reverse=True):
        line = lines[lineno - 1].encode()  # col offsets count UTF-8 bytes
        start = end - len(attr.encode())
        lines[lineno - 1] = (line[:start] + MOVED[attr].encode() + line[end:]).decode()
    if edits:
        path.write_text("".join(lines))
        print(f"{rel}: {len(edits)}")
    return len(edits)


def main() -> int:
    root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else ".")
    total = 0
    for folder in ("parefg", "scripts", "tests"):
        for path in sorted((root / folder).rglob("*.py")):
            rel = str(path.relative_to(root))
            if rel not in SKIP:
                total += rewrite(path, rel)
    print(f"{total} reads rewritten")
    return 0


if __name__ == "__main__":
    sys.exit(main())
