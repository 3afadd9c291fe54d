"""The CLI harness of this repository's tests: :mod:`splat_framework.testing`'s, which plugin authors'
tests use too (importable from every test folder, ``pythonpath = ["tests"]``)::

    from cli_harness import run_cli
    run_cli("export", run, "--out", target, code=2, match="exists", watch=[tmp_path])
"""

from splat_framework.testing import CliResult, changed_paths, cli_env, message_lines, run_cli, snapshot, stop_training

__all__ = ["CliResult", "changed_paths", "cli_env", "message_lines", "run_cli", "snapshot", "stop_training"]
