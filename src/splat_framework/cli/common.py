"""What every CLI shares: clean one-line errors and exit codes.

Exit codes: 0 success, 2 bad input or config, 1 internal error (or an
environment failure such as a full disk, reported in one line), 130
interrupted (after a checkpoint was written when training). A path that cannot
be what it must (a file where a folder goes, a path through a file) is bad
input: one line naming it, exit 2.

Invalid config values (pydantic validation, e.g. ``--model.sh-degree 9``) are
reported as one line naming the dotted field (``model.sh_degree``) before any
work starts, and so is anything else tyro rejects (``--views abc``, an unknown
method, a bad choice): wrap ``tyro.cli`` in :func:`one_line_parse_errors`.
SIGTERM outside the training loop is treated like Ctrl-C.
"""

from __future__ import annotations

import argparse
import atexit
import errno
import gc
import os
import re
import signal
import sys
import warnings
from contextlib import contextmanager
from typing import Callable, Iterator

from ..errors import did_you_mean  # noqa: F401  (the CLIs' messages name it from here)

EXIT_CODES: dict[int, str] = {
    0: "success",
    1: "the machine failed, not the input: a full disk, a read-only or unwritable output, a run that "
       "diverged through every checkpoint restore, a sweep with failed runs (one line says which)",
    2: "bad input: an option, a config value, a file or a path the command cannot use (one line naming it)",
    130: "interrupted (Ctrl-C or SIGTERM); a training run says whether a checkpoint was written",
}
"""Exit code -> what it means, for every ``splat-*`` command (the CLI reference lists them)."""

_ENV_ERRNOS = {
    errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EFBIG, errno.EMFILE,
}
"""OSErrors caused by the machine rather than by a bug: reported in one line, exit 1."""
_PATH_ERRNOS = {errno.ENOTDIR, errno.EISDIR, errno.ENAMETOOLONG, errno.ELOOP}
"""OSErrors caused by a path the user gave (a component is a file, a folder where a file goes,
a name too long, a symlink loop): reported in one line naming it, exit 2."""


def format_validation_error(e, prefix: str = "") -> str:
    """One line: ``field.path: message; other.field: message`` (the dotted path of the flag: the tag
    pydantic puts after a tagged union's field, ``model.init.triangulated.matching``, is left out)."""
    tags = _kind_tags()
    parts = []
    for err in e.errors():
        loc = ".".join(str(p) for i, p in enumerate(err["loc"]) if not (i and p in tags))
        loc = ".".join(x for x in (prefix, loc) if x) or "config"
        parts.append(f"{loc}: {err['msg']}")
    return "; ".join(parts)


def _kind_tags() -> set[str]:
    """The ``kind`` tags of every config class defined so far (members of tagged unions)."""
    import typing

    from ..config import SplatConfig

    tags, todo = set(), [SplatConfig]
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        field = cls.model_fields.get("kind")
        if field is not None:
            annotation = field.annotation
            while typing.get_origin(annotation) is typing.Annotated:
                annotation = typing.get_args(annotation)[0]
            tags.update(a for a in typing.get_args(annotation) if isinstance(a, str))
    return tags


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

    todo = [("", c) for c in (TrainConfig, *_subclasses(TrainConfig))]
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
                    # a field of a base class (the registered strategies) holds its subclasses
                    todo += [(f"{prefix}.{name}".lstrip("."), c) for c in (member, *_subclasses(member))]
    return ""


def _subclasses(cls: type) -> list[type]:
    """Every subclass of ``cls``, at any depth."""
    return [c for sub in cls.__subclasses__() for c in (sub, *_subclasses(sub))]


