"""A ROS 2 robot as a ROS 2 user writes one: plain rclpy and std_msgs/String, none of our code.

    python tests/ros2_robot.py NAME LATITUDE LONGITUDE

It speaks the WARA-PS JSON on ``/NAME/waraps/...`` the way SMARC's robots do, in the three
spellings real publishers use: the heartbeat as a Python literal (``str(dict)``: single quotes,
True/False/None), sensor_info as JSON wrapped in quotes (``json.dumps`` of JSON text), the rest as
JSON. It takes ``start-task`` for ``move-to`` (answers ``running``, finishes after a second at the
waypoint) and answers ``ping``; it prints ``ready`` once its subscription exists and
``finished <task-uuid>`` for every task it ends. Stops on SIGTERM/SIGINT.
"""

import json
import signal
import sys
import time
import uuid

import rclpy
from rclpy.node import Node
from std_msgs.msg import String


class Robot(Node):
    def __init__(self, name: str, lat: float, lon: float) -> None:
        super().__init__(name)
        self.name, self.lat, self.lon = name, lat, lon
        self.agent_uuid = str(uuid.uuid4())
        self.pubs = {}
        self.tasks = {}  # task-uuid -> (ends at, waypoint)
        self.create_subscription(String, f"/{name}/waraps/exec/command", self.on_command, 10)
        self.create_timer(0.5, self.status)
        self.create_timer(0.05, self.step)

    def send(self, suffix: str, text: str) -> None:
        if suffix not in self.pubs:
            self.pubs[suffix] = self.create_publisher(String, f"/{self.name}/waraps/{suffix}", 10)
        self.pubs[suffix].publish(String(data=text))

    def status(self) -> None:
        now = time.time()
        heartbeat = {"agent-type": "air", "agent-uuid": self.agent_uuid, "name": self.name,
                     "levels": ["sensor", "direct_execution"], "rate": 2.0, "stamp": now,
                     "type": "HeartBeat", "charging": False, "note": None}
        self.send("heartbeat", str(heartbeat))  # a Python literal, as str(dict) gives
        info = {"name": self.name, "rate": 2.0, "stamp": now, "type": "SensorInfo",
                "sensor-data-provided": ["position", "speed"]}
        self.send("sensor_info", json.dumps(json.dumps(info)))  # JSON wrapped in quotes
        self.send("direct_execution_info", json.dumps({
            "name": self.name, "rate": 2.0, "stamp": now, "type": "DirectExecutionInfo",
            "tasks-available": [{"name": "move-to", "signals": ["$abort", "$enough"]}],
            "tasks-executing": [{"task-name": "move-to", "task-uuid": t} for t in self.tasks]}))
        self.send("sensor/position", json.dumps(
            {"latitude": self.lat, "longitude": self.lon, "altitude": 20.0, "rostype": "GeoPoint"}))
        self.send("sensor/speed", json.dumps({"value": 0.0}))

    def answer(self, command: dict, response: str, reason: str = "") -> None:
        self.send("exec/response", json.dumps({
            "agent-uuid": self.agent_uuid, "com-uuid": str(uuid.uuid4()), "fail-reason": reason,
            "response": response, "response-to": command.get("com-uuid"),
            "task-uuid": command.get("task-uuid")}))

    def feedback(self, task: str, status: str) -> None:
        self.send("exec/feedback", json.dumps({
            "agent-uuid": self.agent_uuid, "com-uuid": str(uuid.uuid4()), "status": status,
            "task-uuid": task}))

    def on_command(self, msg: String) -> None:
        command = json.loads(msg.data)
        if command.get("command") == "ping":
            self.answer(command, "pong")
        elif command.get("command") == "start-task":
            task = command.get("task", {})
            if task.get("name") != "move-to":
                self.answer(command, "failed", "only move-to")
                return
            self.tasks[command["task-uuid"]] = (time.time() + 1.0, task["params"]["waypoint"])
            self.answer(command, "running")
            self.feedback(command["task-uuid"], "running")
        elif command.get("command") == "signal-task" and \
                self.tasks.pop(command.get("task-uuid"), None) is not None:
            self.answer(command, "ok")
            self.feedback(command["task-uuid"], "aborted")

    def step(self) -> None:
        now = time.time()
        for task, (ends, waypoint) in list(self.tasks.items()):
            if now >= ends:
                del self.tasks[task]
                self.lat, self.lon = waypoint["latitude"], waypoint["longitude"]
                self.feedback(task, "finished")
                print("finished", task, flush=True)


def main() -> None:
    name, lat, lon = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
    rclpy.init()
    robot = Robot(name, lat, lon)
    signal.signal(signal.SIGTERM, lambda *_: rclpy.try_shutdown())
    print("ready", flush=True)
    try:
        rclpy.spin(robot)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        robot.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
