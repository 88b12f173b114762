"""What the ROS 2 process tests share: processes in a ROS 2 domain of their own on the project's
loopback-only Fast DDS profile, and the check that every socket they open is on 127.0.0.1."""

from __future__ import annotations

import os
import random
import socket
import struct
import subprocess
import time
from collections.abc import Collection
from pathlib import Path

import cli_forks

ROOT = Path(__file__).resolve().parent.parent
SRC = str(ROOT / "src")
PROFILE = ROOT / "deploy" / "ros2" / "fastdds-loopback.xml"
ROBOT = ROOT / "tests" / "ros2_robot.py"


class RosProcesses:
    """Processes in one ROS 2 domain of their own, killed at the end whatever happened."""

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        # Fast DDS ports are 7400 + 250 x domain: 1..200 stays in range; a random domain keeps
        # parallel test workers apart.
        self.domain = random.SystemRandom().randint(1, 200)
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("WARAPS_")}
        self.env.update(PYTHONPATH=SRC, ROS_DOMAIN_ID=str(self.domain), PYTHONUNBUFFERED="1",
                        FASTDDS_DEFAULT_PROFILES_FILE=str(PROFILE))
        self.procs: dict[str, subprocess.Popen[str] | cli_forks.Forked] = {}

    def start(self, key: str, *argv: str) -> subprocess.Popen[str]:
        log = (self.workdir / f"{key}.log").open("a")
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log,
                                stderr=subprocess.STDOUT, env=self.env, text=True,
                                cwd=self.workdir)
        log.close()
        self.procs[key] = proc
        return proc

    def delegation(self, key: str, *args: str, transport: str = "ros2"
                   ) -> cli_forks.Forked:
        """``delegation ARGS``, a process of its own forked with the CLI imported."""
        proc = cli_forks.spawn([*args, "--transport", transport], self.env,
                               self.workdir / f"{key}.log", cwd=self.workdir)
        self.procs[key] = proc
        return proc

    def run(self, *args: str, transport: str = "ros2", timeout: float = 120.0
            ) -> subprocess.CompletedProcess[str]:
        """A one-shot command, forked with the CLI imported (`cli_forks.run`)."""
        return cli_forks.run([*args, "--transport", transport], self.env, self.workdir, timeout)

    def log(self, key: str) -> str:
        return (self.workdir / f"{key}.log").read_text()

    def wait_log(self, key: str, text: str, timeout: float = 60.0) -> None:
        """Until ``text`` is in ``key``'s output (the service logs every unit that appears)."""
        deadline = time.monotonic() + timeout
        while text not in self.log(key):
            assert self.procs[key].poll() is None, self.log(key)[-3000:]
            assert time.monotonic() < deadline, f"no {text!r} from {key}: {self.log(key)[-3000:]}"
            time.sleep(0.1)

    def stop(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.terminate()
        for proc in self.procs.values():
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)



# --------------------------------------------------------------------------- sockets


def _sockets() -> dict[int, tuple[str, str]]:
    """inode -> (protocol, local IPv4/IPv6 address) of every socket in this network namespace."""
    found: dict[int, tuple[str, str]] = {}
    for proto in ("udp", "udp6", "tcp", "tcp6"):
        try:
            lines = Path(f"/proc/net/{proto}").read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            address = fields[1].split(":")[0]
            raw = bytes.fromhex(address)
            if len(raw) == 4:
                ip = socket.inet_ntop(socket.AF_INET, struct.pack("<I", int(address, 16)))
            else:
                words = struct.unpack("<4I", raw)
                ip = socket.inet_ntop(socket.AF_INET6, struct.pack(">4I", *words))
            found[int(fields[9])] = (proto, ip)
    return found


def _inodes(pid: int) -> set[int]:
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(int(target[8:-1]))
    return inodes


def assert_loopback_only(ros: RosProcesses, on_dds: Collection[str] | None = None) -> None:
    """Every IP socket of every process is bound to 127.0.0.1 (no 0.0.0.0, no multicast), and
    each process on DDS (``on_dds``, default all) has UDP sockets: DDS is really in use."""
    table = _sockets()
    for key, proc in ros.procs.items():
        mine = [table[i] for i in _inodes(proc.pid) if i in table]
        assert mine, f"{key} has no IP socket"
        udp = [ip for proto, ip in mine if proto.startswith("udp")]
        if on_dds is None or key in on_dds:
            assert udp, f"{key} has no UDP socket: is it on DDS at all?"
        outside = [(proto, ip) for proto, ip in mine if ip != "127.0.0.1"]
        assert not outside, f"{key} binds outside 127.0.0.1: {outside}"
