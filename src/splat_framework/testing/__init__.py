"""What a plugin's own tests need from the framework, as the framework's tests use it.

- :mod:`.cli`: run a ``splat-*`` command in a subprocess and check its exit, its one-line error
  and what it wrote (:func:`run_cli`), or stop a training run at a checkpoint (:func:`stop_training`);
- :mod:`.scenes`: the built-in tiny scenes, generated into a test's own cache (:func:`tiny_scene`).

A plugin's test, with the plugin installed (``pip install -e .``: its entry points registered)::

    from splat_framework.testing import cli_env, run_cli, tiny_scene

    def test_my_method_trains(tmp_path):
        data = tiny_scene(tmp_path / "cache")
        env = cli_env(SPLAT_CACHE=tmp_path / "cache")
        run_cli("train", "my-method", "--data", data, "--steps", "20", "--output", tmp_path / "run",
                "--no-progress", code=0, env=env)
"""

from .cli import COMMANDS, CliResult, changed_paths, cli_env, message_lines, run_cli, snapshot, stop_training
from .scenes import TINY_SCENES, tiny_scene

__all__ = ["COMMANDS", "TINY_SCENES", "CliResult", "changed_paths", "cli_env", "message_lines", "run_cli", "snapshot",
           "stop_training", "tiny_scene"]
