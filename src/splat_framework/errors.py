"""Expected failures, each with a one-line message (torch-free, for the CLIs)."""


class DataError(ValueError):
    """Bad input data or options. The message is one line naming the file and the problem.

    The CLIs print it without a traceback and exit with code 2.
    """


class PluginError(DataError):
    """A plugin's part cannot be used: a ``"module:Name"`` it declares does not import or is not what
    its entry must name (:class:`~splat_framework.entry_points.Ref`). The message is one line naming
    the plugin, the entry and the problem; the CLIs exit with code 2."""

    cli_exit_code = 2


class CheckpointError(RuntimeError):
    """A checkpoint file is missing, truncated or corrupt (one-line message)."""


def did_you_mean(word: str, choices) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``choices`` to ``word`` (difflib, letter case aside:
    ``3DGS`` finds ``3dgs``), or ""."""
    import difflib

    by_folded = {}
    for c in map(str, choices):
        by_folded.setdefault(c.casefold(), c)
    close = difflib.get_close_matches(word.casefold(), list(by_folded), n=1, cutoff=0.6)
    return f" (did you mean '{by_folded[close[0]]}'?)" if close else ""