def parse_cli(f, *, prog: str, args: list[str] | None = None, field_prefix: str | None = None, subcommands=(),
              flags=(), **kwargs):
    """``tyro.cli(f)`` under :func:`one_line_parse_errors`: whatever tyro rejects is one line (exit 2).
    ``subcommands``: the names its first argument may take (methods), for an unknown one's message;
    ``flags``: the flags it takes (``cli.help_screen.flag_names``), for an unknown one's.

    ``field_prefix``: for a command whose config is not a training config (splat-match,
    splat-scene), the dotted path its fields' errors are named under ("" = the flag's own
    name: ``seed``, not ``model.matching.seed``); None leaves :func:`run_cli`'s naming."""
    import tyro

    from ..config import InvalidArguments
    from ..errors import DataError

    try:
        with one_line_parse_errors(prog, subcommands, flags):
            return tyro.cli(f, prog=prog, args=sys.argv[1:] if args is None else args, **kwargs)
    except InvalidArguments as e:
        if field_prefix is None:
            raise
        raise DataError(f"invalid config: {format_validation_error(e.error, field_prefix)}") from None


class OneLineArgumentParser(argparse.ArgumentParser):
    """An argparse parser whose errors (``--workers`` without a value, an unknown flag, a bad
    choice) are one line for :func:`run_cli` (an :class:`ArgumentsError`, exit 2), not usage + error."""

    def error(self, message: str):  # noqa: D102 - argparse's hook
        raise ArgumentsError(f"{message}; see {self.prog} --help")  # the form of tyro_error_line's


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings on the command line: ``warning: MESSAGE`` on one line (no source line)."""
    text = str(message).strip().splitlines()
    print(f"warning: {text[0] if text else category.__name__}", file=file or sys.stderr)


def _sigterm_as_interrupt(signum, frame):
    raise KeyboardInterrupt


def exit_without_collecting() -> None:
    """Let the process's exit skip the garbage collector: an interpreter with PyTorch loaded spends
    1-2 s (3-6 s after training, with the compiler loaded) at shutdown collecting objects that the
    process frees anyway; ``gc.freeze`` at exit (an atexit handler, so it runs after the command and
    before the interpreter's final collections) hides them from those collections (0.4-0.6 s; 2-core
    machine, load 3). Objects still die by their reference counts, open files are still closed, and
    the other atexit handlers still run. Registered once however often it is called."""
    atexit.unregister(gc.freeze)
    atexit.register(gc.freeze)


def _silence_stdout() -> None:
    """Point stdout at the null device, so the interpreter's last flush of a closed pipe says nothing."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # no file descriptor behind stdout (an embedding host)
        pass


def run_cli(main: Callable[[], object]) -> None:
    """Run ``main`` and turn expected failures into one-line messages and exit codes."""
    from pydantic import ValidationError

    from ..config import InvalidArguments
    from ..environment import check_environment
    from ..errors import CheckpointError, DataError

    warnings.showwarning = _one_line_warning
    exit_without_collecting()
    try:
        signal.signal(signal.SIGTERM, _sigterm_as_interrupt)
    except ValueError:  # not the main thread
        pass
    try:
        check_environment()
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
    except BrokenPipeError:  # the reader left (`splat-train --help | head`): stop quietly, as `cat` does
        _silence_stdout()
        sys.exit(141)
    except SystemExit:  # --help's exit: the buffered rest of the screen may meet a closed pipe too
        try:
            sys.stdout.flush()
        except BrokenPipeError:
            _silence_stdout()
        raise
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


class ArgumentsError(Exception):
    """The command line could not be parsed (tyro's error, as one line): exit code 2."""

    cli_exit_code = 2


_BOX = re.compile(r"[\u2500-\u257f]")
_RULE = re.compile(r"^[\s\u2500-\u257f-]*$")


