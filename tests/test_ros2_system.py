"""ROS 2 end to end, in separate processes (DESIGN 3.12, docs/ros2.md): ``serve``, ``engine`` and
``sim`` all ``--transport ros2`` run a mission to ``succeeded``; a robot written as a ROS 2 user
writes one (plain rclpy, `tests/ros2_robot.py`, Python-literal and quoted-JSON payloads) does
the tasks of a mission; and no DDS socket of any of these processes is bound outside 127.0.0.1.

Every process gets the project's loopback-only Fast DDS profile (deploy/ros2/) and this test's own
``ROS_DOMAIN_ID``. Skipped, with one reason, where the ``[ros2]`` extra is not installed.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from delegation.runtime.transport import ros2_missing
from ros2_helpers import ROBOT, ROOT, RosProcesses, assert_loopback_only

_MISSING = ros2_missing()
pytestmark = [
    pytest.mark.skipif(_MISSING is not None,
                       reason=f"the [ros2] extra is not installed ({_MISSING})"),
    pytest.mark.slow,
]


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
    assert_loopback_only(ros)


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
    assert_loopback_only(ros)


HOME = {"u0": (57.7600, 16.6800), "u1": (57.7600, 16.6840), "u2": (57.7624, 16.6842)}
# u1's leg is long (it must still be flying when killed); u0's is short (120 m, 6 s wall): the
# mission waits for it too, and its length tests nothing.
GOAL = {"u0": (57.7611, 16.6800), "u1": (57.7627, 16.6840)}


def test_a_ros2_unit_killed_mid_task_is_re_delegated(ros: RosProcesses) -> None:
    """As on MQTT (tests/test_faults.py): u1 killed -9 while the mission runs; its task moves to
    u2, the mission succeeds."""
    _service_and_engine(ros)
    for name, (lat, lon) in HOME.items():
        path = ros.workdir / f"{name}.json"
        path.write_text(json.dumps({
            "name": name, "description": "one unit of a ROS 2 fault test",
            "agents": [{"name": name, "type": "air", "rate": 2.0,
                        "position": {"latitude": lat, "longitude": lon, "altitude": 20.0},
                        "speeds": {"slow": 2.0, "standard": 4.0, "fast": 8.0},
                        "tasks": ["move-to"]}],
            "mission": {"name": "move-to", "common_params": {"execunit": "*"},
                        "params": {"waypoint": {"latitude": lat, "longitude": lon}}}}))
        # 300 m at 4 m/s is 75 s simulated, 15 s wall: longer than finding u1 lost (5 s).
        ros.delegation(name, "sim", str(path), "--speedup", "5")
    for unit in ("op0", *HOME):
        ros.wait_log("serve", f"unit {unit} appeared")
    mission = ros.workdir / "mission.json"
    mission.write_text(json.dumps({"name": "conc", "children": [
        {"name": "move-to", "common_params": {"execunit": f"/{unit}"},
         "params": {"speed": "standard",
                    "waypoint": {"latitude": lat, "longitude": lon, "altitude": 20.0}}}
        for unit, (lat, lon) in GOAL.items()]}))
    submit = ros.delegation("submit", "submit", str(mission), "--wait", "30", "--timeout", "90")
    ros.wait_log("engine", "executing tree")
    ros.procs["u1"].kill()
    ros.procs["u1"].wait(10)
    assert submit.wait(120) == 0, {k: ros.log(k)[-3000:] for k in ros.procs}
    out = ros.log("submit")
    assert "mission succeeded" in out, out
    serve = ros.log("serve")
    assert "unit u1 lost" in serve, serve[-3000:]
    # moved within the running tree (rebind-tst-nodes), or the tree replaced
    assert re.search(r"re-delegated( in place)?: root/children\[1\]( \(move-to [^)]*\))? -> /u2",
                     serve), serve[-3000:]
    assert "re-delegated: /u1 lost" in out, out
