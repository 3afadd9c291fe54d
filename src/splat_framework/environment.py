"""Every ``SPLAT_*`` environment variable the project reads, with what it does (torch-free).

The one list: the CLI reference (``docs/cli.md``) is generated from it, and a test fails when
code under ``src/`` names a ``SPLAT_*`` variable that is not here. :func:`check_environment`
validates every variable that is set (every command calls it first: one line, exit 2), with the
same parsing functions their readers use.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from .errors import DataError

VARIABLES: dict[str, str] = {
    "SPLAT_DATA": "Folder under which a relative `--data` name that does not exist is looked up "
                  "(`splat-train 3dgs --data llff/fern` with `SPLAT_DATA=~/data` reads `~/data/llff/fern`).",
    "SPLAT_CACHE": "Where generated scenes, match caches and compiled kernels go (default `~/.cache/splat`); "
                   "the native rasterizer kernels are built under `$SPLAT_CACHE/native`, torch.compile's under "
                   "`$SPLAT_CACHE/inductor`.",
    "SPLAT_COMPILE": "`0` or `1`: compile the rasterizer's kernels (native C++ on a CPU, torch.compile elsewhere) "
                     "or run them eagerly, whatever `--compile` says.",
    "SPLAT_RASTERIZER": "Which kernels render: `auto` (the default: native C++ on a CPU, Triton on CUDA, torch "
                        "elsewhere, while kernels are compiled), `native`, `triton` (CUDA, or a CPU under "
                        "`TRITON_INTERPRET=1`) or `torch`; `--rasterizer` other than auto wins.",
    "SPLAT_THREADS": "CPU threads of the whole process (torch and OpenCV, every phase): `auto` (the default) "
                     "follows the cores other processes leave free, re-read every second; a whole number (1 to 4096) pins the "
                     "count; `off` leaves it alone.",
    "SPLAT_IMAGE_MEMORY_BUDGET": "Bytes of decoded training images kept in memory (suffixes K, M, G; unset: no "
                                "limit); images beyond it are decoded again when needed.",
    "SPLAT_CONFIG_PATH": "`:`-separated folders of TOML config variants, registered after the installed "
                         "packages' variants (a name already taken is refused with one warning naming both files).",
    "SPLAT_PLUGINS": "Plugins used without installing a package: comma-separated module names (importable, "
                     "on `PYTHONPATH`), each declaring its parts (methods, strategies, init kinds, photo matchers, "
                     "config variants) in a dict `ENTRY_POINTS = {group: {name: \"module:object\"}}`, the table an "
                     "installed package's entry points hold (`SPLAT_PLUGINS=my_plugin splat-train my-method --data ...`).",
    "SPLAT_INSTALLED_PLUGINS": "`on` (the default) or `off`: with `off`, the parts of installed packages other than "
                               "splat itself are not registered (`SPLAT_PLUGINS`'s modules still are): run without "
                               "a plugin you installed, as the documentation generator and the test suite do.",
    "SPLAT_METHODS": "No longer read: a set `SPLAT_METHODS` is refused with one line; name a module in "
                     "`SPLAT_PLUGINS` whose `ENTRY_POINTS` holds `{\"splat_framework.methods\": {NAME: \"module:spec\"}}`.",
}
"""Variable -> one line on what it does."""


_SIZE = re.compile(r"\s*(\d+(?:\.\d*)?|\.\d+)\s*([kKmMgGtT]?)(?:i?[bB])?\s*")
_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
_SWITCH = {"1": True, "true": True, "yes": True, "on": True, "0": False, "false": False, "no": False, "off": False}


def _bad(name: str, value: str, expected: str) -> DataError:
    return DataError(f"{name}={value!r}: {expected}")


def size_bytes(name: str, value: str) -> int:
    """``"123"``, ``"512K"``, ``"2G"``, ``"1.5GiB"`` -> bytes (binary units); one line naming ``name`` else."""
    m = _SIZE.fullmatch(value)
    if m is None:
        raise _bad(name, value, "not a size (examples: 800000000, 512M, 2G)")
    n = int(float(m.group(1)) * _UNITS[m.group(2).upper()])
    if n < 1:
        raise _bad(name, value, "a size of at least one byte")
    return n


MAX_THREADS = 4096
"""The largest SPLAT_THREADS: torch and OpenCV take a C int; more threads than this no machine has."""


def threads_setting(value: str | None) -> int | str:
    """``SPLAT_THREADS``: a whole number of threads >= 1, or "auto" (also when unset or empty) or "off"."""
    text = (value or "").strip().lower() or "auto"
    if text in ("auto", "off"):
        return text
    if text.isdigit() and 1 <= int(text) <= MAX_THREADS:
        return int(text)
    raise _bad("SPLAT_THREADS", value or "", f"expected auto, off or a whole number of threads (1 to {MAX_THREADS})")


def compile_setting(value: str | None) -> bool | None:
    """``SPLAT_COMPILE``: True / False from 1, true, yes, on / 0, false, no, off; None when unset or empty."""
    text = (value or "").strip().lower()
    if not text:
        return None
    if text not in _SWITCH:
        raise _bad("SPLAT_COMPILE", value or "", "expected 1 or 0 (also true/false, yes/no, on/off)")
    return _SWITCH[text]


def installed_plugins_setting(value: str | None) -> bool:
    """``SPLAT_INSTALLED_PLUGINS``: whether installed packages' parts register (on unless 0, false, no, off)."""
    text = (value or "").strip().lower()
    if not text:
        return True
    if text not in _SWITCH:
        raise _bad("SPLAT_INSTALLED_PLUGINS", value or "", "expected on or off (also 1/0, true/false, yes/no)")
    return _SWITCH[text]