def tyro_error_line(box: str, prog: str, subcommands=(), flags=()) -> str:
    """One line for the error box tyro prints on stderr (title, then its first section up to the
    next rule, lines rejoined; UTF-8 or ASCII boxes), e.g.
    ``--views: expected INT|{all}, got ['abc']; see splat-train --help``.

    ``subcommands``: the names the first positional argument may take (methods), so that an unknown
    one reads ``unknown method 'x' (did you mean 'y'?)``; ``flags``: the flags the command takes, so
    that an unknown one reads ``unrecognized arguments: --dta x (did you mean '--data'?)``."""
    lines = [ln for ln in box.splitlines() if ln.strip()]
    title = _BOX.sub("", lines[0]).strip() if lines else ""
    body: list[str] = []
    for ln in lines[1:]:
        if _RULE.match(ln):
            if body:
                break
            continue  # the rule under the title (ASCII boxes, when stdout is not UTF-8)
        body.append(_BOX.sub("", ln).strip())
    text = " ".join(" ".join(body).split())
    see = f"see {prog} --help"
    if text.startswith(("Unrecognized or misplaced options:", "Unrecognized options:")):
        tokens = re.findall(r"(\S+) \(applied to [^)]*\)", text) or text.split(":", 1)[1].strip().split(", ")
        if subcommands and tokens and not tokens[0].startswith("-") and tokens[0] not in subcommands:
            return f"unknown method '{tokens[0]}'{did_you_mean(tokens[0], subcommands)}; {prog} --help lists them"
        text = "unrecognized arguments: " + " ".join(tokens) + _closest_flags(tokens, flags)
    elif text.startswith("Error parsing "):  # "Value error": the flag, tyro's message, then every union member's
        text = text[len("Error parsing "):].split(" Got errors:")[0].rstrip(".")
        text = re.sub(r"no type matching (.*) could be instantiated from (.*)", r"expected \1, got \2", text)
    elif m := re.match(r"invalid choice '(.*)' for argument '(.*)'\. Expected one of \((.*)\)", text):
        choices = re.findall(r"'([^']*)'", m.group(3))
        return f"{m.group(2)}: {m.group(1)!r} is not one of {', '.join(choices)}{did_you_mean(m.group(1), choices)}"
    elif title and not text:
        text = title
    elif title == "Missing subcommand":
        text = f"missing a command: {text[0].lower()}{text[1:]}".rstrip(".")
    return f"{text.rstrip('.')}; {see}" if text else f"invalid arguments; {see}"


def _closest_flags(tokens: list[str], flags) -> str:
    """`` (did you mean '--data'?)`` for the unknown flags among ``tokens`` that are close to one of
    ``flags`` (``--dta``; several: ``'--data' for --dta, '--steps' for --stpes``), or ""."""
    close = {}
    for token in tokens:
        name = token.partition("=")[0]
        hint = did_you_mean(name, flags) if name.startswith("--") else ""
        if hint:
            close[name] = hint[len(" (did you mean "):-len("?)")]
    if len(close) <= 1:
        return "".join(f" (did you mean {flag}?)" for flag in close.values())
    return f" (did you mean {', '.join(f'{flag} for {name}' for name, flag in close.items())}?)"


@contextmanager
def one_line_parse_errors(prog: str, subcommands=(), flags=()) -> Iterator[None]:
    """Around ``tyro.cli(...)``: a command line tyro rejects raises :class:`ArgumentsError` with one
    line (``run_cli`` prints it and exits 2) instead of tyro's box (:func:`tyro_error_line`), and an
    invalid config value raises ``config.InvalidArguments`` naming its field (``config.cli_parsing``).
    ``--help`` (stdout, exit 0) is untouched; what else reaches stderr meanwhile is passed on.
    ``subcommands``: the names of the command's subcommands (methods), for an unknown one's message;
    ``flags``: the flags the command takes, for an unknown one's."""
    import io

    from ..config import cli_parsing

    captured, real = io.StringIO(), sys.stderr
    sys.stderr = captured
    try:
        with cli_parsing():
            yield
    except SystemExit as e:
        if e.code not in (0, None):
            raise ArgumentsError(tyro_error_line(captured.getvalue(), prog, subcommands, flags)) from None
        raise
    finally:
        sys.stderr = real
    real.write(captured.getvalue())
