"""The linter's rules (pyproject.toml's ``[tool.ruff]``: pyflakes, pycodestyle's errors, import
sorting) hold on the whole tree; the test extra pins ruff."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_check_passes_on_the_tree():
    ruff = shutil.which("ruff")
    if ruff is None:
        pytest.skip("ruff is not installed (pip install -e '.[test]')")
    done = subprocess.run([ruff, "check", "--no-cache", "--quiet", str(ROOT)], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr


def test_ruff_check_fails_on_an_unused_import(tmp_path):
    """The rules are in force: a planted unused import in a copy of the configuration fails."""
    ruff = shutil.which("ruff")
    if ruff is None:
        pytest.skip("ruff is not installed (pip install -e '.[test]')")
    (tmp_path / "pyproject.toml").write_text((ROOT / "pyproject.toml").read_text())
    (tmp_path / "planted.py").write_text("import os\nimport sys\n\nprint(sys.argv)\n")
    done = subprocess.run([ruff, "check", "--no-cache", str(tmp_path)], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 1 and "F401" in done.stdout
