"""The type stub of the C++ module (python/ibrtools/_core.pyi, made by tools/gen_core_stub.py) lists
exactly what _core exports; it is shipped with py.typed; mypy reads it precisely enough to
reject a wrong array dtype; the typed usage example (tests/typing_usage.py) runs."""
from __future__ import annotations

import ast
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from ibrtools import _core

REPO = Path(__file__).resolve().parents[1]
STUB = REPO / "python" / "ibrtools" / "_core.pyi"


def _stub_tree() -> ast.Module:
    return ast.parse(STUB.read_text())


def _defined(body: list[ast.stmt]) -> set[str]:
    """Public names a stub body defines (classes, functions, annotated or plain assignments)."""
    names: set[str] = set()
    for node in body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return {n for n in names if not n.startswith("_")}


def test_stub_lists_every_core_name():
    """Fails when _core gains or loses a name that the stub does not list: regenerate it with
    `.venv/bin/python tools/gen_core_stub.py` (then refine the new name's types there)."""
    tree = _stub_tree()
    exported = {n for n in dir(_core) if not n.startswith("_")}
    stubbed = _defined(tree.body)
    assert sorted(exported - stubbed) == [], "in _core, missing from _core.pyi"
    assert sorted(stubbed - exported) == [], "in _core.pyi, gone from _core"
    all_node = next(n for n in tree.body if isinstance(n, ast.AnnAssign) and getattr(n.target, "id", "") == "__all__")
    assert set(ast.literal_eval(all_node.value)) == exported


def test_stub_lists_every_class_member():
    """Methods and properties of each bound class, both ways."""
    for node in _stub_tree().body:
        if not isinstance(node, ast.ClassDef):
            continue
        cls = getattr(_core, node.name)
        real = {k for k in vars(cls) if not k.startswith("_")}
        assert _defined(node.body) == real, node.name


def test_stub_has_no_vague_types():
    """Arrays are typed by dtype (NDArray[numpy.float32], ...), never typing.Any or a bare tuple."""
    sys.path.insert(0, str(REPO / "tools"))
    try:
        import gen_core_stub as gen
    finally:
        sys.path.pop(0)
    # Deliberate: a dict of named arrays of several dtypes, an info dict (each chosen in OVERRIDES).
    chosen = {ast.unparse(ast.parse(t, mode="eval").body) for o in gen.OVERRIDES.values() for t in o.values()}

    def vague_(ann: ast.expr | None) -> bool:
        return gen._vague(ann) and ast.unparse(ann) not in chosen

    vague = []
    for node in ast.walk(_stub_tree()):
        if isinstance(node, ast.FunctionDef):
            for a in node.args.posonlyargs + node.args.args + node.args.kwonlyargs:
                if vague_(a.annotation):
                    vague.append(f"{node.name}({a.arg})")
            if vague_(node.returns):
                vague.append(f"{node.name} -> {ast.unparse(node.returns)}")
    assert vague == []


@pytest.mark.skipif(importlib.util.find_spec("pybind11_stubgen") is None,
                    reason="pybind11-stubgen is not installed (pip install pybind11-stubgen)")
def test_stub_is_up_to_date():
    """The committed stub is what the generator makes of the built module now."""
    r = subprocess.run([sys.executable, str(REPO / "tools" / "gen_core_stub.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_package_ships_markers():
    """py.typed (PEP 561) and the stub are in the package directory, which the wheel packs whole
    (pyproject: wheel.packages = ["python/ibrtools", ...])."""
    pkg = REPO / "python" / "ibrtools"
    assert (pkg / "py.typed").is_file()
    assert STUB.is_file()


@pytest.mark.skipif(importlib.util.find_spec("mypy") is None, reason="mypy is not installed (test extra)")
def test_mypy_rejects_wrong_types(tmp_path):
    """The stub and the API annotations are precise: mypy (the project's configuration) refuses a
    float64 array where the kernel takes float32, a misspelt result field, a bad camera type."""
    bad = tmp_path / "bad_usage.py"
    bad.write_text(
        "import numpy as np\n"
        "import ibrtools\n"
        "from ibrtools import _core\n"
        "_core.pushpull(np.zeros((8, 8, 3)), np.zeros((8, 8), np.bool_))\n"
        "scene = ibrtools.load_scene('scene')\n"
        "ibrtools.render(scene, 3)\n"
        "ibrtools.render(scene, 't000').colour\n")
    r = subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(REPO / "pyproject.toml"), str(bad)],
                       capture_output=True, text=True, cwd=REPO)
    out = r.stdout
    assert r.returncode == 1, out + r.stderr
    assert 'Argument 1 to "pushpull" has incompatible type' in out and "float64" in out
    assert 'Argument 2 to "render" has incompatible type "int"' in out
    assert '"RenderResult" has no attribute "colour"' in out


def test_typing_usage_runs(tmp_path):
    """The typed example is real code: it runs on a tiny scene."""
    from ibrtools import synth
    from ibrtools.formats import native

    sys.path.insert(0, str(REPO / "tests"))
    try:
        import typing_usage
    finally:
        sys.path.pop(0)
    native.save(synth.make_scene("objects", size=(64, 48), views=4, holdout_targets=1, path_frames=2),
                tmp_path / "scene")
    cov = typing_usage.render_all(tmp_path / "scene")
    assert set(cov) == {"t000", "orbit", "wander"}
    assert all(0.0 < c <= 1.0 for c in cov.values())
    mean, levels = typing_usage.core_calls()
    assert 0.0 < mean <= 1.0 and levels == 3  # 8x8 -> 4, 2, 1
