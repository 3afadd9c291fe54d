"""Servers listen on 127.0.0.1 unless told otherwise, with real sockets: the machine's other address
is refused; an explicit host opens it with a one-line warning; a taken port moves to the next free
one and says so; an invalid port is one line and exit 2 at parse time; malformed websocket messages
print no traceback (issue 40); a page of another web site or a DNS-rebinding name gets 403 for the page
and the websocket (issue 60)."""

import asyncio
import contextlib
import http.client
import socket
import subprocess
import sys
import threading
import time
import urllib.request

import pytest

from cli_harness import cli_env, run_cli

pytest.importorskip("viser")


def non_loopback_address() -> str | None:
    """An IPv4 address of this machine other than loopback (None if it has none)."""
    candidates = []
    with contextlib.suppress(OSError), socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.connect(("10.255.255.255", 1))  # UDP: nothing is sent, the kernel picks the outgoing interface
        candidates.append(s.getsockname()[0])
    with contextlib.suppress(OSError):
        candidates.append(socket.gethostbyname(socket.gethostname()))
    return next((a for a in candidates if not a.startswith("127.") and a != "0.0.0.0"), None)


OTHER = non_loopback_address()
needs_other = pytest.mark.skipif(OTHER is None, reason="this machine has no non-loopback IPv4 address to connect to")


def answers(address: str, port: int) -> bool:
    """Whether an HTTP GET of the viewer's page at ``address:port`` gets a 200."""
    try:
        with urllib.request.urlopen(f"http://{address}:{port}/", timeout=10) as r:
            return r.status == 200
    except OSError:
        return False


@pytest.mark.parametrize("command, flag", [("view", "--port"), ("train", "--viewer-port")])
@pytest.mark.parametrize("port", ["-1", "70000", "abc"])
@pytest.mark.bad_input("`--port -1`, `70000`, `abc` (splat-view, splat-train --viewer-port)", "exit 2 at parse time, one line; never a hang")
def test_invalid_port_is_one_line_at_parse_time(command, flag, port, tmp_path):
    """Before: a traceback from viser's server thread, then the command hung (the thread died
    before releasing the semaphore ViserServer waits on); ``abc``: tyro's box."""
    args = (tmp_path,) if command == "view" else ("3dgs", "--data", "synthetic/forward-tiny")
    run_cli(command, *args, flag, port, code=2, match=(f"invalid port '{port}'", "0..65535"), watch=[tmp_path],
            timeout=60)


@needs_other
@pytest.mark.bad_input("`splat-view RUN`, `splat-train --viewer` with no host given", "listen on 127.0.0.1 only (the machine's other addresses are refused); the URL printed is the one served")
@pytest.mark.bad_input("`splat-view --host 0.0.0.0`, `splat-train --viewer-host 0.0.0.0`", "serves every interface, with one warning line naming what becomes reachable (the model, the photos' thumbnails, \"Render with splat\")")
def test_viewer_listens_on_loopback_unless_a_host_is_given():
    from splat_framework.viewer.scene_viewer import Viewer
    from splat_framework.viewer.serving import ServingWarning

    v = Viewer(port=0)
    try:
        assert v.url == f"http://localhost:{v.port}"
        assert answers("127.0.0.1", v.port) and not answers(OTHER, v.port)
    finally:
        v.close()
    with pytest.warns(ServingWarning, match="open to every machine .* thumbnails and \"Render with splat\""):
        v = Viewer(port=0, host="0.0.0.0")
    try:  # the check above can fail: opened, the other address answers
        assert answers(OTHER, v.port) and v.url == f"http://{socket.gethostname()}:{v.port}"
    finally:
        v.close()


def _serve(command: list[str], ready: str, timeout: float = 120) -> tuple[subprocess.Popen, str]:
    """Start a serving ``splat-*`` subprocess; return it and its stdout line containing ``ready``."""
    proc = subprocess.Popen([sys.executable, "-m", *command], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=cli_env())
    deadline = time.monotonic() + timeout
    for line in proc.stdout:
        if ready in line:
            return proc, line
        assert time.monotonic() < deadline, f"no {ready!r} line in {timeout} s"
    proc.kill()
    raise AssertionError(f"exited {proc.wait()} before serving: {proc.stderr.read()[-2000:]}")


