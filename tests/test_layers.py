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
