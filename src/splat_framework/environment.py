"""Every ``SPLAT_*`` environment variable the project reads, with what it does (torch-free).

The one list: the CLI reference (``docs/cli.md``) is generated from it, and a test fails when
code under ``src/`` names a ``SPLAT_*`` variable that is not here.
"""

from __future__ import annotations

VARIABLES: dict[str, str] = {
    "SPLAT_DATA": "Folder under which a relative `--data` name that does not exist is looked up "
                  "(`splat-train 3dgs --data llff/fern` with `SPLAT_DATA=../shared/data`).",
    "SPLAT_CACHE": "Where generated scenes, match caches and compiled kernels go (default `~/.cache/splat`); "
                   "the native rasterizer kernels are built under `$SPLAT_CACHE/native`, torch.compile's under "
                   "`$SPLAT_CACHE/inductor`.",
    "SPLAT_COMPILE": "`0` or `1`: compile the rasterizer's kernels (native C++ on a CPU, torch.compile elsewhere) "
                     "or run them eagerly, whatever `--compile` says.",
    "SPLAT_THREADS": "CPU threads of the whole process (torch and OpenCV, every phase): `auto` (the default) "
                     "follows the cores other processes leave free, re-read every second; an integer pins the "
                     "count; `off` leaves it alone.",
    "SPLAT_IMAGE_MEMORY_BUDGET": "Bytes of decoded training images kept in memory (suffixes K, M, G; unset: no "
                                "limit); images beyond it are decoded again when needed.",
    "SPLAT_CONFIG_PATH": "`:`-separated folders of TOML config variants, searched before the installed "
                         "packages' variants.",
}
"""Variable -> one line on what it does."""