def _stop(proc: subprocess.Popen) -> str:
    """Kill a serving subprocess; its stderr."""
    proc.kill()
    _, err = proc.communicate(timeout=30)
    return err


@pytest.mark.slow
@needs_other
@pytest.mark.bad_input("`splat-view RUN`, `splat-train --viewer` with no host given", "listen on 127.0.0.1 only (the machine's other addresses are refused); the URL printed is the one served")
@pytest.mark.bad_input("a port already in use", "one line, then the next free port, which the URL shows")
def test_splat_view_listens_on_loopback_and_a_taken_port_moves_on(run_dir):
    """Before: ``splat-view RUN --port P`` listened on 0.0.0.0 (HTTP 200 on the machine's other
    address) while the URL said localhost; a taken port was skipped silently by viser."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = None
        try:
            proc, line = _serve(["splat_framework.cli.view", str(run_dir), "--port", str(port)], "viewer of")
            served = int(line.rsplit(":", 1)[1].split()[0])
            assert served != port and f"at http://localhost:{served} " in line
            assert answers("127.0.0.1", served) and not answers(OTHER, served)
        finally:
            err = _stop(proc) if proc else ""
    # beside the progress of loading the run (shown on a slow machine), one line: the warning
    shown = [x for x in err.splitlines() if x.strip() and not x.startswith(f"loading {run_dir}: ")]
    assert shown == [f"warning: port {port} is in use; serving on {served}"]


@pytest.mark.slow
@needs_other
@pytest.mark.bad_input("`splat-view --host 0.0.0.0`, `splat-train --viewer-host 0.0.0.0`", "serves every interface, with one warning line naming what becomes reachable (the model, the photos' thumbnails, \"Render with splat\")")
def test_splat_train_viewer_host_opens_it_with_a_warning(tmp_path):
    """Before: splat-train --viewer listened on 0.0.0.0 with no option to choose the address."""
    from splat_framework.registry import get_method

    assert get_method("3dgs").default_config().viewer_host == "127.0.0.1"
    proc = None
    try:
        proc, line = _serve(["splat_framework.cli.train", "3dgs", "--data", "synthetic/forward-tiny", "--steps", "2",
                             "--output", str(tmp_path / "run"), "--no-progress", "--viewer", "--viewer-port", "0",
                             "--viewer-host", "0.0.0.0", "--model.init.num-points", "300"], "viewer at")
        url = line.split("viewer at", 1)[1].strip()
        port = int(url.rsplit(":", 1)[1])
        assert url == f"http://{socket.gethostname()}:{port}" and answers(OTHER, port)
    finally:
        err = _stop(proc) if proc else ""
    warned = [x for x in err.splitlines() if x.startswith("warning: the viewer listens on 0.0.0.0")]
    assert len(warned) == 1 and "thumbnails" in warned[0] and "Render with splat" in warned[0], err
    assert "Traceback" not in err


@pytest.mark.parametrize("host", ["nosuch.invalid", "192.0.2.1"])  # 192.0.2.1: TEST-NET-1, no machine's address
@pytest.mark.bad_input("a host this machine cannot listen on; a viewer server thread that dies", "exit 2, one line, before training writes anything; never a hang")
def test_a_host_that_cannot_be_listened_on_is_one_error(host):
    """Before: viser tried 1000 ports on it, then the command waited forever for a server that never started."""
    from splat_framework.viewer.scene_viewer import Viewer
    from splat_framework.viewer.serving import InvalidAddress

    with pytest.raises(InvalidAddress, match="cannot listen on"):
        Viewer(port=0, host=host)


@pytest.mark.bad_input("a host this machine cannot listen on; a viewer server thread that dies", "exit 2, one line, before training writes anything; never a hang")
def test_a_server_thread_that_dies_ends_the_wait(monkeypatch):
    """viser's constructor waits without a timeout for its server thread; one that dies (as on
    ``--port -1`` before) made the command hang. Now: an error after the startup timeout."""
    import websockets.asyncio.server

    from splat_framework.viewer.scene_viewer import _start_server
    from splat_framework.viewer.serving import InvalidAddress

    def dies(*args, **kwargs):
        raise RuntimeError("server thread died")

    monkeypatch.setattr(websockets.asyncio.server, "serve", dies)
    monkeypatch.setattr(threading, "excepthook", lambda args: None)  # the dying thread's own report
    with pytest.raises(InvalidAddress, match="did not start listening on 127.0.0.1"):
        _start_server("127.0.0.1", 0, timeout=1)


@pytest.mark.bad_input("a host this machine cannot listen on; a viewer server thread that dies", "exit 2, one line, before training writes anything; never a hang")
def test_splat_train_checks_the_viewer_host_before_training(tmp_path):
    """Before: the viewer opened at step 1, after the run folder was written; on a bad host, viser hung."""
    run_cli("train", "3dgs", "--data", "synthetic/forward-tiny", "--output", tmp_path / "run", "--viewer",
            "--viewer-host", "nosuch.invalid", code=2, match="cannot listen on host 'nosuch.invalid'",
            watch=[tmp_path], timeout=60)


def _send_malformed(port: int, gui_uuids: list[str]) -> None:
    """Send what no viser client sends: text, bytes that are not msgpack, unknown message types,
    GUI updates with values of the wrong type, a share-tunnel request; one connection each."""
    import msgspec
    import viser
    from websockets.asyncio.client import connect

    pack = msgspec.msgpack.encode
    messages = ["not bytes", b"\xff\x00garbage", pack({"type": "NoSuchMessage"}), pack([1, 2]),
                pack({"type": "GuiUpdateMessage", "id": 5}), pack({"type": "ViewerCameraMessage", "wxyz": "x"})]
    messages += [pack({"type": "GuiUpdateMessage", "uuid": u, "updates": bad})
                 for u in gui_uuids for bad in ({"value": "x"}, {"value": None}, {"nosuch": 1}, "s", {"value": [1]})]
    messages.append(pack({"type": "ShareUrlRequest"}))

    async def send_all():
        for message in messages:
            async with connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"],
                               max_size=None) as ws:
                await ws.send(message)
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(ws.recv(), 0.2)

    asyncio.run(send_all())


@pytest.mark.slow
@pytest.mark.bad_input("malformed websocket messages", "nothing printed and the viewer keeps serving")
def test_malformed_websocket_messages_print_no_traceback(run_dir, capfd, recwarn):
    """Before: "connection handler failed" and a traceback on the viewer's stderr for each."""
    from splat_framework.cli.view import ViewArgs, main

    viewer = main(ViewArgs(run_dir=run_dir, port=0), serve=False)
    try:
        capfd.readouterr()
        gui = [viewer._by_type, viewer._chosen, *viewer.server.gui._gui_input_handle_from_uuid.values()]
        _send_malformed(viewer.port, list(dict.fromkeys(h._impl.uuid for h in gui)))
        time.sleep(0.5)  # handler tasks and thread-pool callbacks finish
        out, err = capfd.readouterr()
        assert "Traceback" not in err + out and "Error" not in err, err[-3000:]
        assert not err.strip(), err[-3000:]
        assert not [str(w.message) for w in recwarn], "warnings would be lines in the terminal"
        assert answers("127.0.0.1", viewer.port) and viewer.server._share_tunnel is None
    finally:
        viewer.close()


