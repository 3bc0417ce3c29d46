"""The package's layers: imports run only downward, never into another module's private names, never
in a circle. Read from the source (AST), so a lazy import inside a function counts like a top-level one.

Layers, lowest first (each folder's ``__init__`` docstring says what lives there):
config < control < plants < simulation < metrics < logs < scenario < studies < figures < cli, api, __main__.
A module may import its own layer and the ones below. The package root (``ftstab_mj/__init__.py``:
the version and the lazy Python API) is below everything, and only the API may be imported from it lazily.
"""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "ftstab_mj"
LAYERS = ("config", "control", "plants", "simulation", "metrics", "logs", "scenario", "studies", "figures",
          "cli")
TOP = {"api": "cli", "__main__": "cli"}  # root modules that sit with the command line


def _module(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _layer(module: str) -> int:
    """Index in LAYERS of a dotted ftstab_mj module; -1 for the package root."""
    parts = module.split(".")
    if len(parts) == 1:
        return -1
    head = TOP.get(parts[1], parts[1])
    if head not in LAYERS:
        raise AssertionError(f"{module}: not in a layer folder (layers: {', '.join(LAYERS)})")
    return LAYERS.index(head)


def _imports(tree: ast.AST, module: str, is_package: bool):
    """(imported module, [names], line) of every import of ftstab_mj code in ``tree``."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "ftstab_mj":
                    yield a.name, [], node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against this module's package
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] == "ftstab_mj":
                yield target, [a.name for a in node.names], node.lineno


def violations(root: Path = PACKAGE) -> list[str]:
    """Every upward import, import of another module's private name, and import circle under ``root``."""
    modules = {_module(p, root): p for p in root.rglob("*.py")}
    out, edges = [], {}
    for name, path in sorted(modules.items()):
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        here = _layer(name)
        for target, names, line in _imports(tree, name, path.name == "__init__.py"):
            where = f"{path.relative_to(root.parent)}:{line}"
            sub = [f"{target}.{n}" for n in names if f"{target}.{n}" in modules]
            if name == "ftstab_mj":  # the root hands out the Python API lazily: its face, not a layer
                continue
            for t in sub or [target]:
                if t not in (name, "ftstab_mj"):
                    edges.setdefault(name, set()).add(t)
            if target == "ftstab_mj":
                if set(names) - {"__version__"}:
                    out.append(f"{where}: {name} imports {names} from the package root (only the version)")
                targets = sub
            else:
                targets = [target]
            for t in targets:
                if _layer(t) > here:
                    out.append(f"{where}: {name} ({LAYERS[here]}) imports {t} ({LAYERS[_layer(t)]}), a layer above")
            private = [n for n in names if n.startswith("_") and not n.startswith("__")
                       and f"{target}.{n}" not in modules]
            if private and target != name:
                out.append(f"{where}: {name} imports the private name(s) {', '.join(private)} of {target}")
    # circles between modules (a package's __init__ importing its own modules is not one)
    def reach(start):
        seen, todo = set(), [start]
        while todo:
            for nxt in edges.get(todo.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return seen
    for name in sorted(edges):
        for t in sorted(edges[name]):
            if name in reach(t) and not (t.startswith(name + ".") or name.startswith(t + ".")):
                out.append(f"circle: {name} -> {t} -> ... -> {name}")
    return out


def test_imports_run_only_downward_never_private_never_in_a_circle():
    found = violations()
    assert not found, "\n".join(found)


def test_every_layer_folder_says_what_it_holds_and_may_import():
    for layer in LAYERS:
        path = PACKAGE / layer / "__init__.py"
        path = path if path.exists() else PACKAGE / f"{layer}.py"
        doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8")))
        assert doc and "import" in doc, f"{path}: a docstring saying what it may import"


@pytest.mark.parametrize("planted, expected", [
    ("from ftstab_mj.studies.compare import load_comparison\n", "a layer above"),
    ("from ftstab_mj.control.hong_terms import _power\n", "private name"),
    ("import ftstab_mj.scenario.loader\n", "a layer above"),
])
def test_the_layer_test_fails_on_a_planted_import(tmp_path, planted, expected):
    copy = tmp_path / "ftstab_mj"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "*.so", "_data"))
    target = copy / "plants" / "cart.py"
    target.write_text(planted + target.read_text(encoding="utf-8"), encoding="utf-8")
    found = violations(copy)
    assert any(expected in line and "plants/cart.py:1" in line for line in found), found


def test_the_layer_test_finds_a_planted_circle(tmp_path):
    copy = tmp_path / "ftstab_mj"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "*.so", "_data"))
    (copy / "config" / "a_mod.py").write_text("from ftstab_mj.config import b_mod\n")
    (copy / "config" / "b_mod.py").write_text("def f():\n    from ftstab_mj.config import a_mod\n")
    assert any(line.startswith("circle: ftstab_mj.config.a_mod") for line in violations(copy))


def _law_name_comparisons(root: Path, names: set[str]) -> list[str]:
    """Comparisons of a value with a law's name (``law == "robust"``, ``x in ("nominal", "robust")``)."""
    out = []
    for path in sorted(root.rglob("*.py")):
        if "laws" in path.relative_to(root).parts[:-1]:
            continue  # a law's own module may name itself
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.Compare):
                continue
            for side in (node.left, *node.comparators):
                items = side.elts if isinstance(side, (ast.Tuple, ast.List, ast.Set)) else [side]
                hit = [i.value for i in items if isinstance(i, ast.Constant) and i.value in names]
                if hit:
                    out.append(f"{path.relative_to(root.parent)}:{node.lineno}: compares with law name(s) {hit}")
    return out


def test_no_code_outside_the_laws_compares_a_law_name():
    """Code asks a law what it declares (time_bound, bound_holds, ultimate_bound, ...), never its name."""
    from ftstab_mj.control import LAWS

    found = _law_name_comparisons(PACKAGE, set(LAWS))
    assert not found, "\n".join(found)


def test_the_law_name_test_finds_a_planted_comparison(tmp_path):
    copy = tmp_path / "ftstab_mj"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "*.so", "_data"))
    (copy / "metrics" / "planted.py").write_text('def f(loop):\n    return loop.law in ("nominal", "robust")\n')
    assert _law_name_comparisons(copy, {"nominal", "robust"}) == [
        "ftstab_mj/metrics/planted.py:2: compares with law name(s) ['nominal', 'robust']"]
