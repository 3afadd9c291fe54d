"""How renders run: one frozen value, made once at the edge and passed down to ``rasterize``.

The commands make it from the run's config and the environment (:meth:`RenderSettings.from_config`);
a model holds it (``model.render_settings``) and hands it to every render, so a viewer and a trainer
in one process may render with different kernels. Nothing under ``render/`` reads the environment
per render.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..environment import compile_setting, rasterizer_setting
from ..errors import DataError

RASTERIZERS = ("auto", "native", "triton", "torch")


@dataclass(frozen=True)
class RenderSettings:
    """The render choices of a run (the default: the eager torch kernels, no cache folder).

    Attributes:
        rasterizer: which kernels render: "auto", "native", "triton" or "torch" (:mod:`.backend`).
        compile: compiled kernels (native C++ on a CPU, Triton on CUDA, else torch.compile), or
            the eager torch kernels where ``rasterizer`` is "auto".
        cache_dir: where built kernels and the backends' verdicts are kept across processes
            (None: built per process, each backend proved per process).
    """

    rasterizer: str = "auto"
    compile: bool = False
    cache_dir: Path | None = None

    def __post_init__(self) -> None:
        if self.rasterizer not in RASTERIZERS:
            raise DataError(f"--rasterizer {self.rasterizer!r}: expected one of {', '.join(RASTERIZERS)}")

    @classmethod
    def from_config(cls, config, env: Mapping[str, str] = os.environ, cache_dir: Path | None = None) -> RenderSettings:
        """The settings of a run with ``config`` (``.compile``, ``.rasterizer``): ``SPLAT_COMPILE``
        wins over ``config.compile``; ``config.rasterizer`` other than auto wins over
        ``SPLAT_RASTERIZER``. ``cache_dir``: None takes the user's cache folder. Raises DataError
        (one line) on a malformed variable."""
        compile_env = compile_setting(env.get("SPLAT_COMPILE"))
        rasterizer = config.rasterizer
        if rasterizer == "auto":
            rasterizer = rasterizer_setting(env.get("SPLAT_RASTERIZER")) or "auto"
        if cache_dir is None:
            from ..data.cache_dir import user_cache_dir

            cache_dir = user_cache_dir()
        return cls(rasterizer=rasterizer, compile=bool(config.compile) if compile_env is None else compile_env,
                   cache_dir=Path(cache_dir))

    def replace(self, **changes) -> RenderSettings:
        """A copy with ``changes`` (e.g. ``rasterizer="torch"`` for a backend refused here)."""
        from dataclasses import replace

        return replace(self, **changes)


__all__ = ["RASTERIZERS", "RenderSettings"]
