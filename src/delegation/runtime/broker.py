"""Brokers we start ourselves: the embedded amqtt default and a private mosquitto.

Both listen on 127.0.0.1 only, on a free port, and are started and stopped explicitly (or as
context managers). `EmbeddedBroker` is the default when no broker is configured: pure Python,
MQTT 3.1.1 only, ~5k msg/s (docs/protocol.md §10); `BrokerProcess` runs it in a child process
(the demo's choice: its own GIL). `PrivateMosquitto` is for tests and benchmarks
where the `mosquitto` binary exists.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import pwd
import random
import selectors
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from pathlib import Path
from typing import IO, Any, Self

from delegation.errors import DelegationError
from delegation.runtime.lifecycle import StartStop
from delegation.runtime.settings import BrokerSettings

log = logging.getLogger(__name__)

LOOPBACK = "127.0.0.1"


class BrokerError(DelegationError):
    """A broker we tried to start did not come up (or did not stop)."""


def _ephemeral_range() -> tuple[int, int]:
    try:
        lo, hi = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
        return int(lo), int(hi)
    except (OSError, ValueError):
        return 32768, 60999


def free_port(host: str = LOOPBACK, stable: bool = False) -> int:
    """A TCP port that is free on ``host`` right now.

    With ``stable``, the port is outside the kernel's ephemeral range, so that it stays free for
    a listener that must come back on the same port (outgoing connections never take it).
    """
    if not stable:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind((host, 0))
            return int(s.getsockname()[1])
    lo, _ = _ephemeral_range()
    candidates = list(range(max(1024, lo - 12000), lo))
    random.shuffle(candidates)
    for port in candidates[:500]:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
            return port
    raise BrokerError("no free port outside the ephemeral range")


def wait_for_port(host: str, port: int, deadline: float) -> bool:
    """True once ``host:port`` accepts a TCP connection, False at ``deadline`` (monotonic)."""
    while time.monotonic() < deadline:
        try:
            with socket.create_connection((host, port), timeout=0.5):
                return True
        except OSError:
            time.sleep(0.05)  # polling a port that is not open yet: nothing to wait on
    return False


class _Drain:
    """Reads a child's output stream to its end on a thread, logging each line: a pipe nobody
    reads fills (64 kB) and blocks the child's next write. The last lines are kept for an error
    message when the child does not start."""

    def __init__(self, stream: IO[bytes], name: str, level: int = logging.WARNING) -> None:
        self.lines: deque[str] = deque(maxlen=20)
        self._stream, self._name, self._level = stream, name, level
        self._thread = threading.Thread(target=self._run, name=f"drain-{name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        with contextlib.suppress(OSError, ValueError):  # closed under us: the child is gone
            for raw in iter(self._stream.readline, b""):
                line = raw.decode(errors="replace").rstrip()
                if line:
                    self.lines.append(line)
                    log.log(self._level, "%s: %s", self._name, line)

    def text(self, timeout: float = 1.0) -> str:
        """What it said last (waiting up to ``timeout`` for the child's end of the stream)."""
        self._thread.join(timeout)
        return "\n".join(self.lines)


class _Amqtt(StartStop, ABC):
    """What the two ways of running amqtt share: loopback only, 3.1.1 settings, a context."""

    kind = "amqtt"

    def __init__(self, host: str = LOOPBACK, port: int = 0) -> None:
        if host not in (LOOPBACK, "localhost", "::1"):
            raise BrokerError(f"the embedded broker listens on loopback only, not {host!r}")
        self.host = LOOPBACK if host == "localhost" else host
        self._requested_port = port
        self.port = 0

    @abstractmethod
    def start(self, timeout: float = 10.0) -> Self:
        """Listen (on a free port unless one was asked for); raise `BrokerError` if it cannot."""

    @abstractmethod
    def stop(self, timeout: float = 10.0) -> None:
        """Stop listening and free everything (idempotent)."""

    def settings(self) -> BrokerSettings:
        """Client settings for this broker (MQTT 3.1.1: amqtt speaks nothing else)."""
        return BrokerSettings(host=self.host, port=self.port, protocol="3.1.1")


class EmbeddedBroker(_Amqtt):
    """amqtt in-process, on its own thread and event loop, bound to 127.0.0.1 on a free port."""

    def __init__(self, host: str = LOOPBACK, port: int = 0) -> None:
        super().__init__(host, port)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._broker: Any = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    def config(self) -> dict[str, Any]:
        """amqtt's configuration: one TCP listener, anonymous clients allowed, nothing else."""
        return {
            "listeners": {
                "default": {"type": "tcp", "bind": f"{self.host}:{self._requested_port}"},
            },
            "plugins": {
                "amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True},
            },
        }

    def start(self, timeout: float = 10.0) -> EmbeddedBroker:
        if self._thread is not None:
            return self
        self._ready.clear()
        self._error = None
        self._thread = threading.Thread(target=self._run, name="amqtt-broker", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            self.stop()
            raise BrokerError(f"amqtt did not start within {timeout}s")
        if self._error is not None:
            error = self._error
            self.stop()
            raise BrokerError(f"amqtt did not start: {error}") from error
        log.info("embedded amqtt broker on %s:%d", self.host, self.port)
        return self

    def _run(self) -> None:
        from amqtt.broker import Broker

        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)

        async def boot() -> None:
            broker = Broker(self.config())
            await broker.start()
            self._broker = broker
            # The listener was bound to port 0; read the port the OS chose.
            server = broker._servers["default"].instance
            self.port = int(server.sockets[0].getsockname()[1])

        try:
            loop.run_until_complete(boot())
        except BaseException as exc:  # report any start failure to start()
            self._error = exc
            self._ready.set()
            loop.close()
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            with contextlib.suppress(Exception):
                pending = [t for t in asyncio.all_tasks(loop) if not t.done()]
                for task in pending:
                    task.cancel()
                loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
            loop.close()

    @staticmethod
    async def _shutdown(broker: Any, timeout: float) -> None:
        """Close the listeners first (the port is free at once), then amqtt's own shutdown.

        amqtt 0.12's shutdown can hang while a client is still connected (it waits for the
        client's reader); after ``timeout`` it is cancelled, which closes the connections.
        """
        for server in list(broker._servers.values()):
            instance = getattr(server, "instance", None)
            if instance is not None:
                instance.close()
        try:
            await asyncio.wait_for(broker.shutdown(), timeout)
        except (Exception, asyncio.CancelledError) as exc:
            log.debug("amqtt shutdown did not complete (%r); cancelling what is left", exc)

    def stop(self, timeout: float = 10.0) -> None:
        """Shut the broker down and join its thread (idempotent)."""
        thread, loop, broker = self._thread, self._loop, self._broker
        if thread is None:
            return
        # Closing connections with QoS 1 messages in flight makes amqtt log a warning per message
        # ("Received PUBACK for unknown pending message", "N messages not broadcasted"): 139 lines
        # at the end of a 10-unit demo. They describe the shutdown itself, not a fault.
        amqtt_log = logging.getLogger("amqtt")
        level = amqtt_log.level
        amqtt_log.setLevel(max(logging.ERROR, level))
        try:
            self._stop(thread, loop, broker, timeout)
        finally:
            amqtt_log.setLevel(level)

    def _stop(
        self,
        thread: threading.Thread,
        loop: asyncio.AbstractEventLoop | None,
        broker: Any,
        timeout: float,
    ) -> None:
        if loop is not None and broker is not None and loop.is_running():
            fut = asyncio.run_coroutine_threadsafe(self._shutdown(broker, 3.0), loop)
            try:
                fut.result(timeout)
            except Exception as exc:  # shutting down: log, then stop the loop anyway
                log.warning("amqtt shutdown: %r", exc)
        if loop is not None and loop.is_running():
            loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout)
        if thread.is_alive():
            raise BrokerError("amqtt thread did not stop")
        self._thread = None
        self._broker = None
        self._loop = None



