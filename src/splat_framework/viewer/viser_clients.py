"""What the clients of a viser server may do: connect from this server's own page only, never
open a share tunnel, and never print a traceback into the user's terminal, whatever they send.

:func:`guard_clients` applies all three to a ``viser.ViserServer`` (relying on viser's
``_websock_server``, whose connect callbacks are awaited before any message flows to a client);
:func:`from_client` wraps a GUI callback. Malformed messages end as one DEBUG line of the
``splat_framework.viewer.viser_clients`` logger (shown only with debug logging on).
"""

from __future__ import annotations

import functools
import logging
import warnings

from .serving import client_allowed

__all__ = ["guard_clients", "from_client"]

log = logging.getLogger(__name__)


def guard_clients(server, host: str) -> None:
    """Guard the clients of ``server`` (a ``viser.ViserServer`` listening on ``host``)."""
    from viser import _messages

    # a client's "share" request would open a public tunnel to this server: not a client's to grant
    server._websock_server.unregister_handler(_messages.ShareUrlRequest)
    _quiet_client_errors(server)
    _refuse_foreign_pages(server, host)


class _ClientErrorsToDebug(logging.Filter):
    """Turns a record carrying an exception (the websockets server's "connection handler failed"
    after a malformed client message) into one DEBUG line: shown only when debug logging is on."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info:
            exc = record.exc_info[1]
            record.msg, record.args = f"{record.getMessage()}: {type(exc).__name__}: {exc}".replace("\n", " "), None
            record.exc_info = record.exc_text = None
            record.levelno, record.levelname = logging.DEBUG, "DEBUG"
        return True


_CLIENT_ERRORS = _ClientErrorsToDebug()


def _client_loop_error(loop, context: dict) -> None:
    """The viser event loop's exception handler: a failure in a task started by a client's message
    (a malformed one) is one DEBUG line, not asyncio's traceback."""
    exc = context.get("exception")
    log.debug("viewer client message dropped: %s%s", context.get("message", ""), f": {type(exc).__name__}: {exc}" if exc else "")


def _quiet_client_errors(server) -> None:
    """Route what malformed client messages raise to one DEBUG line: viser hands a message it
    cannot decode to the websockets server, which logs the handler's traceback at ERROR
    (``websockets.server``); a message that decodes but fails in a handler task reaches the
    event loop's exception handler; one whose fields have the wrong types also brings viser's
    warning (ignored). GUI callbacks are wrapped by :func:`from_client`."""
    logging.getLogger("websockets.server").addFilter(_CLIENT_ERRORS)  # the same filter object: added once
    # viser's warning when a client's field has the wrong type (the message is then dropped or fails as above)
    warnings.filterwarnings("ignore", message=r"\[viser\] .* does not match annotation", category=UserWarning)
    loop = getattr(server, "_event_loop", None)
    if loop is not None:
        loop.set_exception_handler(_client_loop_error)


def _refuse_foreign_pages(server, host: str) -> None:
    """Close, before anything is sent to it, a websocket opened by a page of another web site or
    under a non-loopback name on a loopback server (:func:`~splat_framework.viewer.serving.client_allowed`).
    Runs first among viser's connect callbacks, which are awaited before a client's messages flow."""
    websock = server._websock_server

    async def check(client) -> None:
        connection = websock._live_connections.get(client.client_id)
        if connection is None:
            return
        headers = connection.request.headers
        if not client_allowed(host, headers.get("Host"), headers.get("Origin")):
            log.debug("viewer refused a client: Host %r, Origin %r", headers.get("Host"), headers.get("Origin"))
            await connection.close(1008, "this page may not use the viewer")

    websock._client_connect_cb.insert(0, check)


def from_client(callback):
    """A GUI callback run on a client's message: a failure is one DEBUG line (viser's thread pool
    would print its traceback into the terminal)."""

    @functools.wraps(callback)
    def run(event) -> None:
        try:
            callback(event)
        except Exception as e:  # noqa: BLE001 - whatever a client's message caused
            log.debug("viewer callback failed on a client's message: %s: %s", type(e).__name__, e)

    return run
