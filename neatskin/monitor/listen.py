"""Where the monitor listens: the address family of a host (IPv6 for `::1`), and a listen error's fix for its
reason (a port in use is not an address the machine lacks)."""

from __future__ import annotations

import errno
import ipaddress
import socket

from neatskin.errors import ConfigError


def address_family(host: str) -> socket.AddressFamily:
    """IPv6 for an IPv6 literal (`::1`, `[::1]`) or a name that resolves only to IPv6, else IPv4."""
    bare = host.strip("[]")
    try:
        return socket.AF_INET6 if ipaddress.ip_address(bare).version == 6 else socket.AF_INET
    except ValueError:
        pass
    try:
        families = {info[0] for info in socket.getaddrinfo(bare, None, type=socket.SOCK_STREAM)}
    except OSError:
        return socket.AF_INET  # the bind then fails with the resolver's own words
    return socket.AF_INET if socket.AF_INET in families or not families else socket.AF_INET6


def listen_error(host: str, port: int, exc: OSError) -> ConfigError:
    """Why the monitor cannot listen, with the fix for that reason: a port in use is not a missing address."""
    reason = exc.strerror or str(exc)
    if exc.errno == errno.EADDRINUSE:
        return ConfigError(
            f"cannot listen on {host}:{port}: {reason}",
            field="--port",
            fix="choose another port (--port 0 picks a free one), or stop the other monitor",
        )
    if exc.errno in (errno.EACCES, errno.EPERM):
        return ConfigError(
            f"cannot listen on {host}:{port}: {reason}", field="--port", fix="use a port above 1023 (default 8765)"
        )
    v6 = ":" in host
    return ConfigError(
        f"cannot listen on {host}: {reason}",
        field="--host",
        fix=(
            "this machine has no IPv6 loopback (or IPv6 is off): use --host 127.0.0.1"
            if v6
            else "give an address of this machine: 127.0.0.1 (the default), ::1, or with --allow-remote one of "
            "its network addresses"
        ),
    )
