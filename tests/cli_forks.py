"""``python -m delegation ARGS`` without paying for Python's start and the CLI's imports each time.

A test that runs the CLI as an operator does (a child process: its exit code, its stdout and
stderr, never a traceback) spends about 0.3 s of CPU per command importing numpy, shapely,
pydantic and the CLI before the command even starts; the suite runs a few hundred. This module is
both sides of a small fork server:

* run as a script, it imports the CLI once, then for each request read from stdin (one JSON line:
  argv, environment, working directory) forks a child that sets them, points its stdin at
  /dev/null and its stdout and stderr at files, and runs ``delegation`` as ``python -m`` does
  (``runpy``, ``__main__``). The child ends as that interpreter would: ``SystemExit`` codes,
  atexit handlers, a traceback and exit 1 for an uncaught exception. The answer (exit code and
  both outputs) goes back as one JSON line;
* `run` is `subprocess.run` for the CLI: through a server of this process's own (`CliForks`,
  started on first use, one at a time; it ends when this process closes its stdin, at exit);
* `spawn` and `spawn_piped` are `subprocess.Popen` for the long-running commands (``serve``,
  ``engine``, ``sim``, ``ui``, ``demo``): the server forks the command and answers its pid at
  once; `Forked` waits for its exit on a pidfd and asks the server (its parent) for the code.
  Signals go straight to its pid. Output goes to a file, or to FIFOs read as Popen's pipes;
* `relay` lets a shell script do the same: while it is open, ``python cli_forks.py --via SOCKET
  ARGS`` (a client importing only the standard library, ~20 ms) has the test process run
  ``delegation ARGS`` through `run` with the client's environment and directory, writes the
  command's stdout and stderr as its own and exits with its code (the deployment doc's session).

Each command is still its own process, forked from a parent that has imported the CLI and done
nothing else, so commands share nothing. What this does not cover is the import itself: a test
whose subject is a fresh interpreter (`test_validate_cli`'s console script) or a process group
(the bench's Ctrl-C tests) still starts ``python -m delegation`` with `subprocess`.
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import importlib
import io
import json
import os
import runpy
import select
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO

ROOT = Path(__file__).resolve().parents[1]
#: The server's answers go out on this descriptor (a copy of its stdout; closed in children).
_REPLIES = -1
#: What most commands import: the CLI, planning, the broker client, bench, the tables.
PRELOAD = ("delegation.cli", "delegation.cli.demo", "delegation.allocation.planner",
           "delegation.scenario", "delegation.runtime.client", "delegation.messages",
           "delegation.bench.runner", "rich.console", "rich.table",
           # and what ``serve``, ``engine`` and ``sim`` import (`spawn`)
           "delegation.cli.serve", "delegation.local", "delegation.service.store")


# --------------------------------------------------------------------------- the server side


def _child(request: dict[str, Any], out: int, err: int) -> None:
    """In the forked child: become ``python -m delegation ARGV`` (never returns)."""
    os.close(_REPLIES)
    devnull = os.open(os.devnull, os.O_RDONLY)
    os.dup2(devnull, 0)
    os.dup2(out, 1)
    os.dup2(err, 2)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    sys.path[0] = os.getcwd()  # as ``python -m`` has it, and after it PYTHONPATH's folders
    sys.path[1:1] = [p for p in request["env"].get("PYTHONPATH", "").split(os.pathsep)
                     if p and p not in sys.path]
    if request["env"].get("PYTHONUNBUFFERED"):  # as a new interpreter would read it (-u)
        sys.stdout, sys.stderr = (
            io.TextIOWrapper(open(fd, "wb", buffering=0, closefd=False),  # noqa: SIM115
                             encoding=stream.encoding, errors=stream.errors, write_through=True)
            for fd, stream in ((1, sys.stdout), (2, sys.stderr)))
    sys.argv = ["delegation", *request["argv"]]
    runpy.run_module("delegation", run_name="__main__", alter_sys=True)
    raise SystemExit(0)  # the interpreter's own exit: atexit handlers, non-daemon threads


def _exits_within(pid: int, timeout: float) -> bool:
    """True once the child ``pid`` has exited (not yet reaped), False at the deadline."""
    if hasattr(os, "pidfd_open"):  # Linux: a descriptor that becomes readable at the exit
        exited = os.pidfd_open(pid)
        try:
            return bool(select.select([exited], [], [], timeout)[0])
        finally:
            os.close(exited)
    exited = threading.Event()  # elsewhere: a thread waits for the exit without reaping it

    def wait() -> None:
        with contextlib.suppress(ChildProcessError):
            os.waitid(os.P_PID, pid, os.WEXITED | os.WNOWAIT)
        exited.set()

    threading.Thread(target=wait, daemon=True).start()
    return exited.wait(timeout)


def _spawn(request: dict[str, Any]) -> dict[str, Any]:
    """Fork one command and answer its pid at once; its stdout and stderr append to a file.
    It is reaped by a later ``reap`` request (the test waits for its exit on a pidfd)."""
    log = os.open(request["log"], os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    err = os.open(request["err"], os.O_WRONLY | os.O_APPEND) if "err" in request else log
    pid = os.fork()
    if pid == 0:
        _child(request, log, err)
    os.close(log)
    if err != log:
        os.close(err)
    return {"pid": pid}


def _reap(pid: int) -> dict[str, Any]:
    """The exit code of a spawned command that has exited."""
    _, status = os.waitpid(pid, 0)
    return {"code": os.waitstatus_to_exitcode(status)}


def _answer(request: dict[str, Any]) -> dict[str, Any] | None:
    """Fork one command and wait for it; None in the child (which then exits)."""
    if "log" in request:
        return _spawn(request)
    if "reap" in request:
        return _reap(int(request["reap"]))
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        pid = os.fork()
        if pid == 0:
            _child(request, out.fileno(), err.fileno())
        if not _exits_within(pid, float(request["timeout"])):
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return {"timeout": True}
        _, status = os.waitpid(pid, 0)
        out.seek(0)
        err.seek(0)
        return {"code": os.waitstatus_to_exitcode(status),
                "stdout": out.read().decode("utf-8", "replace"),
                "stderr": err.read().decode("utf-8", "replace")}


def serve() -> None:
    """Answer requests on stdin until it closes."""
    for name in PRELOAD:  # paid once, here (a module renamed since is only not preloaded)
        with contextlib.suppress(ImportError):
            importlib.import_module(name)

    # Every child would otherwise copy the pages of the preloaded heap as its collector and its
    # interpreter's finalisation walk them: frozen objects are never collected nor traversed.
    gc.collect()
    gc.freeze()
    global _REPLIES
    _REPLIES = os.dup(1)
    replies = os.fdopen(_REPLIES, "w")
    for line in sys.stdin:
        answer = _answer(json.loads(line))
        replies.write(json.dumps(answer) + "\n")
        replies.flush()


# --------------------------------------------------------------------------- the test side


class CliForks:
    """The fork server, started on first use; `run` is `subprocess.run` for the CLI."""

    def __init__(self) -> None:
        self._proc: subprocess.Popen[str] | None = None
        self._lock = threading.Lock()

    def _server(self) -> subprocess.Popen[str]:
        if self._proc is None or self._proc.poll() is not None:
            env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
            self._proc = subprocess.Popen([sys.executable, __file__], env=env, text=True,
                                          stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        return self._proc

    def ask(self, request: dict[str, Any]) -> dict[str, Any]:
        """One request to the server, one answer."""
        with self._lock:
            proc = self._server()
            assert proc.stdin is not None and proc.stdout is not None
            proc.stdin.write(json.dumps(request) + "\n")
            proc.stdin.flush()
            line = proc.stdout.readline()
        if not line:
            raise RuntimeError("the CLI fork server ended")
        return dict(json.loads(line))

    def run(self, argv: list[str], env: dict[str, str], cwd: Path | str | None = None,
            timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
        """``python -m delegation *argv`` with exactly ``env``, in ``cwd``, stdin empty."""
        answer = self.ask({"argv": argv, "env": env, "cwd": str(cwd or os.getcwd()),
                           "timeout": timeout})
        if answer.get("timeout"):
            raise subprocess.TimeoutExpired(["delegation", *argv], timeout)
        return subprocess.CompletedProcess(["delegation", *argv], answer["code"],
                                           answer["stdout"], answer["stderr"])

    def close(self) -> None:
        if self._proc is not None:
            assert self._proc.stdin is not None
            self._proc.stdin.close()
            try:
                self._proc.wait(10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(10)
            self._proc = None


class Forked:
    """A `spawn`ed command: the part of `subprocess.Popen` the tests use. Its parent is the fork
    server, so its exit is seen on a pidfd and its code asked of the server."""

    def __init__(self, forks: CliForks, argv: list[str], pid: int) -> None:
        self.args, self.pid, self._forks = ["delegation", *argv], pid, forks
        self.returncode: int | None = None
        self.stdout: TextIO | None = None  # set by `spawn_piped`
        self.stderr: TextIO | None = None  # set by `spawn_piped(..., stderr=True)`
        self._exited = os.pidfd_open(pid)  # readable once the process has exited
        weakref.finalize(self, os.close, self._exited)  # not before: another thread may wait
        self._reaping = threading.Lock()

    def poll(self) -> int | None:
        return self._returncode_within(0.0)

    def wait(self, timeout: float | None = None) -> int:
        code = self._returncode_within(timeout)
        if code is None:
            raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        return code

    def _returncode_within(self, timeout: float | None) -> int | None:
        if self.returncode is None and select.select([self._exited], [], [], timeout)[0]:
            with self._reaping:  # reaped once, whichever thread asks first
                if self.returncode is None:
                    self.returncode = int(self._forks.ask({"reap": self.pid})["code"])
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.returncode is None:  # never a pid the server has reaped (and may be reused)
            os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def communicate(self, timeout: float | None = None) -> tuple[str, str]:
        """The rest of its piped output and errors, read to their ends, then its exit."""
        read: dict[int, str] = {}
        readers = [threading.Thread(target=lambda i=i, s=s: read.__setitem__(i, s.read()),
                                    daemon=True)
                   for i, s in enumerate((self.stdout, self.stderr)) if s is not None]
        for reader in readers:
            reader.start()
        deadline = None if timeout is None else time.monotonic() + timeout
        for reader in readers:
            reader.join(None if deadline is None else max(0.0, deadline - time.monotonic()))
            if reader.is_alive():
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        self.wait(None if deadline is None else max(0.0, deadline - time.monotonic()))
        return read.get(0, ""), read.get(1, "")

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


_shared = CliForks()
atexit.register(_shared.close)


def run(argv: list[str], env: dict[str, str], cwd: Path | str | None = None,
        timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    """``python -m delegation *argv`` with exactly ``env``, in ``cwd`` (`CliForks.run`)."""
    return _shared.run(argv, env, cwd, timeout)


def spawn(argv: list[str], env: dict[str, str], log: Path, cwd: Path | str | None = None,
          err: Path | None = None) -> Forked:
    """``python -m delegation *argv`` started as `subprocess.Popen` would, without its imports:
    forked by the server, stdin empty, stdout appended to ``log`` and stderr to ``err`` (default:
    ``log`` too). Where no pidfd exists (not Linux), a real `subprocess.Popen` of the command."""
    if not hasattr(os, "pidfd_open"):
        with log.open("ab") as out, (err or log).open("ab") as errors:
            return subprocess.Popen(  # type: ignore[return-value]
                [sys.executable, "-m", "delegation", *argv], stdin=subprocess.DEVNULL,
                stdout=out, stderr=errors, env=env, cwd=cwd)
    request = {"argv": argv, "env": env, "cwd": str(cwd or os.getcwd()), "log": str(log)}
    if err is not None:
        request["err"] = str(err)
    return Forked(_shared, argv, int(_shared.ask(request)["pid"]))


def _fifo(workdir: Path) -> tuple[Path, int]:
    """A new FIFO in ``workdir`` and its read end, opened without waiting for a writer."""
    fifo = workdir / f"cli-forks-{len(list(workdir.glob('cli-forks-*')))}.fifo"
    os.mkfifo(fifo)
    return fifo, os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)


def spawn_piped(argv: list[str], env: dict[str, str], workdir: Path,
                cwd: Path | str | None = None, stderr: bool | Path = False) -> Forked:
    """`spawn` with its output on a pipe read from ``.stdout`` (text), as ``Popen(stdout=PIPE,
    stderr=STDOUT, text=True)``; with ``stderr=True`` its errors on another, ``.stderr``, as
    ``stderr=PIPE``; with a path, its errors to that file (``os.devnull``: ``DEVNULL``). The
    pipes are FIFOs in ``workdir``, opened for reading before the server opens them for
    writing, so neither side blocks; each ends when the command and whatever inherited it have
    exited."""
    out, out_fd = _fifo(workdir)
    err, err_fd = _fifo(workdir) if stderr is True else (stderr or None, -1)
    try:
        forked = spawn(argv, env, out, cwd, err)
    except BaseException:
        for fd in (out_fd, err_fd):
            if fd >= 0:
                os.close(fd)
        raise
    os.set_blocking(out_fd, True)
    forked.stdout = os.fdopen(out_fd, "r")
    if err_fd >= 0:
        os.set_blocking(err_fd, True)
        forked.stderr = os.fdopen(err_fd, "r")
    return forked


# --------------------------------------------------------------------------- shell scripts


#: Exit code of a relayed command that outlived its timeout (as coreutils' ``timeout``).
TIMED_OUT = 124


def _relay_one(connection: socket.socket) -> None:
    """Answer one client: its request line in, the command's result line out."""
    with connection, connection.makefile("rwb") as stream:
        request = json.loads(stream.readline())
        try:
            done = run(request["argv"], request["env"], request["cwd"], request["timeout"])
            answer = {"code": done.returncode, "stdout": done.stdout, "stderr": done.stderr}
        except subprocess.TimeoutExpired:
            answer = {"code": TIMED_OUT, "stdout": "",
                      "stderr": f"delegation {request['argv']}: no exit within "
                                f"{request['timeout']} s (killed)\n"}
        stream.write(json.dumps(answer).encode() + b"\n")


