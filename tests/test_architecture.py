"""The architecture is checked, not remembered: the import contracts in pyproject.toml
(``[tool.importlinter]``) hold for the tree as it is.

The same check runs in CI as ``lint-imports``; running it here too means ``pytest`` alone catches
a core module that starts importing paho, threads, the clock or a unit.
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: The developers' guide: no function over this many lines (decorators and docstring included).
MAX_FUNCTION_LINES = 100


def test_import_contracts_hold() -> None:
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which(
        "lint-imports"
    )
    assert exe, "import-linter is a test dependency (pip install -e '.[test]')"
    result = subprocess.run(
        [exe, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert "BROKEN" not in result.stdout
    assert "5 kept, 0 broken" in result.stdout, result.stdout[-2000:]


def long_functions(root: Path, limit: int) -> dict[str, int]:
    """``path:qualified.name`` -> lines, for every function or method under ``root`` longer than
    ``limit`` lines."""
    found: dict[str, int] = {}

    def visit(node: ast.AST, path: str, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            name = prefix
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                name = f"{prefix}{child.name}"
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                first = min([child.lineno] + [d.lineno for d in child.decorator_list])
                lines = (child.end_lineno or child.lineno) - first + 1
                if lines > limit:
                    found[f"{path}:{name}"] = lines
            visit(child, path, f"{name}." if name != prefix else prefix)

    for file in sorted(root.rglob("*.py")):
        visit(ast.parse(file.read_text(encoding="utf-8")), file.relative_to(root).as_posix(), "")
    return found


def test_long_functions_are_found(tmp_path: Path) -> None:
    body = "".join(f"        x{i} = {i}\n" for i in range(4))
    (tmp_path / "m.py").write_text(
        f"class C:\n    @staticmethod\n    def f():\n{body}\n\ndef g():\n    pass\n"
    )
    assert long_functions(tmp_path, 5) == {"m.py:C.f": 6}  # decorator, def and 4 lines
    assert long_functions(tmp_path, 6) == {}


def test_no_function_over_100_lines() -> None:
    too_long = long_functions(ROOT / "src", MAX_FUNCTION_LINES)
    assert not too_long, f"split these (over {MAX_FUNCTION_LINES} lines): {too_long}"
