"""The CLI harness itself: it sees every kind of change, and it fails a multi-line or traceback error."""

from __future__ import annotations

import os

import pytest

from cli_harness import changed_paths, run_cli, snapshot


def test_snapshot_sees_content_mode_link_and_special_changes(tmp_path):
    (tmp_path / "a.txt").write_text("one")
    (tmp_path / "sub").mkdir()
    os.symlink("a.txt", tmp_path / "link")
    os.mkfifo(tmp_path / "pipe")
    base = snapshot(tmp_path)
    assert base["pipe"][0] == "special" and base["link"] == ("link", "a.txt")
    (tmp_path / "a.txt").write_text("two")
    assert changed_paths(base, snapshot(tmp_path)) == {"a.txt"}
    os.chmod(tmp_path / "sub", 0o700)
    os.unlink(tmp_path / "link")
    os.symlink("sub", tmp_path / "link")
    (tmp_path / "sub" / "new").write_bytes(b"")
    assert changed_paths(base, snapshot(tmp_path)) == {"a.txt", "sub", "link", os.path.join("sub", "new")}


def test_run_cli_checks_code_lines_and_changes(tmp_path):
    missing = tmp_path / "no-run"
    r = run_cli("export", missing, "--out", tmp_path / "out.ply", code=2, match="no such run folder", watch=[tmp_path])
    assert len(r.message.splitlines()) == 1
    with pytest.raises(AssertionError, match="expected exit 0"):
        run_cli("export", missing, "--out", tmp_path / "out.ply", code=0)
    with pytest.raises(AssertionError, match="not in the message"):
        run_cli("export", missing, "--out", tmp_path / "out.ply", match="something it never says")


def test_run_cli_fails_a_change_outside_the_allowed_paths(tmp_path):
    out = tmp_path / "scene"
    args = ("forward", "--out", out, "--width", 16, "--height", 12, "--views", 3)
    with pytest.raises(AssertionError, match="changed outside the expected output"):
        run_cli("scene", *args, code=0, watch=[tmp_path])
    run_cli("scene", *args[:2], tmp_path / "scene2", *args[3:], code=0, watch=[tmp_path], allowed=[tmp_path / "scene2"])