@contextlib.contextmanager
def relay(path: Path) -> Iterator[list[str]]:
    """Serve `run` on the UNIX socket ``path`` while open; yields the client's command line
    (append the CLI's arguments). Clients are answered one after another, as `run` runs one
    command at a time."""
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(path))
    listener.listen()

    def accept() -> None:
        while True:
            try:
                connection, _ = listener.accept()
            except OSError:  # closed: the relay ends
                return
            _relay_one(connection)

    thread = threading.Thread(target=accept, name="cli-forks-relay", daemon=True)
    thread.start()
    try:
        yield [sys.executable, __file__, "--via", str(path)]
    finally:
        with contextlib.suppress(OSError):
            listener.shutdown(socket.SHUT_RDWR)  # wakes the accept
        listener.close()
        thread.join(10)


def client(path: str, argv: list[str], timeout: float = 120.0) -> int:
    """The shell's side of `relay`: run ``delegation ARGV`` there, as if here."""
    request = {"argv": argv, "env": dict(os.environ), "cwd": os.getcwd(), "timeout": timeout}
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as connection:
        connection.connect(path)
        with connection.makefile("rwb") as stream:
            stream.write(json.dumps(request).encode() + b"\n")
            stream.flush()
            answer = json.loads(stream.readline())
    sys.stdout.write(answer["stdout"])
    sys.stderr.write(answer["stderr"])
    return int(answer["code"])


if __name__ == "__main__":
    if sys.argv[1:2] == ["--via"]:
        sys.exit(client(sys.argv[2], sys.argv[3:]))
    serve()
