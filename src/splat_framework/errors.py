"""Expected failures, each with a one-line message (torch-free, for the CLIs)."""


class DataError(ValueError):
    """Bad input data or options. The message is one line naming the file and the problem.

    The CLIs print it without a traceback and exit with code 2.
    """


class CheckpointError(RuntimeError):
    """A checkpoint file is missing, truncated or corrupt (one-line message)."""
