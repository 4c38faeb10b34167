"""The import contract of the Python package (README "Architecture"): every module belongs to one
layer, and an import (at module level or inside a function) may only point to its own layer or
a lower one; the module graph has no cycle. Read from the source (ast), so it needs no build."""
from __future__ import annotations

import ast
import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "ibrtools"

# Lowest first. A module belongs to the first entry naming it or a package above it.
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("base", ("ibrtools._core", "ibrtools.errors", "ibrtools.checks", "ibrtools.memory", "ibrtools.outputs",
              "ibrtools.params")),
    ("model", ("ibrtools.camera", "ibrtools.mesh", "ibrtools.scene")),
    ("io", ("ibrtools.imageio", "ibrtools.meshio")),
    ("formats / cache", ("ibrtools.formats", "ibrtools.cache", "ibrtools.paths")),
    ("families", ("ibrtools.raycast", "ibrtools.metrics", "ibrtools.solvers", "ibrtools.synth", "ibrtools.dibr",
                  "ibrtools.depthwarp", "ibrtools.inpaint", "ibrtools.metamers", "ibrtools.hybrid",
                  "ibrtools.mvs")),
    ("methods", ("ibrtools.methods",)),
    ("pipeline", ("ibrtools.pipeline",)),
    ("api", ("ibrtools.api", "ibrtools")),
    ("applications", ("ibrtools.viewer", "ibrtools.viewer_page")),
]


def modules() -> dict[str, Path]:
    out = {}
    for p in sorted(PACKAGE.rglob("*.py")):
        parts = p.relative_to(PACKAGE.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def layer_of(module: str) -> int:
    best, best_len = None, -1
    for i, (_, names) in enumerate(LAYERS):
        for n in names:
            if (module == n or module.startswith(n + ".")) and len(n) > best_len:
                best, best_len = i, len(n)
    assert best is not None, f"{module}: in no layer of tests/test_layers.py LAYERS"
    return best


def imports(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the package modules it imports anywhere in its body (TYPE_CHECKING blocks
    excepted: they are not executed)."""
    out: dict[str, set[str]] = {}
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        got: set[str] = set()

        def visit(node: ast.AST) -> None:
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                    continue
                if isinstance(child, ast.Import):
                    got.update(a.name for a in child.names)
                elif isinstance(child, ast.ImportFrom):
                    base = child.module or ""
                    if child.level:
                        pkg = name.split(".") if is_pkg else name.split(".")[:-1]
                        pkg = pkg[:len(pkg) - child.level + 1]
                        base = ".".join(pkg + ([base] if base else []))
                    for a in child.names:
                        full = f"{base}.{a.name}"
                        got.add(full if full in mods or a.name == "_core" else base)
                visit(child)
        visit(ast.parse(path.read_text()))
        out[name] = {m for m in got if m.split(".")[0] == "ibrtools" and m != name}
    return out


def test_every_import_points_to_its_own_layer_or_below():
    mods = modules()
    bad = []
    for name, targets in imports(mods).items():
        for t in sorted(targets):
            if layer_of(t) > layer_of(name):
                bad.append(f"{name} ({LAYERS[layer_of(name)][0]}) imports {t} ({LAYERS[layer_of(t)][0]})")
    assert not bad, "upward imports:\n" + "\n".join(bad)


def test_the_module_graph_has_no_cycle():
    mods = modules()
    graph = {m: {t for t in ts if t in mods} for m, ts in imports(mods).items()}
    graph["ibrtools"] = set()  # the package's own eager imports are of the model layer only
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def dfs(v: str) -> None:
        state[v] = 1
        stack.append(v)
        for w in sorted(graph[v]):
            if state.get(w) == 1:
                cycles.append(stack[stack.index(w):] + [w])
            elif w not in state:
                dfs(w)
        stack.pop()
        state[v] = 2

    for m in sorted(graph):
        if m not in state:
            dfs(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_every_module_is_in_a_layer():
    for m in modules():
        layer_of(m)


COMMANDS = ("ibr-preprocess", "ibr-render", "ibr-bench", "ibr-view")
FLAG = re.compile(r"(?:^|[\s(/])--[a-z]")


def _strings(tree: ast.AST):
    """(line, text) of every string literal that is not a docstring; an f-string whole, with
    ``{}`` for its fields."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                skip.add(id(first.value))
        if isinstance(node, ast.JoinedStr):
            skip.update(id(v) for v in node.values)
            yield node.lineno, "".join(v.value if isinstance(v, ast.Constant) else "{}" for v in node.values)
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
            yield node.lineno, node.value


def test_the_library_spells_no_flag():
    """The commands own the flags' spellings (they map an error's argument onto its flag,
    ``IbrError.about``); the library names arguments. A flag may appear only in a command line the
    message suggests (after ``ibr-preprocess`` etc.)."""
    bad = []
    for name, path in modules().items():
        for line, text in _strings(ast.parse(path.read_text())):
            for m in FLAG.finditer(text):
                if not any(c in text[:m.start()] for c in COMMANDS):
                    bad.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {text[:80]!r}")
                    break
    assert not bad, "\n".join(bad)
