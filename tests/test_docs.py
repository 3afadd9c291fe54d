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


@pytest.mark.slow
def test_the_site_builds_strictly(tmp_path):
    """Every page in the nav, every link and anchor resolving (mkdocs.yml's validation: a warning fails
    a strict build)."""
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent))
    if mkdocs is None:
        pytest.skip("mkdocs is not installed (pip install -e '.[docs]')")
    out = subprocess.run([mkdocs, "build", "--strict", "--site-dir", str(tmp_path / "site")],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    assert (tmp_path / "site" / "cli" / "index.html").is_file()
    assert (tmp_path / "site" / "history" / "index.html").is_file()


def _sections(page: Path) -> dict[str, list[str]]:
    """A page's ``## `` sections: heading -> its lines, the heading's included (code fences respected)."""
    sections: dict[str, list[str]] = {}
    current, fence = None, False
    for line in page.read_text().splitlines():
        fence ^= line.startswith("```")
        if not fence and line.startswith("## "):
            current = line[3:]
            sections[current] = []
        if current is not None:
            sections[current].append(line)
    return sections


def test_results_and_decisions_are_short_and_link_their_evidence():
    """Issue 107: the results page holds the current tables (at most 400 lines), the decisions log
    each current default in at most 15 lines with a link to the history page or table that is its
    evidence (at most 600 lines); the dated logs are history pages, each in the site's nav."""
    results, decisions = ROOT / "docs" / "results.md", ROOT / "docs" / "decisions.md"
    assert len(results.read_text().splitlines()) <= 400
    assert len(decisions.read_text().splitlines()) <= 600
    for heading, lines in _sections(decisions).items():
        body = "\n".join(lines).rstrip()
        assert len(body.splitlines()) <= 15, f"decisions.md: '{heading}' takes {len(body.splitlines())} lines"
        assert re.search(r"\]\((history/|results\.md|flags\.md)", body), f"decisions.md: '{heading}' links no evidence"
    days = sorted(p.name for p in (ROOT / "docs" / "history").glob("2*.md"))
    assert days and all(re.fullmatch(r"\d{4}-\d\d-\d\d\.md", d) for d in days)
    nav = (ROOT / "mkdocs.yml").read_text()
    assert all(f"history/{d}" in nav for d in days)
    # the tables lead to the days they came from
    linked = set(re.findall(r"history/(\d{4}-\d\d-\d\d\.md)", results.read_text() + decisions.read_text()))
    assert set(days) <= linked, set(days) - linked


def _code_blocks(text: str) -> list[str]:
    return re.findall(r"^```bash\n(.*?)^```", text, re.S | re.M)


def test_the_readmes_first_command_trains_without_the_test_tools_and_its_test_command_is_cis():
    """Issue 107: the README opens with two commands in two blocks: the first installs what training
    needs (no extra) and trains; the second installs the extras CI installs and runs what .ci/run runs.
    torch is installed by one rule wherever a page says how: PyTorch's CPU index on Linux."""
    readme = (ROOT / "README.md").read_text()
    first, second = _code_blocks(readme)[:2]
    assert len(first.strip().splitlines()) == 1 and len(second.strip().splitlines()) == 1
    steps = [s.strip() for s in first.split("&&")]
    assert "pip install -e ." in steps and not any("[" in s for s in steps if s.startswith("pip install -e"))
    assert steps[-1] == "splat-train scgaussian --data synthetic/forward" and "pytest" not in first
    ci = (ROOT / ".ci" / "run").read_text()
    install, test = [s.strip() for s in second.split("&&")]
    assert test == ci.strip().splitlines()[-1], "the README's test command is the one .ci/run runs"
    extras = re.fullmatch(r'pip install -e "(\.\[[a-z,]+\])"', install).group(1)
    assert f'pip install -q -e "{extras}"' in ci, "the README installs the extras CI installs"
    cpu = "pip install torch --index-url https://download.pytorch.org/whl/cpu"
    install_page = (ROOT / "docs" / "install.md").read_text()
    assert cpu in steps and cpu in readme.split("## Install")[1] and cpu in install_page
    torch_lines = {ln.split("#")[0].strip() for page in (readme, install_page) for block in _code_blocks(page)
                   for part in block.split("&&") for ln in part.splitlines() if re.search(r"pip install torch( |$)", ln)}
    assert torch_lines == {cpu}, torch_lines


def test_the_readmes_links_into_the_docs_resolve():
    """The site's strict build checks the docs' own links; the README is not in it, so its links to a
    page, and to a heading of it, are checked here (the heading's anchor as MkDocs' toc makes it)."""
    toc = pytest.importorskip("markdown.extensions.toc", reason="markdown comes with the docs extra")
    readme = (ROOT / "README.md").read_text()
    broken = []
    for target, anchor in re.findall(r"\]\(((?:docs/)?[\w./-]+\.md)(?:#([\w-]+))?\)", readme):
        page = ROOT / target
        if not page.is_file():
            broken.append(target)
        elif anchor:
            headings = re.findall(r"^#{1,6} (.+)$", re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M), re.M)
            if anchor not in {toc.slugify(h.replace("`", ""), "-") for h in headings}:
                broken.append(f"{target}#{anchor}")
    assert broken == []


