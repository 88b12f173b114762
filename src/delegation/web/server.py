"""uvicorn in a thread: the page beside the service, the demo, or alone (``delegation ui``).

Port 0 picks a free port; `WebServer.url` is the real one once `start` returns. `stop` ends the
event streams and the server within a second or two (open streams are not waited for longer).
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import uvicorn
from starlette.applications import Starlette

from delegation.errors import DelegationError
from delegation.runtime.lifecycle import StartStop
from delegation.web.auth import is_loopback_name

log = logging.getLogger(__name__)


class WebServerError(DelegationError):
    """The page's server could not start (address in use, bad host)."""


def parse_http(value: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:8765`` for IPv6; a bare ``PORT`` means 127.0.0.1); ValueError."""
    text = value.strip()
    if text.isdigit():
        host, port_text = "127.0.0.1", text
    elif text.startswith("["):
        host, sep, port_text = text[1:].partition("]:")
        if not sep:
            raise ValueError(f"{value!r}: expected [HOST]:PORT")
    else:
        host, sep, port_text = text.rpartition(":")
        if not sep or not host:
            raise ValueError(f"{value!r}: expected HOST:PORT (e.g. 127.0.0.1:8765)")
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise ValueError(f"{value!r}: the port must be 0-65535 (0: any free port)")
    return host, int(port_text)


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and ``localhost``."""
    return is_loopback_name(host.strip("[]"))


class WebServer(StartStop):
    """One uvicorn server for an app, in a daemon thread."""

    def __init__(self, app: Starlette, host: str = "127.0.0.1", port: int = 0) -> None:
        self.app = app
        self.host = host
        self.port = port
        config = uvicorn.Config(app, host=host, port=port, log_level="warning",
                                access_log=False, lifespan="off", timeout_graceful_shutdown=1,
                                timeout_keep_alive=5)
        self._server = uvicorn.Server(config)
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}"

    def _run(self) -> None:
        try:
            self._server.run()
        except BaseException as exc:  # reported by start(); SystemExit from a failed bind too
            self._error = exc

    def start(self, timeout: float = 10.0) -> WebServer:
        """Serve; the real port is known when this returns. `WebServerError` when it cannot."""
        self._thread = threading.Thread(target=self._run, name="ui-http", daemon=True)
        self._thread.start()
        done = threading.Event()

        def started() -> bool:
            return bool(self._server.started) or not self._thread or not self._thread.is_alive()

        while not started() and not done.wait(0.02):  # uvicorn sets a plain flag
            timeout -= 0.02
            if timeout <= 0:
                self.stop()
                raise WebServerError(f"the page's server did not start on {self.url}")
        if not self._server.started:
            raise WebServerError(f"cannot serve the page on {self.host}:{self.port} "
                                 f"(address in use, or not an address of this machine)")
        servers: Any = getattr(self._server, "servers", [])
        for srv in servers:
            for sock in srv.sockets:
                self.port = int(sock.getsockname()[1])
                break
        log.info("operator page on %s", self.url)
        return self

    def stop(self) -> None:
        """End the streams and the server (idempotent)."""
        page = getattr(self.app.state, "page", None)
        if page is not None:
            page.stopping.set()
        self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
