"""Every ``SPLAT_*`` variable is validated where it is read (issue 60): an invalid value is one
line naming the variable and what it takes, exit 2, before any work starts; its reader parses it
with the same function."""

from __future__ import annotations

import os

import pytest

from cli_harness import cli_env, run_cli
from splat_framework.environment import VARIABLES, check_environment, compile_setting, threads_setting
from splat_framework.errors import DataError

INVALID = {
    "SPLAT_THREADS": ["-1", "0", "abc", "2.5", "4097", "99999999999"],
    "SPLAT_COMPILE": ["2", "maybe"],
    "SPLAT_RASTERIZER": ["cuda", "gsplat", "1"],
    "SPLAT_IMAGE_MEMORY_BUDGET": ["lots", "0", "-5G"],
    "SPLAT_CACHE": ["FILE", "/proc/self", "/proc/self/cache"],
    "SPLAT_DATA": ["FILE"],
    "SPLAT_CONFIG_PATH": ["MISSING"],
    "SPLAT_PLUGINS": ["my plugin", "my_plugin,not a module", "mod:spec", "pkg..parts", "1mod"],
    "SPLAT_METHODS": ["my_methods:spec", "anything"],
    "SPLAT_INSTALLED_PLUGINS": ["maybe", "2"],
}
VALID = {
    "SPLAT_THREADS": ["auto", "off", "1", "16", " Auto ", "", "4096"],
    "SPLAT_COMPILE": ["1", "0", "true", "Off", ""],
    "SPLAT_RASTERIZER": ["auto", "native", "Triton", "torch", ""],
    "SPLAT_IMAGE_MEMORY_BUDGET": ["2G", "512M", "1.5GiB", "800000000", ""],
    "SPLAT_CACHE": ["NEW"],
    "SPLAT_DATA": ["NEW"],
    "SPLAT_CONFIG_PATH": ["DIR"],
    "SPLAT_PLUGINS": ["my_plugin", "pkg.parts, other,", ""],
    "SPLAT_METHODS": ["", " "],
    "SPLAT_INSTALLED_PLUGINS": ["on", "off", "0", "Yes", ""],
}


def _value(text: str, tmp_path) -> str:
    (tmp_path / "file").write_text("x")
    (tmp_path / "dir").mkdir(exist_ok=True)
    return {"FILE": str(tmp_path / "file"), "MISSING": str(tmp_path / "missing"), "NEW": str(tmp_path / "new"),
            "DIR": str(tmp_path / "dir")}.get(text, text)


def test_every_variable_has_invalid_and_valid_cases():
    assert set(INVALID) == set(VARIABLES) == set(VALID)


@pytest.mark.parametrize("name,value", [(n, v) for n, vs in INVALID.items() for v in vs])
def test_an_invalid_value_is_one_line_naming_the_variable(name, value, tmp_path):
    value = _value(value, tmp_path)
    with pytest.raises(DataError) as info:
        check_environment({name: value})
    message = str(info.value)
    assert message.startswith(f"{name}={value!r}: ") and "\n" not in message


@pytest.mark.parametrize("name,value", [(n, v) for n, vs in VALID.items() for v in vs])
def test_a_valid_value_passes(name, value, tmp_path):
    check_environment({name: _value(value, tmp_path)})


def test_the_readers_parse_with_the_same_rules():
    assert threads_setting(None) == "auto" and threads_setting(" 4 ") == 4 and threads_setting("OFF") == "off"
    assert compile_setting(None) is None and compile_setting("yes") is True and compile_setting("0") is False
    with pytest.raises(DataError, match=r"^SPLAT_THREADS='0': expected auto, off or a whole number of threads \(1 to 4096\)$"):
        threads_setting("0")


@pytest.mark.bad_input("`SPLAT_THREADS=-1` (or `0`, `abc`, `99999999999`), `SPLAT_COMPILE=maybe` or any other invalid `SPLAT_*` value",
                       "exit 2, one line naming the variable and what it takes, before any work")
@pytest.mark.parametrize("name,value,expected", [
    ("SPLAT_THREADS", "abc", "expected auto, off or a whole number of threads (1 to 4096)"),
    ("SPLAT_THREADS", "99999999999", "expected auto, off or a whole number of threads (1 to 4096)"),
    ("SPLAT_COMPILE", "maybe", "expected 1 or 0 (also true/false, yes/no, on/off)"),
])
def test_every_command_refuses_an_invalid_variable_before_any_work(name, value, expected, tmp_path):
    env = cli_env(**{name: value})
    for command, args in (("train", ("3dgs", "--data", "synthetic/forward-tiny", "--steps", "2", "--output", tmp_path / "run")),
                          ("eval", (tmp_path / "nothing",))):
        run_cli(command, *args, code=2, match=f"error: {name}={value!r}: {expected}", env=env,
                watch=[tmp_path])
    assert not (tmp_path / "run").exists() and os.listdir(tmp_path) == []
