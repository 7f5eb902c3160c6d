"""The house's layout, drawn from the code: no two modules that need each other (an import
circle, counting imports inside functions too; an import under ``if TYPE_CHECKING:`` names a
type for annotations and is not one), no private name imported from another module, no module
longer than a reader takes in at once."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

REPO = Path(__file__).resolve().parent.parent
PACKAGES = ("shared", "schemas", "services")
MAX_LINES = 600


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in sorted((REPO / pkg).rglob("*.py")):
            parts = list(f.relative_to(REPO).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


def _imports(mods: dict[str, Path]):
    """Per module, the modules it imports (anywhere in it), and every private name it imports
    from another module (``(importer, module, name)``)."""

    def owner(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    edges, private = {m: set() for m in mods}, []
    for m, f in mods.items():
        package = m.split(".") if f.name == "__init__.py" else m.split(".")[:-1]
        tree = ast.parse(f.read_text())
        typing_only = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If)
                       and isinstance(block.test, ast.Name) and block.test.id == "TYPE_CHECKING"
                       for n in ast.walk(block)}
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.Import):
                targets = [owner(a.name) for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = package[: len(package) - node.level + 1] if node.level else []
                full = ".".join(base + ([node.module] if node.module else []))
                if full.split(".")[0] not in PACKAGES:
                    continue
                targets = []
                for a in node.names:
                    sub = f"{full}.{a.name}"
                    targets.append(owner(sub) if sub in mods else owner(full))
                    if a.name.startswith("_") and not a.name.startswith("__") and sub not in mods:
                        private.append((m, full, a.name))
            else:
                continue
            edges[m].update(t for t in targets if t and t != m)
    return edges, private


def _circles(edges: dict[str, set[str]]) -> list[list[str]]:
    names = sorted(edges)
    index = {n: i for i, n in enumerate(names)}
    pairs = [(index[a], index[b]) for a, bs in edges.items() for b in bs]
    graph = csr_matrix((np.ones(len(pairs)), tuple(np.array(pairs).T)), shape=(len(names),) * 2)
    _, label = connected_components(graph, directed=True, connection="strong")
    groups = [[names[i] for i in np.flatnonzero(label == k)] for k in np.unique(label)]
    return [g for g in groups if len(g) > 1]


def test_the_graph_finds_a_circle_and_a_private_import(tmp_path, monkeypatch):
    """The check itself: two modules importing each other inside functions are a circle, and a
    private name taken from another module is found."""
    pkg = tmp_path / "shared"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from shared.b import g\n")
    (pkg / "b.py").write_text("from shared.a import f as _f\nfrom shared.a import _hidden\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from shared.d import T\n")
    (pkg / "d.py").write_text("from shared.c import g\n")
    monkeypatch.setattr(sys.modules[__name__], "REPO", tmp_path)
    edges, private = _imports(_modules())
    assert _circles(edges) == [["shared.a", "shared.b"]]
    assert private == [("shared.b", "shared.a", "_hidden")]


def test_no_import_circles_and_no_private_names_across_modules():
    edges, private = _imports(_modules())
    assert _circles(edges) == []
    assert private == []


def test_no_module_is_longer_than_a_reader_takes_in():
    long = {m: n for m, f in _modules().items() if (n := len(f.read_text().splitlines())) > MAX_LINES}
    assert long == {}, f"modules over {MAX_LINES} lines: {long}"


#: the library's layers, lowest first (shared/__init__.py says what each owns); a package may
#: import its own layer and the layers below it, never one above
LAYERS = (("shared.errors", "shared.deadline", "shared.compiled", "shared.extras", "shared.digest",
           "shared.once", "shared.rates"), ("shared.motion",), ("shared.io",),
          ("shared.bodies",), ("shared.pss",), ("shared.estimation",), ("shared.coaching",), ("shared.agents",),
          ("shared.capture", "shared.observe"), ("shared.bus", "schemas"), ("shared.reproduce",), ("shared.reports",),
          ("shared.cli", "shared.demo", "services"))


def _package(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "shared" and len(parts) > 1 else parts[0]


def test_every_package_imports_only_its_layer_and_those_below():
    layer = {p: k for k, ps in enumerate(LAYERS) for p in ps}
    edges, _ = _imports(_modules())
    packages = {_package(m) for m in edges} - {"shared"}
    assert packages <= set(layer), f"packages in no layer: {packages - set(layer)}"
    upward = sorted({(a, b) for m, targets in edges.items() for t in targets
                     if (a := _package(m)) != (b := _package(t)) and b != "shared" and layer[b] > layer[a]})
    assert upward == [], f"imports of a higher layer: {upward}"


def test_the_pss_core_s_public_api_is_documented_and_costs_nothing_to_import():
    """``shared.pss.__all__``: every name resolves; every function's docstring has numpydoc
    Parameters and Returns; importing the package imports none of its modules."""
    import inspect
    import subprocess

    import shared.pss as pss

    for name in pss.__all__:
        obj = getattr(pss, name)
        assert obj.__doc__, name
        if inspect.isfunction(obj):
            assert "Parameters\n    ----------" in obj.__doc__ and "Returns\n    -------" in obj.__doc__, name
    loaded = subprocess.run([sys.executable, "-c", "import sys, shared.pss; "
                             "print(sorted(m for m in sys.modules if m.startswith('shared.pss.')))"],
                            capture_output=True, text=True, cwd=REPO, timeout=60)
    assert loaded.returncode == 0 and loaded.stdout.strip() == "[]", loaded.stdout + loaded.stderr