class BrokerProcess(_Amqtt):
    """The embedded amqtt broker in a child Python process (what `LocalSystem` and the demo use).

    Why not a thread: the demo runs the simulated fleet (two threads a unit), the engine and the
    service in one process, and amqtt's event loop then competes with all of them for one GIL. At
    20 units x 100 tasks the loop starved: clients timed out waiting for PUBACKs, the engine did
    not get its start-tst within 15 s and the mission failed; with the same broker in its own
    process it succeeded. The child needs nothing the package does not ship, listens on loopback
    only, ignores Ctrl-C (the parent stops it after its clients) and exits when its stdin closes,
    so a parent killed with -9 leaves no broker behind.
    """

    def __init__(self, host: str = LOOPBACK, port: int = 0) -> None:
        super().__init__(host, port)
        self._proc: subprocess.Popen[bytes] | None = None
        self._drains: list[_Drain] = []

    def start(self, timeout: float = 15.0) -> BrokerProcess:
        if self._proc is not None:
            return self
        self._proc = subprocess.Popen(
            self._command(),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        assert self._proc.stderr is not None and self._proc.stdout is not None
        self._drains = [_Drain(self._proc.stderr, "amqtt child")]
        line = _read_line(self._proc, timeout)
        self._drains.append(_Drain(self._proc.stdout, "amqtt child", logging.INFO))
        if not line.startswith("port "):
            error = self._drains[0].text() if self._proc.poll() is not None else ""
            self.stop()
            raise BrokerError(f"amqtt did not start within {timeout}s: {error or line or 'silent'}")
        self.port = int(line.split()[1])
        log.info("embedded amqtt broker (own process) on %s:%d", self.host, self.port)
        return self

    def _command(self) -> list[str]:
        return [sys.executable, "-m", "delegation.runtime.broker",
                "--host", self.host, "--port", str(self._requested_port)]

    def stop(self, timeout: float = 10.0) -> None:
        """Close its stdin (it shuts down and exits), then terminate or kill it if it lingers."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        with contextlib.suppress(OSError):
            if proc.stdin:
                proc.stdin.close()
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            _end(proc)
        for drain in self._drains:  # the child is gone: its streams end (what is buffered in
            drain.text(timeout)     # the pipe is still read and logged: under load, over 1 s)
        self._drains = []
        for stream in (proc.stdout, proc.stderr):
            if stream:
                stream.close()

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None



def _end(proc: subprocess.Popen[bytes], grace: float = 5.0) -> None:
    """SIGTERM a child still running, SIGKILL it after ``grace`` seconds; reap it."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(grace)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(grace)


def _read_line(proc: subprocess.Popen[bytes], timeout: float) -> str:
    """The child's first stdout line, or "" when it exits or says nothing within ``timeout``."""
    assert proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout):
            return ""
    return proc.stdout.readline().decode(errors="replace").strip()


