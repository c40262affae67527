"""The monitor's HTTP server (stdlib): the page and its assets from the package, the campaign snapshot as JSON,
the campaign folder's own files read-only, and token-guarded pause/continue/stop requests.

Routes: GET / (page), GET /assets/NAME (packaged page files), GET /api/state (snapshot JSON),
GET /files/REL (a file inside the campaign folder; nothing outside it, symlinks included),
POST /api/control/ACTION (pause | continue | stop; header `X-Neatskin-Token` must carry the token, else 403).
Binding to anything but loopback needs allow_remote; with loopback the Host header must be loopback too,
so a web page elsewhere cannot read the campaign through DNS rebinding.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import logging
import mimetypes
import secrets
import threading
from collections.abc import Callable
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlsplit

from neatskin.errors import ConfigError, NeatskinError
from neatskin.monitor.listen import address_family, listen_error
from neatskin.monitor.state import CampaignView
from neatskin.rig.control import ACTIONS, request_control

log = logging.getLogger(__name__)

ASSETS = ("index.html", "app.js", "style.css")
TOKEN_HEADER = "X-Neatskin-Token"
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1", "[::1]")


def is_loopback(host: str) -> bool:
    if host.strip("[]") in ("localhost", "::1"):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def asset_bytes(name: str) -> bytes:
    """A packaged page file by its exact name (only the names in ASSETS exist)."""
    return resources.files("neatskin.monitor").joinpath("assets", name).read_bytes()


def resolve_inside(root: Path, rel: str) -> Path | None:
    """The file `rel` names under `root` (after decoding and resolving symlinks), or None if it lies outside
    the folder, is absolute, or is not a regular file."""
    if not rel or "\x00" in rel:
        return None
    if rel.startswith(("/", "\\")) or Path(rel).is_absolute() or ".." in Path(rel).parts:
        return None
    root = root.resolve()
    try:
        target = (root / rel).resolve(strict=True)
    except (OSError, RuntimeError):
        return None
    if not target.is_relative_to(root) or not target.is_file():
        return None
    return target


CONNECTION_TIMEOUT_S = 10.0  # a connection idle (or trickling) this long in one read or write is closed
MAX_CONNECTIONS = 32  # connections served at once (one thread each); the page needs one or two
MAX_BODY_BYTES = 4096  # a terminal line's JSON; nothing else is posted with a body


@dataclass(frozen=True)
class MonitorConfig:
    folder: Path
    token: str | None  # None: read-only, no controls at all
    remote: bool  # bound to a non-loopback address (the page says so)
    host: str
    port: int
    connection_timeout_s: float = CONNECTION_TIMEOUT_S
    max_connections: int = MAX_CONNECTIONS
    printer_port: str | None = None  # the page's printer terminal talks to it (monitor.terminal's rule)


class MonitorServer(ThreadingHTTPServer):
    """One thread per connection, at most `max_connections` at once (a connection beyond them gets a 503 and
    is closed at once), each closed after `connection_timeout_s` without progress: idle or slow clients cannot
    hold threads for ever."""

    daemon_threads = True

    def __init__(self, config: MonitorConfig) -> None:
        self.config = config
        self.view = CampaignView(config.folder)
        self.view_lock = threading.Lock()
        self.slots = threading.BoundedSemaphore(config.max_connections)
        self.terminal = None
        if config.printer_port is not None and config.token is not None:
            from neatskin.monitor.terminal import PrinterTerminal

            self.terminal = PrinterTerminal(config.folder, config.printer_port)
        self.address_family = address_family(config.host)
        super().__init__((config.host.strip("[]"), config.port), _Handler)

    def service_actions(self) -> None:
        if self.terminal is not None:  # between requests: a terminal left idle lets the printer port go
            self.terminal.release_if_idle()

    def server_close(self) -> None:
        if self.terminal is not None:
            self.terminal.close()
        super().server_close()

    def process_request(self, request, client_address) -> None:
        if not self.slots.acquire(blocking=False):
            self._refuse(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self.slots.release()
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self.slots.release()

    def _refuse(self, request) -> None:
        """Too many connections: a short 503, written without a thread, and the connection closed."""
        body = b"busy: too many open connections to this monitor; try again in a moment"
        head = (
            f"HTTP/1.0 503 Service Unavailable\r\nContent-Type: text/plain\r\nContent-Length: {len(body)}\r\n"
            "Retry-After: 1\r\nConnection: close\r\n\r\n"
        )
        try:
            request.settimeout(0.5)
            request.sendall(head.encode() + body)
        except OSError:
            pass
        finally:
            self.shutdown_request(request)

    @property
    def url(self) -> str:
        host, port = str(self.server_address[0]), int(self.server_address[1])
        shown = f"[{host}]" if ":" in host else host
        return f"http://{shown}:{port}/"


class _Handler(BaseHTTPRequestHandler):
    server: MonitorServer
    server_version = "neatskin-monitor"

    def setup(self) -> None:
        super().setup()
        # every read and write of this connection: an idle or trickling client is dropped, its thread freed
        self.connection.settimeout(self.server.config.connection_timeout_s)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the stdlib's signature
        log.debug("%s " + format, self.address_string(), *args)

    # ---- helpers ----

    def _send(self, status: int, body: bytes, content_type: str, extra: dict[str, str] | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Content-Security-Policy", "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'")
        for key, value in (extra or {}).items():
            self.send_header(key, value)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, status: int, payload: Any) -> None:
        self._send(status, json.dumps(payload, allow_nan=False).encode(), "application/json")

    def _error(self, status: int, message: str) -> None:
        self._json(status, {"error": message})

    def _host_ok(self) -> bool:
        if self.server.config.remote:
            return True
        host = self.headers.get("Host", "")
        name = host.rsplit(":", 1)[0] if not host.startswith("[") else host.split("]")[0] + "]"
        return name in LOOPBACK_NAMES or is_loopback(name)

    # ---- GET ----

    def do_HEAD(self) -> None:  # noqa: N802 - http.server's naming
        self.do_GET()

    def do_GET(self) -> None:  # noqa: N802
        if not self._host_ok():
            return self._error(HTTPStatus.FORBIDDEN, "unexpected Host header for a loopback monitor")
        raw_path = urlsplit(self.path).path
        if raw_path in ("/", "/index.html"):
            return self._send(HTTPStatus.OK, asset_bytes("index.html"), "text/html; charset=utf-8")
        if raw_path == "/favicon.ico":
            return self._send(HTTPStatus.NO_CONTENT, b"", "image/x-icon")
        if raw_path.startswith("/assets/"):
            name = unquote(raw_path[len("/assets/") :])
            if name not in ASSETS:
                return self._error(HTTPStatus.NOT_FOUND, "no such asset")
            kind = mimetypes.guess_type(name)[0] or "application/octet-stream"
            return self._send(HTTPStatus.OK, asset_bytes(name), f"{kind}; charset=utf-8")
        if raw_path == "/api/state":
            with self.server.view_lock:
                body = self.server.view.snapshot_json()
            cfg = self.server.config
            server = {
                "controls": cfg.token is not None,
                "remote": cfg.remote,
                "bound_to": cfg.host,
                "terminal": self.server.terminal is not None,
                "printer_port": cfg.printer_port if self.server.terminal is not None else None,
            }
            body = body[:-1] + b', "server": ' + json.dumps(server).encode() + b"}"
            return self._send(HTTPStatus.OK, body, "application/json")
        if raw_path.startswith("/files/"):
            target = resolve_inside(self.server.config.folder, unquote(raw_path[len("/files/") :]))
            if target is None:
                return self._error(HTTPStatus.NOT_FOUND, "no such file in this campaign folder")
            kind = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
            if target.suffix in (".log", ".toml", ".md"):
                kind = "text/plain; charset=utf-8"
            return self._send(HTTPStatus.OK, target.read_bytes(), kind)
        return self._error(HTTPStatus.NOT_FOUND, "not found")

    # ---- POST ----

    def _token_ok(self) -> bool:
        token = self.server.config.token
        given = self.headers.get(TOKEN_HEADER, "")
        return token is not None and hmac.compare_digest(given.encode(), token.encode())

    def _printer(self) -> None:
        """POST /api/printer, body {"line": "M114"}: one terminal line and the printer's reply (terminal's rule)."""
        from neatskin.monitor.terminal import TerminalRefused

        terminal = self.server.terminal
        if terminal is None:
            return self._error(HTTPStatus.NOT_FOUND, "no printer terminal: start the monitor with --printer-port PORT")
        if not self._token_ok():
            return self._error(HTTPStatus.FORBIDDEN, "the terminal needs the token printed by `neatskin monitor`")
        try:
            length = int(self.headers.get("Content-Length", "0"))
        except ValueError:
            length = -1
        if not 0 < length <= MAX_BODY_BYTES:
            return self._error(HTTPStatus.BAD_REQUEST, 'send {"line": "..."} as JSON')
        try:
            line = json.loads(self.rfile.read(length).decode("utf-8"))["line"]
            if not isinstance(line, str):
                raise TypeError(line)
        except (ValueError, KeyError, TypeError):
            return self._error(HTTPStatus.BAD_REQUEST, 'send {"line": "..."} as JSON')
        try:
            reply = terminal.send(line)
        except TerminalRefused as exc:
            return self._error(HTTPStatus.CONFLICT, str(exc))
        return self._json(HTTPStatus.OK, {"line": reply.line, "reply": reply.reply, "port": reply.port})

    def do_POST(self) -> None:  # noqa: N802
        if not self._host_ok():
            return self._error(HTTPStatus.FORBIDDEN, "unexpected Host header for a loopback monitor")
        path = urlsplit(self.path).path
        if path == "/api/printer":
            return self._printer()
        action = path[len("/api/control/") :] if path.startswith("/api/control/") else ""
        if action not in ACTIONS:
            return self._error(HTTPStatus.NOT_FOUND, "not found")
        if not self._token_ok():
            return self._error(
                HTTPStatus.FORBIDDEN,
                "controls need the token printed by `neatskin monitor` in its terminal"
                if self.server.config.token is not None
                else "this monitor is read-only (--read-only)",
            )
        try:
            request = request_control(self.server.config.folder, action, by="monitor page")
        except NeatskinError as exc:
            return self._error(HTTPStatus.CONFLICT, str(exc))
        return self._json(HTTPStatus.OK, {"action": action, "id": request.request_id})


def make_server(
    folder: str | Path,
    *,
    host: str = "127.0.0.1",
    port: int = 8765,
    allow_remote: bool = False,
    token: str | None = None,
    read_only: bool = False,
    printer_port: str | None = None,
    **limits: Any,
) -> MonitorServer:
    """A monitor server for `folder`, bound but not yet serving. token None and not read_only: a random one.
    `limits`: connection_timeout_s, max_connections (MonitorConfig's defaults otherwise)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():  # a folder not made yet is fine: a campaign may be starting
        raise ConfigError(
            "not a campaign folder (a file)",
            file=str(folder),
            fix="give the folder `neatskin campaign run --out` wrote",
        )
    remote = not is_loopback(host)
    if remote and not allow_remote:
        raise ConfigError(
            f"--host {host} would show the campaign (and, with the token, its controls) to the network",
            field="--host",
            fix="keep the default 127.0.0.1, or add --allow-remote if that is what you want",
        )
    if read_only:
        token = None
    elif token is None:
        token = secrets.token_urlsafe(16)
    try:
        return MonitorServer(MonitorConfig(folder, token, remote, host, port, printer_port=printer_port, **limits))
    except OSError as exc:
        raise listen_error(host, port, exc) from exc


def serve(
    folder: str | Path,
    *,
    host: str = "127.0.0.1",
    port: int = 8765,
    allow_remote: bool = False,
    token: str | None = None,
    read_only: bool = False,
    printer_port: str | None = None,
    announce: Callable[[str], None] = log.info,
) -> None:
    """Serve the monitor until Ctrl-C; `announce` receives the URL and the control token."""
    server = make_server(
        folder,
        host=host,
        port=port,
        allow_remote=allow_remote,
        token=token,
        read_only=read_only,
        printer_port=printer_port,
    )
    cfg = server.config
    announce(f"neatskin monitor: {cfg.folder} on {server.url}")
    if not cfg.folder.exists():
        announce("  the folder does not exist yet: the page fills in when a campaign creates it")
    if cfg.remote:
        announce(f"  bound to {cfg.host}: anyone who can reach this address sees the page (--allow-remote)")
    if cfg.token is None:
        announce("  read-only: no controls")
    else:
        announce(f"  control token (paste it in the page to pause/continue/stop): {cfg.token}")
        announce(f"  or open {server.url}#token={cfg.token}")
    if server.terminal is not None:
        announce(f"  printer terminal on {cfg.printer_port}: works while no campaign holds this folder")
    elif printer_port is not None:
        announce("  no printer terminal: a read-only monitor has no token to guard it")
    try:
        server.serve_forever(poll_interval=0.25)
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
