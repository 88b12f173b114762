"""The architecture is checked, not remembered: the import contracts in pyproject.toml
(``[tool.importlinter]``) hold for the tree as it is.

The same check runs in CI as ``lint-imports``; running it here too means ``pytest`` alone catches
a core module that starts importing paho, threads, the clock or a unit.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


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
    assert "4 kept, 0 broken" in result.stdout, result.stdout[-2000:]
