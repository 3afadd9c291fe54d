"""What a plugin's own tests need from the framework, as the framework's tests use it.

- :mod:`.cli`: run a ``splat-*`` command in a subprocess and check its exit, its one-line error
  and what it wrote (:func:`run_cli`), or stop a training run at a checkpoint (:func:`stop_training`);
- :mod:`.scenes`: the built-in tiny scenes, generated into a test's own cache (:func:`tiny_scene`);
- :mod:`.inprocess`: a scene and its data manager (:func:`scene_and_data`), a parsed command line
  (:func:`parse_train_args`), and the framework's pieces a test builds a model or a short run from
  (``Trainer``, ``MatchSet``, ``apply_overrides``, ``get_method``, ``export_ply``, ...: ``inprocess.EXPORTS``),
  resolved on first use;
- :mod:`.host_syncs`: the host syncs a step would make on CUDA, counted on any device
  (:func:`~.host_syncs.count_host_syncs`: a plugin's loss can be held to none).

A plugin's test, with the plugin installed (``pip install -e .``: its entry points registered)::

    from splat_framework.testing import cli_env, run_cli, tiny_scene

    def test_my_method_trains(tmp_path):
        data = tiny_scene(tmp_path / "cache")
        env = cli_env(SPLAT_CACHE=tmp_path / "cache")
        run_cli("train", "my-method", "--data", data, "--steps", "20", "--output", tmp_path / "run",
                "--no-progress", code=0, env=env)
"""

from typing import Any

from .cli import COMMANDS, CliResult, changed_paths, cli_env, message_lines, run_cli, snapshot, stop_training
from .inprocess import EXPORTS, parse_train_args, resolve, scene_and_data, skip_without_matcher_weights
from .scenes import TINY_SCENES, tiny_scene

__all__ = sorted(["COMMANDS", "TINY_SCENES", "CliResult", "changed_paths", "cli_env", "message_lines", "run_cli",
                  "snapshot", "stop_training", "tiny_scene", "parse_train_args", "scene_and_data",
                  "skip_without_matcher_weights", *EXPORTS])


def __getattr__(name: str) -> Any:
    if name not in EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = globals()[name] = resolve(name)
    return value


def __dir__() -> list[str]:
    return __all__
