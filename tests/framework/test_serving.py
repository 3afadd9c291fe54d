"""Servers listen on 127.0.0.1 unless told otherwise, with real sockets: the machine's other address
is refused; an explicit host opens it with a one-line warning; a taken port moves to the next free
one and says so; an invalid port is one line and exit 2 at parse time; malformed websocket messages
print no traceback (issue 40)."""

import asyncio
import contextlib
import socket
import subprocess
import sys
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
def test_invalid_port_is_one_line_at_parse_time(command, flag, port, tmp_path):
    """Before: a traceback from viser's server thread, then the command hung (the thread died
    before releasing the semaphore ViserServer waits on); ``abc``: tyro's box."""
    args = (tmp_path,) if command == "view" else ("3dgs", "--data", "synthetic/forward-tiny")
    run_cli(command, *args, flag, port, code=2, match=(f"invalid port '{port}'", "0..65535"), watch=[tmp_path],
            timeout=60)


@needs_other
def test_viewer_listens_on_loopback_unless_a_host_is_given():
    from splat_framework.serving import ServingWarning
    from splat_framework.viewer import Viewer

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
def test_splat_view_host_opens_it_with_a_warning_and_a_taken_port_moves_on(run_dir):
    with socket.socket() as taken:
        taken.bind(("0.0.0.0", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc, line = None, ""
        try:
            proc, line = _serve(["splat_framework.cli.view", str(run_dir), "--port", str(port), "--host", "0.0.0.0"],
                                "viewer of")
            served = int(line.rsplit(":", 1)[1].split()[0])
            assert served != port and f"http://{socket.gethostname()}:{served}" in line
            assert answers(OTHER, served)
        finally:
            err = _stop(proc) if proc else ""
    lines = [x for x in err.splitlines() if x.strip()]
    assert f"warning: port {port} is in use; serving on {served}" in lines
    assert any(x.startswith("warning: the viewer listens on 0.0.0.0") and "thumbnails" in x for x in lines), err
    assert "Traceback" not in err


@pytest.mark.slow
@needs_other
def test_splat_train_viewer_listens_on_loopback(tmp_path):
    proc = None
    try:
        proc, line = _serve(["splat_framework.cli.train", "3dgs", "--data", "synthetic/forward-tiny", "--steps", "2",
                             "--output", str(tmp_path / "run"), "--no-progress", "--viewer", "--viewer-port", "0",
                             "--model.init-num-points", "300"], "viewer at")
        url = line.split("viewer at", 1)[1].strip()
        port = int(url.rsplit(":", 1)[1])
        assert url == f"http://localhost:{port}" and answers("127.0.0.1", port) and not answers(OTHER, port)
    finally:
        err = _stop(proc) if proc else ""
    assert "warning" not in err and "Traceback" not in err


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
