"""What every CLI shares: clean one-line errors and exit codes.

Exit codes: 0 success, 2 bad input or config, 1 internal error (or an
environment failure such as a full disk, reported in one line), 130
interrupted (after a checkpoint was written when training). A path that cannot
be what it must (a file where a folder goes, a path through a file) is bad
input: one line naming it, exit 2.

Invalid config values (pydantic validation, e.g. ``--model.sh-degree 9``) are
reported as one line naming the dotted field (``model.sh_degree``) before any
work starts. SIGTERM outside the training loop is treated like Ctrl-C.
"""

from __future__ import annotations

import argparse
import errno
import signal
import sys
import warnings
from typing import Callable

_ENV_ERRNOS = {
    errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EFBIG, errno.EMFILE,
}
"""OSErrors caused by the machine rather than by a bug: reported in one line, exit 1."""
_PATH_ERRNOS = {errno.ENOTDIR, errno.EISDIR, errno.ENAMETOOLONG, errno.ELOOP}
"""OSErrors caused by a path the user gave (a component is a file, a folder where a file goes,
a name too long, a symlink loop): reported in one line naming it, exit 2."""


def format_validation_error(e, prefix: str = "") -> str:
    """One line: ``field.path: message; other.field: message``."""
    parts = []
    for err in e.errors():
        loc = ".".join(str(p) for p in err["loc"])
        loc = ".".join(x for x in (prefix, loc) if x) or "config"
        parts.append(f"{loc}: {err['msg']}")
    return "; ".join(parts)


def config_path(config_cls: type) -> str:
    """Dotted field path at which configs of exactly ``config_cls`` sit in a method's config
    (``GaussianModelConfig`` -> ``model``, ``MatchConfig`` -> ``model.matching``; "" for a
    ``TrainConfig``), found by walking the fields of every ``TrainConfig`` subclass."""
    import typing

    from ..config import SplatConfig, TrainConfig

    def members(annotation) -> tuple:
        args = typing.get_args(annotation)
        if typing.get_origin(annotation) is typing.Annotated:
            return members(args[0])
        return tuple(a for m in args for a in members(m)) if args else (annotation,)

    todo, subclasses = [], [TrainConfig]
    while subclasses:
        cls = subclasses.pop()
        todo.append(("", cls))
        subclasses.extend(cls.__subclasses__())
    seen = set()
    while todo:
        prefix, cls = todo.pop(0)
        if cls is config_cls:
            return prefix
        if (prefix, cls) in seen:
            continue
        seen.add((prefix, cls))
        for name, field in cls.model_fields.items():
            for member in members(field.annotation):
                if isinstance(member, type) and issubclass(member, SplatConfig):
                    todo.append((f"{prefix}.{name}".lstrip("."), member))
    return ""


def tyro_error_line(box: str) -> str:
    """tyro's error box (stderr of a failed parse) as one line: its first paragraph.

    The box's borders go, the text before its first rule or blank line stays (after the
    box's title when the text does not say it), with indented detail lines (argument
    help) dropped and wrapped lines joined:
    ``Error parsing --max-lines: invalid literal for int() with base 10: 'abc'``."""
    rows, title = [], ""
    for raw in box.splitlines():
        line = raw.strip()
        if line.startswith(("╭", "╰")):
            title = title or line.strip("╭╮╰╯─ ")
            continue
        line = line.strip("│").rstrip()
        text = line.strip()
        if set(text) <= {"─", " "} and text or (not text and rows):
            if rows:
                break
            continue
        if text and len(line) - len(line.lstrip()) <= 5:
            rows.append(text)
    text = " ".join(rows) or "invalid arguments (see --help)"
    if title and title.lower() not in text.lower() and not text.startswith("Error parsing"):
        text = f"{title.lower()}: {text}"  # "missing subcommand: Expected one of {images, video}."
    return text


def parse_cli(f, *, prog: str, args: list[str] | None = None, field_prefix: str | None = None, **kwargs):
    """``tyro.cli(f)`` whose failures are one line for :func:`run_cli` (exit 2), not a box.

    A value tyro cannot parse (``--max-lines abc``), an unknown flag or a missing one
    raises :class:`DataError` with tyro's message; a config value pydantic rejects
    raises :class:`~splat_framework.config.InvalidArguments` naming the field, with
    ``field_prefix`` (when given) in place of the path the field has in a training
    config. ``--help`` prints as usual."""
    import contextlib
    import io

    import tyro

    from ..config import InvalidArguments, cli_parsing
    from ..errors import DataError

    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured), cli_parsing():
            parsed = tyro.cli(f, prog=prog, args=sys.argv[1:] if args is None else args, **kwargs)
        sys.stderr.write(captured.getvalue())  # warnings while parsing
        return parsed
    except SystemExit as e:
        if e.code in (0, None):
            sys.stderr.write(captured.getvalue())
            raise
        raise DataError(tyro_error_line(captured.getvalue())) from None
    except InvalidArguments as e:
        if field_prefix is None:
            raise
        raise DataError(f"invalid config: {format_validation_error(e.error, field_prefix)}") from None


class OneLineArgumentParser(argparse.ArgumentParser):
    """An argparse parser whose errors (``--workers`` without a value, an unknown flag, a bad
    choice) are one line for :func:`run_cli` (a :class:`DataError`, exit 2), not usage + error."""

    def error(self, message: str):  # noqa: D102 - argparse's hook
        from ..errors import DataError

        raise DataError(f"{self.prog}: {message} (see --help)")


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings on the command line: ``warning: MESSAGE`` on one line (no source line)."""
    text = str(message).strip().splitlines()
    print(f"warning: {text[0] if text else category.__name__}", file=file or sys.stderr)


def _sigterm_as_interrupt(signum, frame):
    raise KeyboardInterrupt


def run_cli(main: Callable[[], object]) -> None:
    """Run ``main`` and turn expected failures into one-line messages and exit codes."""
    from pydantic import ValidationError

    from ..config import InvalidArguments
    from ..errors import CheckpointError, DataError

    warnings.showwarning = _one_line_warning
    try:
        signal.signal(signal.SIGTERM, _sigterm_as_interrupt)
    except ValueError:  # not the main thread
        pass
    try:
        main()
    except InvalidArguments as e:
        print(f"error: invalid config: {format_validation_error(e.error, config_path(e.config_cls))}", file=sys.stderr)
        sys.exit(2)
    except (DataError, CheckpointError) as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(getattr(type(e), "cli_exit_code", 2))
    except ValidationError as e:
        print(f"error: invalid config: {format_validation_error(e)}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        sys.exit(130)
    except OSError as e:
        code = getattr(type(e), "cli_exit_code", None)
        if code is not None:  # an OSError subclass that declares its own one-line message
            print(f"error: {e}", file=sys.stderr)
            sys.exit(code)
        if e.errno not in _ENV_ERRNOS | _PATH_ERRNOS:
            raise
        where = f"{e.filename}: " if e.filename else ""
        print(f"error: {where}{e.strerror or e}", file=sys.stderr)
        sys.exit(2 if e.errno in _PATH_ERRNOS else 1)
    except Exception as e:
        code = getattr(type(e), "cli_exit_code", None)
        if code is None:
            raise
        print(f"{getattr(type(e), 'cli_prefix', 'error')}: {e}", file=sys.stderr)
        sys.exit(code)
