"""Where a server listens, as config values (torch-free): the default address :data:`LOOPBACK` and
the :data:`Port` type, checked while arguments are parsed. The listening itself is
:mod:`splat_framework.viewer.serving`."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field
from tyro.constructors import PrimitiveConstructorSpec

LOOPBACK = "127.0.0.1"
"""The default address of every server: this machine only."""
MAX_PORT = 65535
"""The largest TCP port."""


class InvalidAddress(Exception):
    """A port or host a server cannot listen on (one-line message; the CLIs exit 2).

    Deliberately not a ValueError: the argument parser (tyro) turns ValueErrors raised
    while parsing into its own multi-line box; this one reaches ``cli.common.run_cli``."""

    cli_exit_code = 2


def check_port(port: object) -> int:
    """``port`` as an int in 0..65535, or :class:`InvalidAddress` naming it."""
    try:
        value = int(str(port).strip(), 10) if not isinstance(port, int) else port
    except ValueError:
        value = None
    if isinstance(port, bool) or value is None or not 0 <= value <= MAX_PORT:
        raise InvalidAddress(f"invalid port {port!r}: a TCP port is an integer 0..{MAX_PORT} (0 = any free port)")
    return value


Port = Annotated[
    int,
    PrimitiveConstructorSpec(
        nargs=1, metavar="PORT", instance_from_str=lambda args: check_port(args[0]),
        is_instance=lambda x: isinstance(x, int) and not isinstance(x, bool), str_from_instance=lambda x: [str(x)],
    ),
    Field(ge=0, le=MAX_PORT),
]
"""A TCP port, 0..65535 (0 = any free port): checked by pydantic in a config and, on the command
line, while arguments are parsed (one line and exit 2 for ``-1``, ``70000`` or ``abc``)."""
