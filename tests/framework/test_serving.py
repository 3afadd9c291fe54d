"""Servers listen on 127.0.0.1 unless told otherwise, with real sockets: the machine's other address
is refused; an explicit host opens it with a one-line warning; a taken port moves to the next free
one and says so; an invalid port is one line and exit 2 at parse time; malformed websocket messages
print no traceback (issue 40)."""

import asyncio
import contextlib
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
    from splat_framework.viewer.serving import ServingWarning
    from splat_framework.viewer.scene_viewer import Viewer

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
    from splat_framework.viewer.serving import InvalidAddress
    from splat_framework.viewer.scene_viewer import Viewer

    with pytest.raises(InvalidAddress, match="cannot listen on"):
        Viewer(port=0, host=host)


@pytest.mark.bad_input("a host this machine cannot listen on; a viewer server thread that dies", "exit 2, one line, before training writes anything; never a hang")
def test_a_server_thread_that_dies_ends_the_wait(monkeypatch):
    """viser's constructor waits without a timeout for its server thread; one that dies (as on
    ``--port -1`` before) made the command hang. Now: an error after the startup timeout."""
    import websockets.asyncio.server

    from splat_framework.viewer.serving import InvalidAddress
    from splat_framework.viewer.scene_viewer import _start_server

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
@pytest.mark.bad_input("malformed websocket messages; a page of another web site (or a DNS-rebinding page) opening the viewer's websocket", "nothing printed and the viewer keeps serving; the foreign page's socket is closed before anything is sent")
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


@pytest.mark.bad_input("malformed websocket messages; a page of another web site (or a DNS-rebinding page) opening the viewer's websocket", "nothing printed and the viewer keeps serving; the foreign page's socket is closed before anything is sent")
def test_pages_of_other_sites_cannot_use_the_viewer():
    """Loopback stops other machines, not other web sites: a page the user opens elsewhere (its
    Origin), or one that rebinds its domain to 127.0.0.1 (its Host), is closed before any message."""
    import viser
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed

    from splat_framework.viewer.scene_viewer import Viewer

    v = Viewer(port=0)

    async def first_message(uri: str, origin: str | None) -> int | str:
        """The close code, or "message" when the server sends the scene."""
        sock = socket.create_connection(("127.0.0.1", v.port))
        async with connect(uri, origin=origin, sock=sock, subprotocols=[f"viser-v{viser.__version__}"],
                           max_size=None) as ws:
            try:
                await asyncio.wait_for(ws.recv(), 10)
                return "message"
            except ConnectionClosed as e:
                return e.rcvd.code

    try:
        own = f"http://localhost:{v.port}"
        assert asyncio.run(first_message(f"ws://localhost:{v.port}", own)) == "message"
        numeric = f"http://127.0.0.1:{v.port}"  # the page opened by its address (headless Chromium's in test_viewer)
        assert asyncio.run(first_message(f"ws://127.0.0.1:{v.port}", numeric)) == "message"
        assert asyncio.run(first_message(f"ws://127.0.0.1:{v.port}", None)) == "message"  # not a browser
        assert asyncio.run(first_message(f"ws://localhost:{v.port}", "http://evil.example")) == 1008
        assert asyncio.run(first_message(f"ws://evil.example:{v.port}", f"http://evil.example:{v.port}")) == 1008
    finally:
        v.close()