def test_the_project_has_a_licence_a_free_name_and_a_citation():
    """Issue 61: a LICENSE named in pyproject, the distribution name used by every hint (``splat``
    is another project's on PyPI; ``splat-framework`` was free on 2026-11-27), a CITATION.cff."""
    tomllib = pytest.importorskip("tomllib", reason="tomllib is Python 3.11+")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["name"] == "splat-framework" and project["license"] == "Apache-2.0"
    assert (ROOT / "LICENSE").read_text().lstrip().startswith("Apache License")
    cff = (ROOT / "CITATION.cff").read_text()
    assert cff.startswith("cff-version: 1.2.0") and "license: Apache-2.0" in cff
    assert "Structure Consistent Gaussian Splatting with Matching Prior" in cff.split("references:")[0]
    stale = [f"{p.relative_to(ROOT)}" for base in ("src", "docs", "tests", "examples") for p in (ROOT / base).rglob("*")
             if p.suffix in (".py", ".md", ".toml") and p.name != "test_docs.py"
             and re.search(r"""pip install ["']?splat\[""", p.read_text())]
    assert stale == [] and 'pip install "splat[' not in (ROOT / "README.md").read_text()


def test_no_user_facing_page_points_at_the_development_machines_shared_folder():
    # ../shared exists only on the developers' machines; users are told of $SPLAT_DATA and the data page
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    found = [f"{p.relative_to(ROOT)}:{i}" for p in pages
             for i, line in enumerate(p.read_text().splitlines(), 1) if "../shared" in line]
    assert found == []


def _generate_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_generate", ROOT / "docs" / "generate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_quoted_figure_comes_from_the_figures_file_and_a_stale_copy_is_rewritten():
    """Issue 85: figures quoted in the README and the docs are written once (docs/figures.toml);
    a page's stale copy is replaced, an unknown figure or unpaired markers stop naming the page."""
    gen = _generate_module()
    known = {"kernel-build": "about 25 s"}
    stale = "builds (<!-- figure:kernel-build -->about a minute<!-- /figure:kernel-build -->)."
    assert gen.fill_figures(stale, known, "README.md") == \
        "builds (<!-- figure:kernel-build -->about 25 s<!-- /figure:kernel-build -->)."
    with pytest.raises(SystemExit, match="README.md: figure 'test-count' is not in figures.toml"):
        gen.fill_figures("<!-- figure:test-count -->1<!-- /figure:test-count -->", known, "README.md")
    with pytest.raises(SystemExit, match="cli.md: figure 'kernel-build' is closed by '/figure:ci-time'"):
        gen.fill_figures("<!-- figure:kernel-build -->1<!-- /figure:ci-time -->", known, "cli.md")
    quoted = {m.group(1) for page in [ROOT / "README.md", *(ROOT / "docs").glob("*.md")]
              for m in gen.FIGURE.finditer(page.read_text())}
    assert quoted == set(gen.figures()), "every figure in docs/figures.toml is quoted, and only those"


def test_the_readme_test_count_is_the_suites():
    """The README's 'about N tests' is within 5 % of what pytest collects."""
    gen = _generate_module()
    figure = int(re.sub(r"[^0-9]", "", gen.figures()["test-count"]))
    out = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                          "-p", "no:xdist", str(ROOT / "tests")], capture_output=True, text=True, cwd=ROOT)
    found = re.search(r"^(\d+) tests? collected", out.stdout, re.M)
    assert found, out.stdout[-2000:] + out.stderr[-2000:]
    collected = int(found.group(1))
    assert abs(collected - figure) <= 0.05 * collected, f"docs/figures.toml says {figure}, pytest collects {collected}"