def rasterizer_setting(value: str | None) -> str | None:
    """``SPLAT_RASTERIZER``: auto, native, triton or torch (any case); None when unset or empty."""
    text = (value or "").strip().lower()
    if not text:
        return None
    if text not in ("auto", "native", "triton", "torch"):
        raise _bad("SPLAT_RASTERIZER", value or "", "expected auto, native, triton or torch")
    return text


_MODULE = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")


def plugin_modules(value: str | None) -> list[str]:
    """``SPLAT_PLUGINS``: its module names (comma-separated; blanks ignored); one line naming the
    variable and the first entry that is not a dotted module name else (the module's table is
    checked where it is read, :func:`splat_framework.entry_points.declared_entry_points`)."""
    entries = [e.strip() for e in (value or "").split(",") if e.strip()]
    for entry in entries:
        if not _MODULE.fullmatch(entry):
            why = "is not a module name (my_plugin or pkg.parts; the module declares ENTRY_POINTS)"
            raise _bad("SPLAT_PLUGINS", value or "", f"entry {entry!r} {why}")
    return entries


def plugin_entry_error(module: str, why: str) -> DataError:
    """The one line refusing ``module`` of ``$SPLAT_PLUGINS``."""
    return _bad("SPLAT_PLUGINS", os.environ.get("SPLAT_PLUGINS", module), f"module {module!r} {why}")


def _replaced_methods_variable(value: str) -> None:
    if not value.strip():
        return
    raise _bad("SPLAT_METHODS", value, "no longer read; name a module in SPLAT_PLUGINS whose ENTRY_POINTS = "
               "{'splat_framework.methods': {'NAME': 'module:spec'}} (docs/extending.md)")


def _folder(name: str, value: str, must_exist: bool, writable: bool = False) -> None:
    for part in value.split(os.pathsep) if name == "SPLAT_CONFIG_PATH" else [value]:
        if not part:
            continue
        path = Path(part).expanduser()
        if path.exists() and not path.is_dir():
            raise _bad(name, value, f"{path} is not a folder")
        if must_exist and not path.is_dir():
            raise _bad(name, value, f"no folder {path}")
        if writable and not _can_make_folders_in(path):
            raise _bad(name, value, f"{path} is not a folder this user can create folders in")


def _can_make_folders_in(path: Path) -> bool:
    """Whether a folder can be made in ``path`` (or, where it does not exist yet, in its nearest
    existing parent), tried by making and removing an empty one: permissions alone do not tell
    (root may "write" /proc/self, where nothing can be made)."""
    import tempfile

    probe = path
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".splat-probe-", dir=probe))
    except OSError:
        return False
    return True


def check_environment(environ=None) -> None:
    """Check every ``SPLAT_*`` variable that is set (one :class:`~.errors.DataError` line naming the
    first invalid one and what it takes); the CLIs call it before anything else, and each reader
    parses its variable with the same function."""
    env = os.environ if environ is None else environ
    checks = {
        "SPLAT_THREADS": threads_setting,
        "SPLAT_COMPILE": compile_setting,
        "SPLAT_RASTERIZER": rasterizer_setting,
        "SPLAT_IMAGE_MEMORY_BUDGET": lambda v: v.strip() and size_bytes("SPLAT_IMAGE_MEMORY_BUDGET", v),
        "SPLAT_CACHE": lambda v: _folder("SPLAT_CACHE", v, must_exist=False, writable=True),
        "SPLAT_DATA": lambda v: _folder("SPLAT_DATA", v, must_exist=False),
        "SPLAT_CONFIG_PATH": lambda v: _folder("SPLAT_CONFIG_PATH", v, must_exist=True),
        "SPLAT_PLUGINS": plugin_modules,
        "SPLAT_INSTALLED_PLUGINS": installed_plugins_setting,
        "SPLAT_METHODS": _replaced_methods_variable,
    }
    for name, check in checks.items():
        if name in env:
            check(env[name])
