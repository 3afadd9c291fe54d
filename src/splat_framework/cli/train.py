"""``splat-train METHOD --data PATH [options]``: train a registered method;
``splat-train --load-config RUN/config.json [options]``: train a saved experiment again, into a new
folder, with the options given changed (the method comes from the file, run options do not).
``splat-train METHOD --data PATH [options] --resume``: continue the run that command started and
that did not finish (``engine.run_folder.resume_unfinished``); a stop prints the exact command that
continues it (``engine.run_folder.continue_command``).

Every registered method (entry points of group ``splat_framework.methods``) and
every config variant (package data found through the ``splat_framework.configs``
entry points, see ``splat_framework.registry``) is a subcommand. Heavy modules (torch,
cv2) are imported only after the arguments are parsed, so ``--help`` is fast.
"""

from __future__ import annotations

import sys


def build_parser_type(methods=None, argv: list[str] = (), asked: str | None = None, loaded=None,
                      help_group: str | None = None):
    """The subcommand type of every method's default config; the ``asked`` method's (``loaded``, a
    saved run's config, when given) with the kinds that ``argv``'s ``--PATH.kind K`` flags choose
    (``cli.kinds.choose_kinds``). ``help_group``: the help screen asked for (``cli.help_screen``;
    "" the main one), which the asked method's config then shows, only to print it."""
    import tyro

    from ..registry import discover_methods
    from .help_screen import chosen_kinds, help_view
    from .kinds import choose_kinds

    methods = discover_methods() if methods is None else methods
    defaults = {name: spec.default_config() for name, spec in methods.items()}
    descriptions = {name: spec.description for name, spec in methods.items()}
    if loaded is not None:
        defaults[asked] = loaded
    if asked in defaults:
        defaults[asked] = choose_kinds(defaults[asked], list(argv))
        if help_group is not None:
            defaults[asked], line = help_view(defaults[asked], help_group, f"splat-train {asked}", chosen_kinds(list(argv)))
            descriptions[asked] = f"{descriptions[asked]}\n\n{line}" if line else descriptions[asked]
    return tyro.extras.subcommand_type_from_defaults(defaults, descriptions)


def _discover(asked: str | None):
    """The registered methods; a skipped variant (``$SPLAT_CONFIG_PATH``) warns in one line, except
    the one the command line asks for, which is a one-line DataError naming its file instead."""
    import warnings

    from ..errors import DataError
    from ..registry import VariantWarning, discover_methods, left_out

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", VariantWarning)
        methods = discover_methods()
    if asked and asked not in methods and left_out(asked):  # one line naming the file or plugin, not tyro's box
        raise DataError(left_out(asked))
    for w in caught:
        warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    return methods


LOAD_CONFIG_FLAG = "--load-config"


def _load_config_flag(argv: list[str]) -> tuple[list[str], str | None]:
    """``argv`` without ``--load-config PATH`` (or ``=PATH``), and PATH (None when not given)."""
    rest, path, it = [], None, iter(argv)
    for a in it:
        if a == LOAD_CONFIG_FLAG:
            path = next(it, None)
            if path is None:
                from .common import ArgumentsError

                raise ArgumentsError(f"{LOAD_CONFIG_FLAG} needs a run's config.json; see splat-train --help")
        elif a.startswith(LOAD_CONFIG_FLAG + "="):
            path = a.partition("=")[2]
        else:
            rest.append(a)
    return rest, path


def load_saved_experiment(path: str, methods: dict, trust_edits: bool = False):
    """(method name, config) of the experiment a run's ``config.json`` at ``path`` saved, for a new run:
    the saved config in today's layout, its run options (output folder, resume, device, ...) the
    method's defaults (:func:`~splat_framework.config.run_options`). A missing, unreadable or foreign
    file is a one-line DataError, and so is an edited or unsigned one unless ``trust_edits`` (the
    command line's ``--trust-edited-config``)."""
    from pathlib import Path

    from pydantic import ValidationError

    from ..config import read_config_json, run_options, upgrade_saved_config
    from ..errors import DataError
    from .common import did_you_mean

    file = Path(path)
    if not file.is_file():
        what = "not a regular file" if file.exists() else "no such file"
        raise DataError(f"{file}: {what} (--load-config takes a run's config.json)")
    try:
        method, raw, version = read_config_json(file, trust_edits=trust_edits)
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        if isinstance(e, DataError):
            raise
        raise DataError(f"{file}: not a run's config.json ({type(e).__name__})") from None
    if not isinstance(method, str) or method not in methods:
        raise DataError(f"{file}: method {method!r} is not registered{did_you_mean(str(method), methods)}")
    defaults = methods[method].default_config()
    try:
        saved = type(defaults).model_validate(upgrade_saved_config(raw, version, defaults))
    except ValidationError as e:
        from .common import format_validation_error

        raise DataError(f"{file}: not a {method} config ({format_validation_error(e)})") from None
    except (ValueError, TypeError, RecursionError) as e:  # an edited file the upgrades cannot read
        raise DataError(f"{file}: not a {method} config ({type(e).__name__}: {str(e)[:200]})") from None
    return method, saved.model_copy(update={name: getattr(defaults, name) for name in run_options(type(defaults))})


TRUST_FLAG = "--trust-edited-config"


