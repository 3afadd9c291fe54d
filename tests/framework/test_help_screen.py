"""``splat-train METHOD --help``, one group a screen (``cli.help_screen``): a main screen that fits
150 lines at 100 columns, every flag on the screen of its group, the kinds a method takes listed."""

from __future__ import annotations

import contextlib
import io
import re
from importlib.metadata import EntryPoint, entry_points
from typing import Literal

import pytest

from splat_framework.config import Kind
from splat_framework.config.init import RandomInitConfig
from splat_framework.registry import discover_methods

COLUMNS = "100"
"""The width docs/cli.md is written at (docs/generate.py)."""
MAX_LINES = 150


def help_of(*argv: str) -> str:
    """What ``splat-train ARGV`` prints, at :data:`COLUMNS` columns, without colour."""
    from splat_framework.cli.train import main

    out = io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(out):
        mp.setenv("COLUMNS", COLUMNS)
        mp.setenv("NO_COLOR", "1")
        with pytest.raises(SystemExit) as e:
            main(list(argv))
    assert e.value.code in (0, None), out.getvalue()[-2000:]
    return out.getvalue()


def flags(text: str) -> set[str]:
    """The flags a help screen shows (``--a.b-c``, its ``--no-`` form left out)."""
    return set(re.findall(r"^[│|\s]*(--[a-z0-9][\w.\-]*)", text, re.M)) - {"--help"}


METHODS = sorted({"3dgs", "scgaussian", "scaffold-gs", "octree-gs"} & set(discover_methods()))


@pytest.mark.slow  # builds every help screen of every method
@pytest.mark.parametrize("method", METHODS)
def test_the_main_screen_fits_150_lines_and_every_flag_is_on_its_groups_screen(method):
    main = help_of(method, "--help")
    assert len(main.splitlines()) <= MAX_LINES, f"{method} --help: {len(main.splitlines())} lines"
    every = flags(help_of(method, "--help", "all"))
    named = re.search(r"shows one\):\n(.*?)every flag", main, re.S).group(1)
    groups = re.findall(r"([\w.\-]+) \(\d+\)", named)
    screens = {g: flags(help_of(method, "--help", g)) for g in groups}
    assert set().union(flags(main), *screens.values()) == every  # no flag lost, none invented
    for group, shown in screens.items():  # a group's screen: its flags only
        assert all(f.startswith(f"--{group}.") for f in shown) or group == "options", (group, shown)
    assert "--model.init.kind" in flags(main) and "--strategy.kind" in flags(main)


def test_scgaussian_shows_the_chosen_matchers_flags_only():
    main = help_of("scgaussian", "--help")
    assert "--model.matching.kind" in flags(main) and "--model.matching.max-matches" not in flags(main)
    assert len(main.splitlines()) <= MAX_LINES
    sift = flags(help_of("scgaussian", "--model.matching.kind", "sift", "--help"))  # the choice opens its group
    assert {"--model.matching.sift-features", "--model.matching.max-matches"} <= sift
    assert not {"--model.matching.dense-upscale", "--model.matching.weights"} & sift
    auto = flags(help_of("scgaussian", "--help", "model.matching"))
    assert {"--model.matching.dense-upscale", "--model.matching.weights", "--model.matching.auto-min-matches"} <= auto
    assert "--model.matching.sift-features" not in auto


@pytest.mark.bad_input("`splat-train METHOD --help GROUP` naming no group of the method", "exit 2, one line naming its groups")
def test_an_unknown_group_is_one_line_naming_the_groups():
    from splat_framework.cli.common import ArgumentsError
    from splat_framework.cli.train import main

    with pytest.raises(ArgumentsError, match=r"--help strategyy: not a group of splat-train 3dgs .*strategy.*"
                                             r"did you mean"):
        main(["3dgs", "--help", "strategyy"])


class GridTestInit(RandomInitConfig):
    """A plugin's init kind (registered below through a fake entry point)."""

    kind: Kind[Literal["grid-test"]] = "grid-test"
    """The start."""


def test_the_kind_flags_list_the_registered_strategies_and_start_kinds(monkeypatch):
    """A strategy and an init kind that plugins register show in ``--help``'s kind flags of every
    method that takes them; a method that narrows its kinds lists its own."""
    from splat_framework import entry_points as plugins
    from splat_framework.config.init import init_kinds
    from splat_framework.config.strategy import strategy_kinds
    from splat_framework.entry_points import INIT_ENTRY_POINT_GROUP, STRATEGY_ENTRY_POINT_GROUP

    fake = [EntryPoint("ray-gaussian", "scg_plugin.config:RayStrategyConfig", STRATEGY_ENTRY_POINT_GROUP),
            EntryPoint("grid-test", f"{__name__}:GridTestInit", INIT_ENTRY_POINT_GROUP)]
    monkeypatch.setattr(plugins, "entry_points", lambda group: [e for e in [*entry_points(group=group), *fake]
                                                               if e.group == group])
    strategy_kinds.cache_clear()
    init_kinds.cache_clear()
    try:
        text = " ".join(help_of("3dgs", "--help").split())  # the help's lines joined: a list may wrap
        assert "The strategy's tag: default, ray-gaussian (each with its own flags)" in text
        assert "The init's kind: random, frustum, ply, sfm, triangulated, grid-test (each with its own flags)" in text
        scg = " ".join(help_of("scgaussian", "--help").split())
        assert "The init's kind: random, frustum, ply (each" in scg and "The strategy's tag: ray-gaussian. (default" in scg
    finally:
        strategy_kinds.cache_clear()
        init_kinds.cache_clear()


@pytest.mark.slow
def test_help_into_a_closed_pipe_prints_no_traceback():
    """``splat-train scgaussian --help | head -c 10``: the reader leaves early; the command stops
    quietly (exit 0, or 141 as a shell reports SIGPIPE), with nothing on stderr."""
    import subprocess
    import sys

    code = "import sys; from splat_framework.cli.train import entrypoint; sys.argv = ['splat-train', 'scgaussian', '--help']; entrypoint()"
    for _ in range(3):  # the race (the reader leaves before or after the last write) goes either way
        p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        p.stdout.read(10)
        p.stdout.close()
        err = p.stderr.read().decode()
        assert p.wait() in (0, 141) and err == "", err[-1500:]


def test_the_methods_screen_lists_each_variant_under_its_method():
    """``splat-train --help``: every method, and under each the variants built on it (the paper's
    rows under scgaussian, 3dgs-triang under 3dgs), each name once, no flat list of 26 choices."""
    import re

    text = help_of("--help")
    assert "{" not in text.splitlines()[0]
    block = text.partition("methods, each with its config variants under it")[2]
    entries = re.findall(r"^ {2}( {4})?([a-z0-9][\w.-]*)(?: {2,}|$)", block, re.M)
    methods = discover_methods()
    assert sorted(name for _, name in entries) == sorted(methods)
    parent = None
    for indent, name in entries:
        if not indent:
            parent = name
            assert not methods[name].base
        else:
            assert methods[name].base == parent, (name, parent)
    assert methods["scgaussian-paper-hybrid-rg"].base == "scgaussian" and methods["3dgs-triang"].base == "3dgs"
