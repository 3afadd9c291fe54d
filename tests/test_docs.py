"""The documentation site: its generated blocks are current, it builds without a warning, and
every SPLAT_* variable the code reads is documented."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_generated_docs_are_current():
    out = subprocess.run([sys.executable, str(ROOT / "docs" / "generate.py"), "--check"],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr


def test_every_environment_variable_the_code_reads_is_documented():
    from splat_framework.environment import VARIABLES

    named = set()
    for path in (ROOT / "src").rglob("*.py"):
        named |= set(re.findall(r"\bSPLAT_[A-Z][A-Z_]*[A-Z]\b", path.read_text()))
    assert named - set(VARIABLES) == set(), "add these to splat_framework/environment.py"
    assert set(VARIABLES) - named == set(), "documented but never read"


def test_the_site_builds_strictly(tmp_path):
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent))
    if mkdocs is None:
        pytest.skip("mkdocs is not installed (pip install -e '.[docs]')")
    out = subprocess.run([mkdocs, "build", "--strict", "--site-dir", str(tmp_path / "site")],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    assert (tmp_path / "site" / "cli" / "index.html").is_file()