def _trusts_edits(argv: list[str]) -> bool:
    """Whether ``argv`` says ``--trust-edited-config`` (the last of it and ``--no-trust-edited-config``
    wins, as the parser will read it): ``--load-config`` reads its file before the parser runs."""
    said = [a for a in argv if a in (TRUST_FLAG, "--no-" + TRUST_FLAG[2:])]
    return bool(said) and said[-1] == TRUST_FLAG


def check_data_before_loading(data: str | None) -> None:
    """A ``--data`` that names nothing (a folder, a built-in scene ``synthetic/NAME``) is the same
    one-line DataError as the run's own check (``data.resolve.check_data``), found before PyTorch
    loads: at once, not after 3-6 s of ``starting``. None (no ``--data`` given): nothing to check."""
    from ..data.resolve import check_data

    if data is not None:
        check_data(data)


def method_named(argv: list[str], asked: str | None, methods) -> tuple[list[str], str | None]:
    """(``argv``, ``asked``) with the method named in another letter case spelled as registered
    (``3DGS``: ``3dgs``). A first word that names no method is an ArgumentsError with the closest
    name, said before any config is built; a later word is left to the parser."""
    from .common import ArgumentsError, did_you_mean

    if asked is None or asked in methods:
        return argv, asked
    same = [name for name in methods if name.casefold() == asked.casefold()]
    if len(same) == 1:
        i = argv.index(asked)
        return [*argv[:i], same[0], *argv[i + 1:]], same[0]
    if argv[0] == asked:
        raise ArgumentsError(f"unknown method '{asked}'{did_you_mean(asked, methods)}; splat-train --help lists them")
    return argv, asked


TRAIN_DESCRIPTION = (
    "Train a Gaussian-splatting method. Run 'splat-train METHOD --help' for its options; "
    f"'splat-train {LOAD_CONFIG_FLAG} RUN/config.json [options]' re-runs a saved experiment into a new folder."
)


def main(args: list[str] | None = None) -> dict:
    from .common import ArgumentsError, parse_cli
    from .help_screen import flag_names
    from .help_screen import help_group as help_group_of
    from .kinds import flag_value

    given = list(sys.argv[1:] if args is None else args)  # as typed: a stop names the command that continues
    argv, load = _load_config_flag(given)
    if load is None:
        asked = next((a for a in argv if not a.startswith("-")), None)
    else:  # the method, if named at all, comes first (a later word is a flag's value)
        asked = argv[0] if argv and not argv[0].startswith("-") else None
    check_data_before_loading(flag_value(argv, "--data"))  # before the methods load: at once
    methods = _discover(asked)
    if load is None:
        argv, asked = method_named(argv, asked, methods)
    loaded = None
    if load is not None:
        method, loaded = load_saved_experiment(load, methods, trust_edits=_trusts_edits(argv))
        if asked not in (None, method):
            raise ArgumentsError(f"{LOAD_CONFIG_FLAG} {load} trains its own method {method!r}; leave out {asked!r}")
        if asked is None:
            argv, asked = [method, *argv], method
    if asked is None and load is None and any(a in ("-h", "--help") for a in argv):  # the methods, grouped
        from .help_screen import methods_screen

        sys.stdout.write(methods_screen(methods, TRAIN_DESCRIPTION))
        raise SystemExit(0)
    # tyro's errors and invalid values: one line (cli.common.run_cli), not tyro's box
    argv, help_group = help_group_of(argv, asked)
    # the named method's parser alone: tyro's search for a mistyped flag's neighbours visits every
    # parser it holds (3.3 s for 28 methods, 0.2 s for one)
    named = {asked: methods[asked]} if argv and argv[0] == asked and asked in methods else methods
    parser_type = build_parser_type(named, argv, asked, loaded, help_group)
    config = parse_cli(
        parser_type,
        prog="splat-train",
        args=argv,
        subcommands=methods,
        flags=flag_names(loaded or methods[asked].default_config(), argv) if named is not methods else (),
        description=TRAIN_DESCRIPTION,
    )
    from ..console import show_progress, starting

    check_data_before_loading(config.data)
    show_progress(config.progress)
    spec = methods[config.method]  # the one lookup of the run, handed down
    with starting():
        from ..engine.parts import resolve_parts

        # every plugin part imported and checked: one line before any data loads, and before the
        # compiler, which every run's Adam needs and a refusal does not (docs/decisions.md)
        resolve_parts(spec, config)
        import torch._dynamo  # noqa: F401

        from ..engine.run_folder import resume_unfinished
        from ..engine.trainer import train

    if config.resume and config.output is None and not config.overwrite:  # the run this command started
        config = resume_unfinished(config)
    if not config.viewer:
        return train(config, spec=spec, command=given, defaults=loaded)
    from ..viewer.scene_viewer import ViewerCallback

    live = ViewerCallback(port=config.viewer_port, every=config.viewer_every, host=config.viewer_host)
    metrics = train(config, callbacks=[live], spec=spec, command=given, defaults=loaded)
    if live.viewer is not None:
        print(f"training done; the viewer stays at {live.viewer.url} (Ctrl-C to stop)", flush=True)
        live.viewer.serve_until_interrupted()
    return metrics


def entrypoint() -> None:
    from .common import run_cli

    run_cli(lambda: main(sys.argv[1:]))


if __name__ == "__main__":
    entrypoint()
