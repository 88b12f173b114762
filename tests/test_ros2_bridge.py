"""`delegation bridge` (docs/ros2.md): one mission uses a ROS 2 robot (plain rclpy,
`tests/ros2_robot.py`) and a simulated MQTT unit, with the service and engine on either side of
the bridge; nothing the bridge sent comes back to it (MQTT 5 "No Local", ROS topics only it writes
Separate processes, a private mosquitto, a ROS 2 domain of the test's own on the loopback-only
profile. Skipped, with one reason, where the ``[ros2]`` extra is not installed."""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from delegation.runtime.broker import PrivateMosquitto, free_port, mosquitto_binary
from delegation.runtime.transport import ros2_missing
from ros2_helpers import ROBOT, RosProcesses, assert_loopback_only

_MISSING = ros2_missing()
pytestmark = [
    pytest.mark.skipif(_MISSING is not None,
                       reason=f"the [ros2] extra is not installed ({_MISSING})"),
    pytest.mark.skipif(mosquitto_binary() is None, reason="no mosquitto binary"),
    pytest.mark.slow,
]

HOME = {"u0": (57.7600, 16.6800), "sam_0": (57.7600, 16.6840)}
GOAL = {"u0": (57.7610, 16.6800), "sam_0": (57.7610, 16.6840)}


@pytest.fixture
def world(tmp_path: Path) -> Iterator[tuple[RosProcesses, list[str]]]:
    """The ROS 2 side's processes, and the flags that name the MQTT broker."""
    broker = PrivateMosquitto().start(port=free_port(stable=True))
    procs = RosProcesses(tmp_path)
    try:
        yield procs, ["--broker", broker.host, "--port", str(broker.port)]
    finally:
        procs.stop()
        broker.stop()


def _sim_scenario(path: Path) -> Path:
    lat, lon = HOME["u0"]
    path.write_text(json.dumps({
        "name": "u0", "description": "the MQTT unit of a bridge test",
        "agents": [{"name": "u0", "type": "ground", "rate": 2.0,
                    "position": {"latitude": lat, "longitude": lon, "altitude": 0.0},
                    "speeds": {"slow": 2.0, "standard": 4.0, "fast": 8.0},
                    "tasks": ["move-to"]}],
        "mission": {"name": "move-to", "common_params": {"execunit": "*"},
                    "params": {"waypoint": {"latitude": lat, "longitude": lon}}}}))
    return path


def _mission(path: Path) -> Path:
    path.write_text(json.dumps({"name": "conc", "children": [
        {"name": "move-to", "common_params": {"execunit": f"/{unit}"},
         "params": {"speed": "standard",
                    "waypoint": {"latitude": lat, "longitude": lon, "altitude": 20.0}}}
        for unit, (lat, lon) in GOAL.items()]}))
    return path


@pytest.mark.parametrize("service_on", ["mqtt", "ros2"])
def test_one_mission_uses_a_ros2_robot_and_an_mqtt_unit_across_the_bridge(
        world: tuple[RosProcesses, list[str]], service_on: str) -> None:
    ros, broker = world
    ros.delegation("bridge", "bridge", *broker, "--report", "0.5", "-v", transport="mqtt")
    ros.delegation("serve", "serve", "--state", str(ros.workdir / "state.db"), *broker,
                   transport=service_on)
    ros.delegation("engine", "engine", *broker, transport=service_on)
    ros.delegation("sim", "sim", str(_sim_scenario(ros.workdir / "u0.json")), "--speedup",
                   "10", *broker, transport="mqtt")
    robot = ros.start("robot", sys.executable, str(ROBOT), "sam_0", *map(str, HOME["sam_0"]))
    for unit in ("op0", "u0", "sam_0"):
        ros.wait_log("serve", f"unit {unit} appeared")

    done = ros.run("submit", str(_mission(ros.workdir / "mission.json")), "--wait", "30",
                   "--timeout", "90", *broker, transport=service_on)
    logs = {k: ros.log(k)[-3000:] for k in ros.procs}
    assert done.returncode == 0, (done.stdout[-3000:], done.stderr[-3000:], logs)
    assert "mission succeeded" in done.stdout
    assert "/sam_0" in done.stdout and "/u0" in done.stdout
    # Each unit did its own task: nothing reached a unit too late across the bridge (a start-task
    # held up in the bridge is answered late and its task re-delegated).
    assert "re-delegat" not in done.stdout + ros.log("serve"), done.stdout[-3000:]
    assert ros.log("robot").count("finished ") == 1
    assert robot.poll() is None

    ros.wait_log("bridge", "bridge: BridgeCounts(")
    counts = _last_counts(ros.log("bridge"))
    assert counts["to_mqtt"] > 0 and counts["to_ros"] > 0
    # MQTT 5 "No Local", and no ROS topic read that only the bridge writes: nothing it sent
    # came back to it (tests/test_ros2_bridge_echoes.py: what it does when something does)
    assert counts["echoes"] == 0
    assert counts["full"] == 0 and counts["failed"] == 0
    on_dds = {"bridge", "robot"} | ({"serve", "engine"} if service_on == "ros2" else set())
    assert_loopback_only(ros, on_dds)


def _last_counts(log: str) -> dict[str, int]:
    found = re.findall(r"BridgeCounts\(([^)]*)\)", log)
    assert found, log[-2000:]
    return {k: int(v) for k, v in re.findall(r"(\w+)=(\d+)", found[-1])}