def _get(port: int, headers: list[tuple[str, str]], path: str = "/", address: str = "127.0.0.1") -> tuple[int, bytes]:
    """Status and body of a GET of ``path`` at ``address:port`` sent with exactly ``headers`` (Host among them)."""
    status, _, body = _get_with_headers(port, headers, path, address)
    return status, body


def _get_with_headers(port: int, headers: list[tuple[str, str]], path: str = "/",
                      address: str = "127.0.0.1") -> tuple[int, dict[str, str], bytes]:
    """:func:`_get`, with the answer's headers."""
    conn = http.client.HTTPConnection(address, port, timeout=10)
    try:
        conn.putrequest("GET", path, skip_host=True, skip_accept_encoding=True)
        for name, value in headers:
            conn.putheader(name, value)
        conn.endheaders()
        response = conn.getresponse()
        return response.status, dict(response.getheaders()), response.read()
    finally:
        conn.close()


def _upgrade(port: int, headers: list[tuple[str, str]]) -> tuple[str, bytes]:
    """The status line answering a websocket upgrade request (viser's subprotocol, then ``headers``)
    sent on a raw socket, and what follows the answer's head until the server closes (nothing read
    after a 101)."""
    import viser

    head = ["GET / HTTP/1.1", "Upgrade: websocket", "Connection: Upgrade", "Sec-WebSocket-Version: 13",
            "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", f"Sec-WebSocket-Protocol: viser-v{viser.__version__}"]
    request = "\r\n".join(head + [f"{name}: {value}" for name, value in headers]) + "\r\n\r\n"
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(request.encode())
        received = b""
        while b"\r\n\r\n" not in received and (chunk := s.recv(65536)):
            received += chunk
        answer, _, rest = received.partition(b"\r\n\r\n")
        status = answer.split(b"\r\n")[0].decode()
        while " 101 " not in status and (chunk := s.recv(65536)):
            rest += chunk
    return status, rest