def serve_embedded(argv: list[str] | None = None) -> int:
    """``python -m delegation.runtime.broker``: the child side of `BrokerProcess`."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m delegation.runtime.broker")
    parser.add_argument("--host", default=LOOPBACK)
    parser.add_argument("--port", type=int, default=0)
    args = parser.parse_args(argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group: parent stops us
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    logging.basicConfig(level=logging.ERROR)
    with EmbeddedBroker(args.host, args.port) as broker:
        sys.stdout.write(f"port {broker.port}\n")
        sys.stdout.flush()

        def stdin_closed() -> None:
            sys.stdin.buffer.read()  # returns at EOF: the parent closed it or died
            done.set()

        threading.Thread(target=stdin_closed, name="parent-watch", daemon=True).start()
        done.wait()
    return 0


MOSQUITTO_CONF = """\
listener {port} {host}
{listener_extra}allow_anonymous {anonymous}
persistence false
set_tcp_nodelay true
max_queued_messages 0
log_dest file {log}
log_type error
log_type warning
"""


def mosquitto_binary() -> str | None:
    """The ``mosquitto`` executable, from PATH or /usr/sbin; None when not installed."""
    found = shutil.which("mosquitto")
    if found:
        return found
    for candidate in ("/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto"):
        if Path(candidate).is_file():
            return candidate
    return None


class PrivateMosquitto(StartStop):
    """A mosquitto child process on a free loopback port, with the settings docs/protocol.md §10
    asks for."""

    kind = "mosquitto"

    def __init__(
        self,
        binary: str | None = None,
        host: str = LOOPBACK,
        *,
        certfile: str | None = None,
        keyfile: str | None = None,
        password_file: str | None = None,
        acl_file: str | None = None,
        cafile: str | None = None,
        require_certificate: bool = False,
    ) -> None:
        """``certfile``/``keyfile`` make the listener TLS; ``password_file`` (made with
        ``mosquitto_passwd``) turns anonymous access off; ``acl_file`` limits who may read and
        write which topics; ``cafile`` with ``require_certificate`` asks clients for a
        certificate signed by that CA."""
        found = binary or mosquitto_binary()
        if found is None:
            raise BrokerError("mosquitto is not installed")
        if (certfile is None) != (keyfile is None):
            raise BrokerError("a TLS listener needs both certfile and keyfile")
        if require_certificate and (cafile is None or certfile is None):
            raise BrokerError("client certificates need a TLS listener and the cafile")
        self.binary = found
        self.host = host
        self.port = 0
        self.tls = certfile is not None
        self._files = {
            "certfile": certfile,
            "keyfile": keyfile,
            "cafile": cafile,
            "password_file": password_file,
            "acl_file": acl_file,
        }
        self._require_certificate = require_certificate
        self._anonymous = "false" if password_file else "true"
        self._proc: subprocess.Popen[bytes] | None = None
        self._drain: _Drain | None = None
        self._dir: tempfile.TemporaryDirectory[str] | None = None

    @property
    def pid(self) -> int | None:
        """The mosquitto process's id while it runs (benchmarks read its CPU time)."""
        return self._proc.pid if self._proc is not None else None

    def start(
        self, timeout: float = 10.0, attempts: int = 3, port: int | None = None
    ) -> PrivateMosquitto:
        """Start on a free port, or on ``port`` (a restart after `kill`: clients come back)."""
        if self._proc is not None:
            return self
        self._cleanup_dir()
        self._dir = tempfile.TemporaryDirectory(prefix="delegation-mosquitto-")
        extra = self._stage_files(Path(self._dir.name))
        last = ""
        for _ in range(attempts):
            # To come back on the same port later, start on ``free_port(stable=True)``.
            self.port = port or free_port(self.host)
            conf = Path(self._dir.name) / "mosquitto.conf"
            logfile = Path(self._dir.name) / "mosquitto.log"
            conf.write_text(
                MOSQUITTO_CONF.format(
                    port=self.port,
                    host=self.host,
                    log=logfile,
                    listener_extra=extra,
                    anonymous=self._anonymous,
                )
            )
            self._proc = subprocess.Popen(
                [self.binary, "-c", str(conf)],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
            )
            assert self._proc.stderr is not None
            self._drain = _Drain(self._proc.stderr, "mosquitto")
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline and self._proc.poll() is None:
                if wait_for_port(self.host, self.port, min(deadline, time.monotonic() + 0.5)):
                    log.info("private mosquitto on %s:%d", self.host, self.port)
                    return self
            # It exited (port taken between probe and bind?) or never opened the port.
            last = self._collect_failure(logfile)
            self._kill()
        self._cleanup_dir()
        raise BrokerError(f"mosquitto did not start: {last}")

    def _stage_files(self, workdir: Path) -> str:
        """Copy cert, key and password file next to the config; the config lines for them.

        Started as root, mosquitto drops to the ``mosquitto`` user, which must be able to read
        them and write its log: the working directory and the copies are handed to that user.
        """
        lines = ""
        for option, source in self._files.items():
            if source is None:
                continue
            target = workdir / option
            shutil.copyfile(source, target)
            target.chmod(0o600)
            lines += f"{option} {target}\n"
        if self._require_certificate:
            lines += "require_certificate true\n"
        if os.geteuid() == 0:
            try:
                pw = pwd.getpwnam("mosquitto")
            except KeyError:
                return lines
            for path in (workdir, *workdir.iterdir()):
                os.chown(path, pw.pw_uid, pw.pw_gid)
        return lines

    def _collect_failure(self, logfile: Path) -> str:
        text = ""
        if self._proc is not None and self._proc.poll() is not None and self._drain:
            text = self._drain.text().strip()
        if not text and logfile.exists():
            text = logfile.read_text(errors="replace").strip()
        return text or "port did not open in time"

    def _kill(self) -> None:
        proc, self._proc = self._proc, None
        if proc is None:
            return
        _end(proc)
        self._close_stderr(proc)

    def _cleanup_dir(self) -> None:
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None

    def kill(self) -> None:
        """SIGKILL the broker (fault tests: an outage); `start` with ``port`` brings it back."""
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait(5)
        if proc is not None:
            self._close_stderr(proc)

    def _close_stderr(self, proc: subprocess.Popen[bytes]) -> None:
        """Once the child is gone: let the drain read the end of its stderr, then close it."""
        drain, self._drain = self._drain, None
        if drain is not None:
            drain.text()
        if proc.stderr:
            proc.stderr.close()

    def stop(self) -> None:
        """Terminate the process and remove its files (idempotent)."""
        self._kill()
        self._cleanup_dir()

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def settings(self) -> BrokerSettings:
        """Client settings (anonymous, and without TLS trust: add those for such a broker)."""
        return BrokerSettings(host=self.host, port=self.port, protocol="5", tls=self.tls)


#: Either kind of broker we start ourselves.
LocalBroker = EmbeddedBroker | PrivateMosquitto


if __name__ == "__main__":
    sys.exit(serve_embedded())
