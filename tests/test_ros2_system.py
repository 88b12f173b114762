"""ROS 2 end to end, in separate processes (DESIGN 3.12, docs/ros2.md): ``serve``, ``engine`` and
``sim`` all ``--transport ros2`` run a mission to ``succeeded``; a robot written as a ROS 2 user
writes one (plain rclpy, `tests/ros2_robot.py`, Python-literal and quoted-JSON payloads) does
the tasks of a mission; and no DDS socket of any of these processes is bound outside 127.0.0.1.

Every process gets the project's loopback-only Fast DDS profile (deploy/ros2/) and this test's own
``ROS_DOMAIN_ID``. Skipped, with one reason, where the ``[ros2]`` extra is not installed.
"""

from __future__ import annotations

import json
import os
import random
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from delegation.runtime.transport import ros2_missing

ROOT = Path(__file__).resolve().parent.parent
SRC = str(ROOT / "src")
PROFILE = ROOT / "deploy" / "ros2" / "fastdds-loopback.xml"
ROBOT = ROOT / "tests" / "ros2_robot.py"

_MISSING = ros2_missing()
pytestmark = [
    pytest.mark.skipif(_MISSING is not None,
                       reason=f"the [ros2] extra is not installed ({_MISSING})"),
    pytest.mark.slow,
]


class RosProcesses:
    """Processes in one ROS 2 domain of their own, killed at the end whatever happened."""

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        # Fast DDS ports are 7400 + 250 x domain: 1..200 stays in range; a random domain keeps
        # parallel test workers apart.
        self.domain = random.SystemRandom().randint(1, 200)
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("WARAPS_")}
        self.env.update(PYTHONPATH=SRC, ROS_DOMAIN_ID=str(self.domain),
                        FASTDDS_DEFAULT_PROFILES_FILE=str(PROFILE))
        self.procs: dict[str, subprocess.Popen[str]] = {}

    def start(self, key: str, *argv: str) -> subprocess.Popen[str]:
        log = (self.workdir / f"{key}.log").open("a")
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log,
                                stderr=subprocess.STDOUT, env=self.env, text=True,
                                cwd=self.workdir)
        log.close()
        self.procs[key] = proc
        return proc

    def delegation(self, key: str, *args: str) -> subprocess.Popen[str]:
        return self.start(key, sys.executable, "-m", "delegation", *args, "--transport", "ros2")

    def run(self, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "delegation", *args, "--transport", "ros2"],
                              capture_output=True, text=True, env=self.env, timeout=timeout,
                              cwd=self.workdir)

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


@pytest.fixture
def ros(tmp_path: Path) -> Iterator[RosProcesses]:
    procs = RosProcesses(tmp_path)
    try:
        yield procs
    finally:
        procs.stop()


def _service_and_engine(ros: RosProcesses) -> None:
    ros.delegation("serve", "serve", "--state", str(ros.workdir / "state.db"))
    ros.delegation("engine", "engine")


def _submit(ros: RosProcesses, mission: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    done = ros.run("submit", str(mission), "--wait", "30", "--timeout", "90", *extra)
    logs = {k: ros.log(k)[-3000:] for k in ros.procs}
    assert done.returncode == 0, (done.stdout[-3000:], done.stderr[-3000:], logs)
    return done


def test_a_ros2_only_system_runs_a_mission_to_succeeded(ros: RosProcesses) -> None:
    scenario = str(ROOT / "scenarios" / "demo.yaml")
    _service_and_engine(ros)
    ros.delegation("sim", "sim", scenario, "--speedup", "20")
    for unit in ("op0", "dji0", "dji1", "usv0"):
        ros.wait_log("serve", f"unit {unit} appeared")
    done = _submit(ros, Path(scenario), "--speedup", "20", "--enough")
    assert "mission succeeded" in done.stdout
    for key in ("serve", "engine", "sim"):
        assert ros.procs[key].poll() is None, ros.log(key)[-2000:]
    _assert_loopback_only(ros)


def test_a_plain_rclpy_robot_does_the_tasks_of_a_mission(ros: RosProcesses) -> None:
    _service_and_engine(ros)
    robot = ros.start("robot", sys.executable, str(ROBOT), "sam_0", "57.76", "16.68")
    for unit in ("op0", "sam_0"):
        ros.wait_log("serve", f"unit {unit} appeared")
    goals = [(57.7605, 16.6805), (57.7610, 16.6810)]
    mission = {"name": "seq", "children": [
        {"name": "move-to", "common_params": {"execunit": "*"},
         "params": {"speed": "standard",
                    "waypoint": {"latitude": lat, "longitude": lon, "altitude": 20.0}}}
        for lat, lon in goals]}
    path = ros.workdir / "mission.json"
    path.write_text(json.dumps(mission))
    done = _submit(ros, path)
    assert "mission succeeded" in done.stdout
    assert "sam_0" in done.stdout
    assert robot.poll() is None
    assert ros.log("robot").count("finished ") == 2, ros.log("robot")
    _assert_loopback_only(ros)


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


def _assert_loopback_only(ros: RosProcesses) -> None:
    """Every IP socket of every process is bound to 127.0.0.1 (no 0.0.0.0, no multicast), and
    each process has some: DDS is really in use."""
    table = _sockets()
    for key, proc in ros.procs.items():
        mine = [table[i] for i in _inodes(proc.pid) if i in table]
        udp = [ip for proto, ip in mine if proto.startswith("udp")]
        assert udp, f"{key} has no UDP socket: is it on DDS at all?"
        outside = [(proto, ip) for proto, ip in mine if ip != "127.0.0.1"]
        assert not outside, f"{key} binds outside 127.0.0.1: {outside}"
