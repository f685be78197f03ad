"""The library stays below its shells: no module of common/ imports services/ (nor zenoh), not even
inside a function body."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def _offenders(folder: Path, banned: tuple[str, ...]) -> dict[str, list[str]]:
    out = {}
    for path in sorted(folder.rglob("*.py")):
        bad = sorted(n for n in _imports(path) if n.split(".")[0] in banned)
        if bad:
            out[str(path.relative_to(ROOT))] = bad
    return out


def test_common_never_imports_services_or_the_bus():
    assert _offenders(ROOT / "common", ("services", "zenoh")) == {}


def test_the_check_sees_an_import_inside_a_function(tmp_path):
    """Negative control: a function-body import of services is found."""
    (tmp_path / "m.py").write_text("def f():\n    from services.launcher import Pipeline\n    import zenoh\n")
    global ROOT
    old, ROOT = ROOT, tmp_path
    try:
        assert _offenders(tmp_path, ("services", "zenoh")) == {"m.py": ["services.launcher", "zenoh"]}
    finally:
        ROOT = old


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(root: Path, packages=("common", "services")) -> dict[str, set[str]]:
    """Module -> the project modules it imports anywhere (function bodies too). ``from P import
    X`` counts as importing ``P.X`` when that is a module, else ``P``; relative imports resolved."""
    files = {_module_name(p, root): p for pkg in packages for p in (root / pkg).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for mod, path in files.items():
        is_pkg = path.name == "__init__.py"
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    pkg = mod.split(".") if is_pkg else mod.split(".")[:-1]
                    pkg = pkg[: len(pkg) - (node.level - 1)]
                    base = ".".join(pkg + ([base] if base else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in files else base for a in node.names]
            else:
                continue
            for t in targets:
                while t and t not in files:
                    t = t.rpartition(".")[0]
                if t and t != mod:
                    deps.add(t)
        graph[mod] = deps
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles: strongly connected components of more than one module (Tarjan), a
    package's ``__init__`` importing its own submodules left out (that is how packages re-export)."""
    graph = {m: {d for d in deps if not d.startswith(m + ".")} for m, deps in graph.items()}
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    import sys

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def test_no_import_cycles():
    assert cycles(import_graph(ROOT)) == []


def test_the_cycle_check_finds_a_cycle_through_a_function_body(tmp_path):
    """Negative control: a -> b at the top, b -> a inside a function."""
    pkg = tmp_path / "common"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from common import b\n")
    (pkg / "b.py").write_text("def f():\n    from common.a import g\n")
    (pkg / "c.py").write_text("from . import a\n")
    assert cycles(import_graph(tmp_path, ("common",))) == [["common.a", "common.b"]]
