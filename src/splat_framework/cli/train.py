"""``splat-train METHOD --data PATH [options]``: train a registered method.

Every registered method (entry points of group ``splat_framework.methods``) and
every config variant (package data found through the ``splat_framework.configs``
entry points, see ``splat_framework.registry``) is a subcommand. Heavy modules (torch,
cv2) are imported only after the arguments are parsed, so ``--help`` is fast.
"""

from __future__ import annotations

import sys


def build_parser_type():
    import tyro

    from ..registry import discover_methods

    methods = discover_methods()
    defaults = {name: spec.default_config() for name, spec in methods.items()}
    descriptions = {name: spec.description for name, spec in methods.items()}
    return tyro.extras.subcommand_type_from_defaults(defaults, descriptions)


def main(args: list[str] | None = None) -> dict:
    import tyro

    from ..config import cli_parsing
    from ..errors import DataError
    from ..registry import invalid_variant

    parser_type = build_parser_type()
    argv = sys.argv[1:] if args is None else args
    asked = next((a for a in argv if not a.startswith("-")), None)
    if asked and invalid_variant(asked):  # one line naming the file, not tyro's "invalid choice"
        raise DataError(invalid_variant(asked))
    with cli_parsing():  # an invalid value: one line naming its field (cli.common.run_cli), not tyro's box
        config = tyro.cli(
            parser_type,
            args=args,
            prog="splat-train",
            description="Train a Gaussian-splatting method. Run 'splat-train METHOD --help' for its options.",
        )
    from ..trainer import train

    if not config.viewer:
        return train(config)
    from ..viewer import ViewerCallback

    live = ViewerCallback(port=config.viewer_port, every=config.viewer_every, host=config.viewer_host)
    metrics = train(config, callbacks=[live])
    if live.viewer is not None:
        print(f"training done; the viewer stays at {live.viewer.url} (Ctrl-C to stop)", flush=True)
        live.viewer.serve_until_interrupted()
    return metrics


def entrypoint() -> None:
    from .common import run_cli

    run_cli(lambda: main(sys.argv[1:]))


if __name__ == "__main__":
    entrypoint()