@pytest.mark.bad_input("a web page of another site (foreign Origin) or a DNS-rebinding name (foreign Host) reaching the local viewer", "403 for the websocket and every HTTP request; nothing served")
def test_pages_of_other_sites_and_rebinding_names_get_403_for_the_socket_and_every_request():
    """Loopback stops other machines, not other web sites. Before: with Origin http://evil.example
    the websocket handshake got 101 (the check ran in viser's connect callbacks, after it), and a GET
    with Host evil.example:PORT (a DNS-rebinding page, its domain now resolving to 127.0.0.1) got
    the page. Now every request on the viewer's socket is checked before anything is answered."""
    from splat_framework.viewer.scene_viewer import Viewer
    from splat_framework.viewer.viser_clients import REFUSED

    v = Viewer(port=0)
    try:
        port, own, refused = v.port, f"127.0.0.1:{v.port}", (403, REFUSED.encode())
        status, page = _get(port, [("Host", own)])  # not a browser (no Origin), a loopback name: served
        assert status == 200 and b"<html" in page.lower()
        assert _get(port, [("Host", f"localhost:{port}"), ("Origin", f"http://localhost:{port}")], "/index.html") == (200, page)
        assert _get(port, [("Host", own)], "/nosuch.js")[0] == 404
        for headers in ([("Host", f"evil.example:{port}")],
                        [("Host", f"evil.example:{port}"), ("Origin", f"http://evil.example:{port}")],
                        [("Host", own), ("Origin", "http://evil.example")], [("Host", own), ("Origin", "null")],
                        [("Host", own), ("Origin", "http://[")], [("Host", "[")],
                        [("Host", own), ("Origin", f"http://127.0.0.1:{port + 1}")],  # another local server's page
                        [("Host", own), ("Host", "evil.example")], []):
            for path in ("/", "/index.html", "/nosuch.js"):  # viser's client is one page; other paths: 404
                assert _get(port, headers, path) == refused, (headers, path)
            assert _upgrade(port, headers) == ("HTTP/1.1 403 Forbidden", REFUSED.encode()), headers
        assert _upgrade(port, [("Host", own), ("Origin", f"http://{own}")])[0] == "HTTP/1.1 101 Switching Protocols"
        assert _upgrade(port, [("Host", f"[::1]:{port}")])[0] == "HTTP/1.1 101 Switching Protocols"
        assert _viser_client(port, f"http://localhost:{port}") == "message"  # viser's own client gets the scene
        assert _viser_client(port, "http://evil.example") == 403
    finally:
        v.close()


