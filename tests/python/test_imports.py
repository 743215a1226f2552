"""The package's import structure: the library never imports a CLI module, no module imports the
CLI entry point, imports form no cycle, and the library (and the benchmarks) work without the CLI."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "python" / "shotcrete"
MODULES = sorted(p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__")
LIBRARY = [m for m in MODULES if not m.startswith("cli")]
ENTRY_POINT = "cli"


def _is_cli(name: str) -> bool:
    return name == ENTRY_POINT or name.startswith("cli_")


def imported_modules(path: Path, package_relative: bool = True) -> set[str]:
    """Modules of the shotcrete package a file imports (anywhere in it, also inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1 and package_relative:  # from . import x / from .x import y
                if node.module:
                    found.add(node.module.split(".")[0])
                else:
                    found.update(a.name for a in node.names)
            elif node.level == 0 and node.module and node.module.split(".")[0] == "shotcrete":
                parts = node.module.split(".")
                if len(parts) > 1:
                    found.add(parts[1])
                else:
                    found.update(a.name for a in node.names)
        elif isinstance(node, ast.Import):
            for a in node.names:
                parts = a.name.split(".")
                if parts[0] == "shotcrete" and len(parts) > 1:
                    found.add(parts[1])
    return found & set(MODULES)


GRAPH = {m: imported_modules(PACKAGE / f"{m}.py") for m in MODULES}
GRAPH["__init__"] = imported_modules(PACKAGE / "__init__.py")


def test_the_library_imports_no_cli_module():
    bad = {m: sorted(n for n in GRAPH[m] if _is_cli(n)) for m in LIBRARY + ["__init__"]}
    assert not {m: n for m, n in bad.items() if n}, "library modules importing CLI modules"


def test_nothing_imports_the_cli_entry_point():
    assert not [m for m, deps in GRAPH.items() if ENTRY_POINT in deps]


def test_imports_form_no_cycle():
    state = {}

    def visit(m, stack):
        state[m] = "open"
        for n in sorted(GRAPH.get(m, ())):
            if state.get(n) == "open":
                pytest.fail("import cycle: " + " -> ".join(stack + [m, n]))
            if n not in state:
                visit(n, stack + [m])
        state[m] = "done"

    for m in sorted(GRAPH):
        if m not in state:
            visit(m, [])


def test_benchmarks_import_library_modules_only():
    for path in sorted((ROOT / "bench").glob("*.py")):
        assert not [n for n in imported_modules(path, package_relative=False) if _is_cli(n)], path.name


def test_import_shotcrete_leaves_matplotlib_alone():
    """`import shotcrete` must not pick a matplotlib backend for the user (plots.py sets Agg)."""
    code = "import sys, shotcrete\nassert 'matplotlib' not in sys.modules\n"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_library_imports_without_the_cli():
    code = ("import sys\n"
            f"import shotcrete, {', '.join('shotcrete.' + m for m in LIBRARY)}\n"
            "loaded = sorted(m for m in sys.modules if m.startswith('shotcrete.cli'))\n"
            "assert not loaded, loaded\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
