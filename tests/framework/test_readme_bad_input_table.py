"""The bad-input table of docs/reliability.md says exactly what the tests' bad_input markers say."""

from __future__ import annotations

import textwrap

import pytest

from bad_input_table import PAGE, collect, readme_section, render


def test_readme_bad_input_table():
    rows = collect()
    assert len(rows) >= 10
    assert readme_section(PAGE.read_text(encoding="utf-8")) == render(rows), (
        "docs/reliability.md's bad-input table differs from the tests' markers: run `python tests/bad_input_table.py --write`"
    )


def test_markers_are_collected_with_their_tests(tmp_path):
    (tmp_path / "test_a.py").write_text(textwrap.dedent('''
        import pytest

        @pytest.mark.bad_input("a FIFO", "exit 2")
        def test_one():
            pass

        @pytest.mark.parametrize("x", [1])
        @pytest.mark.bad_input("a FIFO", "exit 2")
        def test_two(x):
            pass
    '''))
    rows = collect(tmp_path)
    assert [(r.input, r.behaviour, r.tests) for r in rows] == [
        ("a FIFO", "exit 2", [f"`{tmp_path.name}/test_a.py::test_one`", f"`{tmp_path.name}/test_a.py::test_two`"])
    ]
    (tmp_path / "test_b.py").write_text('import pytest\n@pytest.mark.bad_input("a FIFO", "exit 1")\ndef test_x(): pass\n')
    with pytest.raises(ValueError, match="two behaviours"):
        collect(tmp_path)