@pytest.mark.bad_input("a page of any site showing the viewer in a frame (clickjacking)",
                       "refused by the browser: every HTTP answer says X-Frame-Options DENY and CSP frame-ancestors 'none'")
def test_no_page_may_show_the_viewer_in_a_frame():
    """Clickjacking: a page of another site could show the viewer (its own socket allowed) in a
    frame and have the user click its buttons unseen. Every HTTP answer forbids framing."""
    from splat_framework.viewer.scene_viewer import Viewer

    v = Viewer(port=0)
    try:
        for path, host, status in (("/", f"127.0.0.1:{v.port}", 200), ("/index.html", f"localhost:{v.port}", 200),
                                   ("/nosuch.js", f"127.0.0.1:{v.port}", 404), ("/", f"evil.example:{v.port}", 403)):
            got, answer, _ = _get_with_headers(v.port, [("Host", host)], path)
            assert got == status, (path, host)
            assert answer.get("X-Frame-Options") == "DENY", (path, answer)
            assert "frame-ancestors 'none'" in answer.get("Content-Security-Policy", ""), path
    finally:
        v.close()


def _viser_client(port: int, origin: str) -> int | str:
    """What a viser client connecting from a page of ``origin`` gets first: "message" (the scene),
    or the HTTP status refusing its handshake."""
    import viser
    from websockets.asyncio.client import connect
    from websockets.exceptions import InvalidStatus

    async def first() -> int | str:
        try:
            async with connect(f"ws://localhost:{port}", origin=origin, subprotocols=[f"viser-v{viser.__version__}"],
                               max_size=None) as ws:
                await asyncio.wait_for(ws.recv(), 10)
                return "message"
        except InvalidStatus as e:
            return e.response.status_code

    return asyncio.run(first())


def test_a_viser_that_bypasses_the_check_is_not_served(monkeypatch):
    """Should viser start its server otherwise than through ``websockets.asyncio.server.serve``, the
    check would not apply: then no viewer is started (RuntimeError, its server stopped)."""
    import websockets.asyncio.server as ws

    from splat_framework.viewer import viser_clients
    from splat_framework.viewer.scene_viewer import Viewer
    from splat_framework.viewer.serving import free_port

    monkeypatch.setattr(viser_clients, "_install_check", lambda: None)
    monkeypatch.setattr(ws, "serve", getattr(ws.serve, "__wrapped__", ws.serve))
    port = free_port("127.0.0.1", 0)
    with pytest.raises(RuntimeError, match="could not refuse the pages of other web sites"):
        Viewer(port=port)
    time.sleep(0.5)  # the server's thread closes its socket
    assert not answers("127.0.0.1", port)


@needs_other
@pytest.mark.bad_input("a web page of another site (foreign Origin) or a DNS-rebinding name (foreign Host) reaching the local viewer", "403 for the websocket and every HTTP request; nothing served")
def test_an_opened_viewer_serves_its_own_address_and_refuses_other_sites():
    """``--host ADDRESS`` opens the viewer to ADDRESS: the page is served under it, with or without its
    Origin; a page of another site still gets 403."""
    from splat_framework.viewer.scene_viewer import Viewer
    from splat_framework.viewer.serving import ServingWarning

    with pytest.warns(ServingWarning):
        v = Viewer(port=0, host=OTHER)
    try:
        opened = f"{OTHER}:{v.port}"
        assert _get(v.port, [("Host", opened)], address=OTHER)[0] == 200
        assert _get(v.port, [("Host", opened), ("Origin", f"http://{opened}")], address=OTHER)[0] == 200
        assert _get(v.port, [("Host", opened), ("Origin", "http://evil.example")], address=OTHER)[0] == 403
    finally:
        v.close()
