"""The package's import graph obeys its layers (an ast scan of every module, deferred imports included).

Layers, bottom up: ``errors``/``_atomic`` (no brdfrig imports); ``rig`` (devices), ``hdr`` (images)
and ``fit`` (numbers), which never import each other; ``lighting`` (the one hdr<->fit bridge);
``report`` (figures, plots, HTML); ``session``; ``sim`` and ``evaluate``; ``devices``; ``cli`` on
top, imported by nothing but ``__main__``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "brdfrig"

BASE = {"errors", "_atomic", "ranges"}
ALLOWED: dict[str, set[str]] = {
    "errors": set(),
    "_atomic": {"errors"},
    "ranges": {"errors"},
    "rig": BASE | {"rig"},
    "hdr": BASE | {"hdr"},
    "fit": BASE | {"fit"},
    "lighting": BASE | {"hdr", "fit"},
    "orientation": BASE | {"fit", "lighting"},  # is a lat-long map the right way round for its sphere image
    "session": BASE | {"rig", "hdr", "fit", "lighting", "report", "session"},
    "sim": BASE | {"rig", "hdr", "fit", "lighting", "report", "session", "sim"},
    "evaluate": BASE | {"hdr", "fit", "lighting", "report", "session", "sim", "evaluate"},
    "report": BASE | {"hdr", "fit", "lighting", "report"},
    "export": BASE | {"fit", "lighting", "export"},
    "devices": BASE | {"rig", "sim", "session", "devices"},
    "cli": BASE | {"rig", "hdr", "fit", "lighting", "orientation", "session", "sim", "evaluate", "report", "export", "devices", "cli"},
    "__main__": {"cli"},
    "__init__": set(),
}


def _layer(path: Path) -> str:
    rel = path.relative_to(PACKAGE)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _imported_layers(path: Path):
    """(line, layer) of every brdfrig import in a module, deferred (function-level) imports included."""
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module + "." + a.name for a in node.names] if node.module == "brdfrig" else [node.module]
        elif isinstance(node, ast.ImportFrom):  # relative import: resolve against the module's package
            raise AssertionError(f"{path}:{node.lineno}: relative import; the project uses absolute imports")
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[0] == "brdfrig" and len(parts) > 1:
                yield node.lineno, parts[1]


def _modules():
    return sorted(PACKAGE.rglob("*.py"))


def test_the_scan_sees_the_package():
    layers = {_layer(p) for p in _modules()}
    assert {"rig", "hdr", "fit", "lighting", "session", "sim", "cli"} <= layers
    # every module's layer has a rule (a new top-level module must be placed deliberately)
    assert layers <= set(ALLOWED), sorted(layers - set(ALLOWED))


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_respect_layers(path):
    layer = _layer(path)
    bad = [f"line {line}: {layer} imports {target}" for line, target in _imported_layers(path)
           if target not in ALLOWED[layer] and target != "__version__"]
    assert not bad, f"{path.relative_to(PACKAGE)}: " + "; ".join(bad)


def test_a_forbidden_edge_is_caught(tmp_path):
    """The scan itself: a deferred fit import inside hdr is reported."""
    fake = tmp_path / "mod.py"
    fake.write_text("def f():\n    from brdfrig.fit.sh import sh_eval\n    import brdfrig.rig.turntable\n")
    assert [t for _, t in _imported_layers(fake)] == ["fit", "rig"]


def _fit_imports(path: Path) -> set[str]:
    """Names of the ``fit`` modules a module imports (module level and deferred)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            base = node.module.split(".")
            names = [node.module + "." + a.name for a in node.names] if base == ["brdfrig", "fit"] else [node.module]
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[:2] == ["brdfrig", "fit"] and len(parts) > 2 and (PACKAGE / "fit" / f"{parts[2]}.py").is_file():
                out.add(parts[2])
    return out


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of ``graph`` that hold a cycle (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph.get(v, ()):
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_fit_modules_import_no_cycle():
    """No two fit modules import each other, directly or round a loop, deferred imports included."""
    graph = {p.stem: _fit_imports(p) - {p.stem} for p in sorted((PACKAGE / "fit").glob("*.py"))}
    assert {"rho", "groundtruth"} <= graph["analytic"] and {"groundtruth", "merl"} <= graph["measured"]
    assert _cycles(graph) == []


def test_the_cycle_scan_sees_a_deferred_cycle(tmp_path):
    """The scan itself: a module-level edge one way and a deferred one back form a cycle."""
    a = tmp_path / "a.py"
    a.write_text("from brdfrig.fit import sh, scene\n\ndef f():\n    import brdfrig.fit.quadrature\n")
    assert _fit_imports(a) == {"sh", "scene", "quadrature"}
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
