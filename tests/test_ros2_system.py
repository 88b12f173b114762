"""ROS 2 end to end, in separate processes (DESIGN 3.12, docs/ros2.md): ``serve``, ``engine`` and
``sim`` all ``--transport ros2`` run a mission to ``succeeded``; a robot written as a ROS 2 user
writes one (plain rclpy, `tests/ros2_robot.py`, Python-literal and quoted-JSON payloads) does
the tasks of a mission; and no DDS socket of any of these processes is bound outside 127.0.0.1.

Every process gets the project's loopback-only Fast DDS profile (deploy/ros2/) and this test's own
``ROS_DOMAIN_ID``. Skipped, with one reason, where the ``[ros2]`` extra is not installed.
"""

from __future__ import annotations

import json
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
