"""``splat-train METHOD --data PATH [options]``: train a registered method.

Every registered method (entry points of group ``splat_framework.methods``) and
every config variant (package data found through the ``splat_framework.configs``
entry points, see ``splat_framework.registry``) is a subcommand. Heavy modules (torch,
cv2) are imported only after the arguments are parsed, so ``--help`` is fast.
"""

from __future__ import annotations

import sys


def build_parser_type(methods=None):
    import tyro

    from ..registry import discover_methods

    methods = discover_methods() if methods is None else methods
    defaults = {name: spec.default_config() for name, spec in methods.items()}
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


def main(args: list[str] | None = None) -> dict:
    import tyro

    from .common import one_line_parse_errors

    argv = sys.argv[1:] if args is None else args
    asked = next((a for a in argv if not a.startswith("-")), None)
    methods = _discover(asked)
    parser_type = build_parser_type(methods)
    # tyro's errors and invalid values: one line (cli.common.run_cli), not tyro's box
    with one_line_parse_errors("splat-train", subcommands=methods):
        config = tyro.cli(
            parser_type,
            args=argv,
            prog="splat-train",
            description="Train a Gaussian-splatting method. Run 'splat-train METHOD --help' for its options.",
        )
    from ..trainer import train

    spec = methods[config.method]  # the one lookup of the run, handed down
    if not config.viewer:
        return train(config, spec=spec)
    from ..viewer import ViewerCallback

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
