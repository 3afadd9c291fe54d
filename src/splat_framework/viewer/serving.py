"""Where a local server (the viewer) listens, and what it says about it.

One mechanism for everything this project serves (``splat-view``, ``splat-train --viewer``):

- it listens on :data:`LOOPBACK` unless an address is given explicitly; any other address
  brings a one-line :class:`ServingWarning` naming what becomes reachable, and by whom
  (:func:`exposure_warning`);
- a port is a :data:`Port`: an integer 0..65535 (0 = any free port), checked while the
  command line is parsed (one line, exit 2; :class:`InvalidAddress`), never handed to a
  server thread that would die on it and leave the command waiting forever;
- a port in use is said in one line and the next free one is used (:func:`free_port`);
- the URL printed is the one that works (:func:`server_url`);
- a browser page of another site cannot use it, even on loopback, nor can a DNS-rebinding name:
  :func:`client_allowed` decides from each request's ``Host`` and ``Origin``, and
  :func:`~splat_framework.viewer.viser_clients.start_checked` answers 403 to the page, its assets
  and the websocket handshake it refuses.

Torch-free and cheap to import; the config values (:data:`Port`, :data:`LOOPBACK`) live in
:mod:`splat_framework.config.address`.
"""

from __future__ import annotations

import errno
import ipaddress
import socket
from urllib.parse import urlsplit

from ..config.address import LOOPBACK, MAX_PORT, InvalidAddress, Port, check_port  # noqa: F401  (the listening policy's names)

__all__ = [
    "LOOPBACK", "MAX_PORT", "Port", "InvalidAddress", "ServingWarning", "check_port", "free_port",
    "is_loopback", "server_url", "exposure_warning", "client_allowed",
]

PORT_TRIES = 100
"""How many ports after a taken one are tried before giving up."""
EXPOSED = "the model, the training/test photos' thumbnails and \"Render with splat\""
"""What a viewer serves to whoever connects (the wording of the exposure warning)."""


class ServingWarning(UserWarning):
    """A server listens somewhere other than asked or than this machine only (one line)."""


def _addresses(host: str, port: int) -> list[tuple]:
    """getaddrinfo's passive TCP addresses of ``host`` (those a server listening on it binds)."""
    try:
        return socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError) as e:
        raise InvalidAddress(f"cannot listen on host {host!r}: {getattr(e, 'strerror', None) or e}") from None


def _try_bind(host: str, port: int) -> int | None:
    """Bind every address of ``host`` at ``port`` as the server will (SO_REUSEADDR, IPv6-only
    sockets), then release them: the port bound (the one the OS chose for 0), or None if in use."""
    sockets = []
    try:
        for family, kind, proto, _, address in _addresses(host, port):
            s = socket.socket(family, kind, proto)
            sockets.append(s)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                s.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            if port == 0 and len(sockets) > 1:  # the other addresses of host: the port the first one got
                address = (address[0], sockets[0].getsockname()[1], *address[2:])
            s.bind(address)
        return sockets[0].getsockname()[1] if sockets else None
    except OSError as e:
        if e.errno == errno.EADDRINUSE:
            return None
        raise InvalidAddress(f"cannot listen on {host} port {port}: {e.strerror or e}") from None
    finally:
        for s in sockets:
            s.close()


def free_port(host: str, port: int) -> int:
    """The first port from ``port`` on (at most :data:`PORT_TRIES` of them) at which ``host`` can
    listen now; for ``port`` 0, one the OS chooses. :class:`InvalidAddress` for a port out of range,
    an unknown host, an address this machine does not have, or when every port tried is taken."""
    port = check_port(port)
    for candidate in range(port, min(port + PORT_TRIES, MAX_PORT + 1)) if port else (0,):
        bound = _try_bind(host, candidate)
        if bound is not None:
            return bound
    raise InvalidAddress(f"ports {port}-{candidate} on {host} are all in use (choose another port, or 0 for any free one)")


def _ips(host: str) -> list:
    return [ipaddress.ip_address(info[4][0].split("%")[0]) for info in _addresses(host, 0)]


def is_loopback(host: str) -> bool:
    """Whether every address ``host`` stands for is this machine's loopback (reachable from here only)."""
    ips = _ips(host)
    return bool(ips) and all(ip.is_loopback for ip in ips)


def server_url(host: str, port: int, scheme: str = "http") -> str:
    """The URL a browser opens: ``localhost`` for a loopback server, this machine's name for one on
    every interface (0.0.0.0, ::), the address given otherwise."""
    if is_loopback(host):
        name = "localhost"
    elif all(ip.is_unspecified for ip in _ips(host)):
        name = socket.gethostname()
    else:
        name = f"[{host}]" if ":" in host else host
    return f"{scheme}://{name}:{port}"


def exposure_warning(host: str, port: int) -> str | None:
    """The one line that says what a viewer on ``host`` exposes and to whom (None on loopback)."""
    if is_loopback(host):
        return None
    who = ("every machine that can reach this one on the network" if all(ip.is_unspecified for ip in _ips(host))
           else f"every machine that can reach {host}")
    return (f"the viewer listens on {host} port {port}, open to {who}: anyone there can see {EXPOSED}, "
            f"without a password (the default host, {LOOPBACK}, keeps it on this machine)")


def client_allowed(bound_host: str, request_host: str | None, origin: str | None) -> bool:
    """Whether a request to a server listening on ``bound_host`` (for the page, an asset, or the
    websocket handshake) may be answered, from its ``Host`` and ``Origin`` headers.

    Listening on loopback stops other machines, not other web sites: any page the user opens can
    script a websocket to ``ws://localhost:PORT``. So a request carrying ``Origin`` (a browser's
    websocket always does, as do its scripts' fetches) is accepted only from a page this server
    served (Origin = its Host), and on loopback every request only under a loopback name (a
    DNS-rebinding page connects under its own domain, which then resolves to 127.0.0.1). Requests
    without Origin (clients that are not browsers, a browser opening the URL) are accepted under
    such a Host. On any other address the Host is the one the user connects with (the opened
    address, or a name of it), and a browser's request must come from a page under that Host."""
    if not request_host:
        return False
    name = _url_part(f"//{request_host}", "hostname")
    if name is None or is_loopback(bound_host) and not _loopback_name(name):
        return False
    return origin is None or _url_part(origin, "netloc") == request_host.strip().lower()


def _url_part(url: str, part: str) -> str | None:
    """``urlsplit(url)``'s ``part`` (``hostname``, ``netloc``) in lower case; None when ``url`` is
    not a URL (``http://[``)."""
    try:
        return (getattr(urlsplit(url.strip()), part) or "").lower()
    except ValueError:
        return None


def _loopback_name(name: str) -> bool:
    """Whether a Host header's name is ``localhost`` or a loopback address."""
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False
