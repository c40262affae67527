"""The monitor server bounds what clients can hold: each connection is closed after its timeout without
progress, at most max_connections are served at once (the rest get a 503 at once), and `--host ::1` binds
IPv6 loopback or says why it cannot (never "choose another port" for a missing address)."""

from __future__ import annotations

import errno
import http.client
import socket
import threading

import pytest

from neatskin.errors import ConfigError
from neatskin.monitor.listen import address_family, listen_error
from neatskin.monitor.server import make_server

DEADLINE_S = 20.0  # a cap for the test's own reads, so a server that never closes fails instead of hanging


@pytest.fixture
def server(tmp_path):
    srv = make_server(tmp_path, port=0, read_only=True, connection_timeout_s=2.0, max_connections=4)
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield srv
    srv.shutdown()
    srv.server_close()


def _idle(port: int) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=DEADLINE_S)
    return sock


def test_idle_connections_are_closed_and_connections_past_the_cap_get_503(server):
    port = server.server_address[1]
    threads_before = threading.active_count()
    held = [_idle(port) for _ in range(4)]  # every slot held by a client that sends nothing
    extra = [_idle(port) for _ in range(6)]
    for sock in extra:  # refused at once: a 503, then the server closes
        reply = b""
        while chunk := sock.recv(4096):
            reply += chunk
        assert reply.startswith(b"HTTP/1.0 503 ") and b"too many open connections" in reply
    assert threading.active_count() <= threads_before + 4  # no thread for the refused ones
    for sock in held:  # the idle ones are closed by the server (recv returns b"" at EOF), not held for ever
        sock.send(b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # a request never finished: still idle
        data = b""
        while chunk := sock.recv(4096):
            data += chunk
        assert b"200 OK" not in data
        sock.close()
    for sock in extra:
        sock.close()
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=DEADLINE_S)  # and the server still serves
    conn.request("GET", "/api/state")
    assert conn.getresponse().status == 200


def test_ipv6_loopback_binds_or_says_why():
    assert address_family("::1") == socket.AF_INET6 and address_family("[::1]") == socket.AF_INET6
    assert address_family("127.0.0.1") == socket.AF_INET
    try:
        srv = make_server(".", host="::1", port=0, read_only=True)
    except ConfigError as exc:  # a machine without IPv6: the message names the address, not the port
        assert exc.problems[0].field == "--host" and "127.0.0.1" in exc.problems[0].fix
        return
    try:
        assert srv.url.startswith("http://[::1]:")
    finally:
        srv.server_close()


def test_listen_errors_give_the_fix_for_their_reason():
    in_use = listen_error("127.0.0.1", 8765, OSError(errno.EADDRINUSE, "Address already in use"))
    assert in_use.problems[0].field == "--port" and "another port" in in_use.problems[0].fix
    no_v6 = listen_error("::1", 8765, OSError(errno.EAFNOSUPPORT, "Address family not supported by protocol"))
    assert no_v6.problems[0].field == "--host" and "another port" not in no_v6.problems[0].fix
    assert "no IPv6 loopback" in no_v6.problems[0].fix
    missing = listen_error("10.9.9.9", 8765, OSError(errno.EADDRNOTAVAIL, "Cannot assign requested address"))
    assert missing.problems[0].field == "--host" and "another port" not in missing.problems[0].fix
