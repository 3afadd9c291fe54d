"""What the clients of a viser server may do: reach it from this server's own page only, never
open a share tunnel, and never print a traceback into the user's terminal, whatever they send.

:func:`start_checked` starts a ``viser.ViserServer`` whose every HTTP request (the page, its
assets) and websocket handshake is checked before anything is served: one that
:func:`~splat_framework.viewer.serving.client_allowed` refuses (a page of another web site, by its
``Origin``; a DNS-rebinding name, by its ``Host``) gets 403 and nothing else, so the websocket
never opens. Viser gives no hook for this (its client-connect callbacks run after the handshake's
101, and plain HTTP never reaches them): the check is added to the ``process_request`` that it
hands to ``websockets.asyncio.server.serve``, the one function through which websockets passes every
request on the server's socket before answering it (:func:`refuse_foreign`), from the moment the
socket listens. :func:`guard_clients` removes the share tunnel and quiets malformed messages
(relying on viser's ``_websock_server``); :func:`from_client` wraps a GUI callback. Refused
requests and malformed messages end as one DEBUG line of the
``splat_framework.viewer.viser_clients`` logger (shown only with debug logging on).
"""

from __future__ import annotations

import functools
import http
import logging
import threading
import warnings
from collections import Counter

from .serving import client_allowed

__all__ = ["start_checked", "refuse_foreign", "guard_clients", "from_client"]

log = logging.getLogger(__name__)

REFUSED = "this page may not use the viewer (only the viewer's own page may)\n"
"""The body of the 403 answering a refused request."""

NO_FRAMING = (("X-Frame-Options", "DENY"), ("Content-Security-Policy", "frame-ancestors 'none'"))
"""Headers of every HTTP answer: no page (of any site) may show the viewer in a frame, where it could
have the user click its buttons unseen (clickjacking); the page's own socket would be allowed."""

_LOCK = threading.Lock()
_STARTING: Counter = Counter()
"""Hosts on which :func:`start_checked` is starting a server now (how many)."""
_CHECKED: Counter = Counter()
"""How many websockets servers were started with :func:`refuse_foreign` on each host."""


def start_checked(start, host: str):
    """``start()``'s ``viser.ViserServer``, listening on ``host``, with :func:`refuse_foreign` in the
    opening handshake of its websockets server from the moment it listens. A viser that no longer
    starts its server through ``websockets.asyncio.server.serve`` would serve every page: its server
    is stopped and RuntimeError raised, never a viewer without the check."""
    with _LOCK:
        _install_check()
        _STARTING[host] += 1
        before = _CHECKED[host]
    try:
        server = start()
    finally:
        with _LOCK:
            _STARTING[host] -= 1
    if _CHECKED[host] == before:
        server.stop()
        raise RuntimeError("the viewer's server did not start through websockets.asyncio.server.serve, so it "
                           "could not refuse the pages of other web sites; not serving (is viser's version supported?)")
    return server


def _install_check() -> None:
    """Have ``websockets.asyncio.server.serve`` add :func:`refuse_foreign` to the servers started
    while :func:`start_checked` starts one on their host; other servers of the process pass through
    unchanged. Installed once, and again if something replaced it since (a test's monkeypatch)."""
    import websockets.asyncio.server as ws

    if not getattr(ws.serve, "refuses_foreign", False):
        ws.serve = _serving_checked(ws.serve)


def _serving_checked(serve):
    """``serve`` (websockets') adding :func:`refuse_foreign` to the ``process_request`` of a server
    on a host in :data:`_STARTING`."""

    @functools.wraps(serve)
    def checked(handler, host=None, port=None, *, process_request=None, **kwargs):
        with _LOCK:
            starting = _STARTING[host] > 0
            if starting:
                _CHECKED[host] += 1
        if starting:
            process_request = refuse_foreign(host, process_request)
        return serve(handler, host, port, process_request=process_request, **kwargs)

    checked.refuses_foreign = True
    return checked


def refuse_foreign(host: str, process_request=None):
    """A websockets ``process_request`` for a server listening on ``host``: 403 (:data:`REFUSED`) for
    a request :func:`~splat_framework.viewer.serving.client_allowed` refuses or that repeats its
    ``Host`` or ``Origin``; else ``process_request``'s answer (viser's: the page and its assets; None,
    the websocket handshake, for an upgrade). Every HTTP answer carries :data:`NO_FRAMING`."""

    def process(connection, request):
        hosts, origins = request.headers.get_all("Host"), request.headers.get_all("Origin")
        if len(hosts) != 1 or len(origins) > 1 or not client_allowed(host, hosts[0], origins[0] if origins else None):
            log.debug("viewer refused a request: Host %r, Origin %r", hosts, origins)
            response = connection.respond(http.HTTPStatus.FORBIDDEN, REFUSED)
        else:
            response = process_request(connection, request) if process_request is not None else None
        if response is not None:
            for name, value in NO_FRAMING:
                if name not in response.headers:
                    response.headers[name] = value
        return response

    return process


def guard_clients(server) -> None:
    """Guard the clients of ``server`` (a ``viser.ViserServer``) once connected: no share tunnel, no
    traceback from what they send."""
    from viser import _messages

    # a client's "share" request would open a public tunnel to this server: not a client's to grant
    server._websock_server.unregister_handler(_messages.ShareUrlRequest)
    _quiet_client_errors(server)


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
