"""``splat-train METHOD --data PATH [options]``: train a registered method.

Every registered method (entry points of group ``splat_framework.methods``) and
every config variant (package data found through the ``splat_framework.configs``
entry points, see ``splat_framework.registry``) is a subcommand. Heavy modules (torch,
cv2) are imported only after the arguments are parsed, so ``--help`` is fast.
"""

from __future__ import annotations

import sys
from pathlib import Path


def build_parser_type(methods=None, argv: list[str] = (), asked: str | None = None):
    """The subcommand type of every method's default config; the ``asked`` method's with the
    kinds that ``argv``'s ``--PATH.kind K`` flags choose (``cli.kinds.choose_kinds``)."""
    import tyro

    from ..registry import discover_methods
    from .kinds import choose_kinds

    methods = discover_methods() if methods is None else methods
    defaults = {name: spec.default_config() for name, spec in methods.items()}
    if asked in defaults:
        defaults[asked] = choose_kinds(defaults[asked], list(argv))
    descriptions = {name: spec.description for name, spec in methods.items()}
    return tyro.extras.subcommand_type_from_defaults(defaults, descriptions)


def _discover(asked: str | None):
    """The registered methods; a skipped variant (``$SPLAT_CONFIG_PATH``) warns in one line, except
    the one the command line asks for, which is a one-line DataError naming its file instead."""
    import warnings

    from ..errors import DataError
    from ..registry import VariantWarning, discover_methods, invalid_variant

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", VariantWarning)
        methods = discover_methods()
    if asked and asked not in methods and invalid_variant(asked):  # one line naming the file, not tyro's box
        raise DataError(invalid_variant(asked))
    for w in caught:
        warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    return methods


STRATEGY_KIND_FLAG = "--strategy.kind"


def _strategy_kind(argv: list[str]) -> tuple[list[str], str | None]:
    """``argv`` without ``--strategy.kind KIND`` (or ``=KIND``), and KIND (None when not given)."""
    rest, kind, it = [], None, iter(argv)
    for a in it:
        if a == STRATEGY_KIND_FLAG:
            kind = next(it, None)
            if kind is None:
                from .common import ArgumentsError

                raise ArgumentsError(f"{STRATEGY_KIND_FLAG} needs a strategy kind; see splat-train METHOD --help")
        elif a.startswith(STRATEGY_KIND_FLAG + "="):
            kind = a.partition("=")[2]
        else:
            rest.append(a)
    return rest, kind


def _with_strategy_kind(spec, kind: str):
    """``spec`` whose default strategy is ``kind``'s, with that kind's defaults (the ``--strategy.*``
    flags then edit it); a kind the method does not accept is a ValidationError naming the field."""
    from dataclasses import replace

    from ..config import deep_merge

    spec = replace(spec, overrides=deep_merge(spec.overrides, {"strategy": {"kind": kind}}))
    spec.default_config()  # refuses a kind the method does not accept, before tyro builds its parser
    return spec


VIEWS_FLAG = "--views"


def own_photos_views(config, argv: list[str]):
    """``config`` training on every photo (``views="all"``: up to ``FEW_PHOTOS`` all of them, else
    all but every 8th) when ``--data`` is one's own photos (a folder of them, a video, a scene
    folder splat-process wrote) and ``argv`` does not say ``--views``; the benchmarks' few-shot
    default stays for datasets, and ``--resume`` keeps the run's own views."""
    from ..data.photos import is_own_photos
    from ..data.resolve import locate_data
    from ..errors import DataError

    if any(a == VIEWS_FLAG or a.startswith(VIEWS_FLAG + "=") for a in argv):
        return config
    if config.resume and config.output is not None and (Path(config.output) / "config.json").is_file():
        from ..config import read_config_json

        try:
            saved = read_config_json(Path(config.output) / "config.json", trust_edits=True)[1].get("views")
        except DataError:  # the resume check says what is wrong with it
            return config
        return config.model_copy(update={"views": saved}) if saved is not None else config
    try:
        own = is_own_photos(locate_data(config.data))
    except DataError:  # said in one line once the run loads its data
        return config
    return config.model_copy(update={"views": "all"}) if own else config


def main(args: list[str] | None = None) -> dict:
    import tyro

    from .common import one_line_parse_errors

    argv, strategy_kind = _strategy_kind(sys.argv[1:] if args is None else args)
    asked = next((a for a in argv if not a.startswith("-")), None)
    methods = _discover(asked)
    if strategy_kind is not None and asked in methods:
        methods[asked] = _with_strategy_kind(methods[asked], strategy_kind)
    # tyro's errors and invalid values: one line (cli.common.run_cli), not tyro's box
    with one_line_parse_errors("splat-train", subcommands=methods):
        parser_type = build_parser_type(methods, argv, asked)
        config = tyro.cli(
            parser_type,
            args=argv,
            prog="splat-train",
            description="Train a Gaussian-splatting method. Run 'splat-train METHOD --help' for its options.",
        )
    config = own_photos_views(config, argv)
    from ..engine.trainer import train

    spec = methods[config.method]  # the one lookup of the run, handed down
    if not config.viewer:
        return train(config, spec=spec)
    from ..viewer.scene_viewer import ViewerCallback

    live = ViewerCallback(port=config.viewer_port, every=config.viewer_every, host=config.viewer_host)
    metrics = train(config, callbacks=[live], spec=spec)
    if live.viewer is not None:
        print(f"training done; the viewer stays at {live.viewer.url} (Ctrl-C to stop)", flush=True)
        live.viewer.serve_until_interrupted()
    return metrics


def entrypoint() -> None:
    from .common import run_cli

    run_cli(lambda: main(sys.argv[1:]))


if __name__ == "__main__":
    entrypoint()
