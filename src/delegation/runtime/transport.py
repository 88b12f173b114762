"""Which client a unit talks through: MQTT (`MqttClient`, the default) or ROS 2 (`Ros2Client`),
chosen by ``BrokerSettings.transport`` at the composition root (the cores never know).

Both clients have the interface `MessageClient` names; rclpy is imported only when ROS 2 is
asked for, so the MQTT path runs without the ``[ros2]`` extra.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Protocol

from delegation.runtime.mqtt import Message, MessageSink, MqttClient
from delegation.runtime.settings import BrokerSettings

__all__ = ["ROS2_INSTALL", "MessageClient", "make_client", "ros2_missing"]

#: The one line `--transport ros2` prints when the extra is missing.
ROS2_INSTALL = (
    "--transport ros2 needs the ROS 2 extra: pip install 'delegation[ros2]' "
    "(ros-rclpy, ros-std-msgs, ros-rmw-fastrtps-cpp from PyPI; docs/ros2.md)"
)


class MessageClient(Protocol):
    """What units and clients use of a transport client (`MqttClient`, `Ros2Client`)."""

    client_id: str
    connected: threading.Event
    messages: queue.Queue[Message]
    _sink: MessageSink

    def connect(self, timeout: float = 10.0) -> None: ...
    def disconnect(self) -> None: ...
    def restart(self, timeout: float = 10.0) -> None: ...
    def subscribe(self, pattern: str, qos: int = ...) -> None: ...
    def unsubscribe(self, pattern: str) -> None: ...
    def publish(
        self, topic: str, payload: bytes | str, qos: int = ..., retain: bool = False
    ) -> None: ...
    @property
    def subscriptions(self) -> dict[str, int]: ...
    @property
    def loop_alive(self) -> bool: ...


def ros2_missing() -> str | None:
    """Why ROS 2 cannot be used here (rclpy, std_msgs or the Fast DDS RMW missing), or None."""
    try:
        import rclpy  # noqa: F401
        from std_msgs.msg import String  # noqa: F401
    except (ImportError, OSError) as exc:  # OSError: librmw_fastrtps_cpp.so not found
        return f"{type(exc).__name__}: {exc}"
    return None


def make_client(
    settings: BrokerSettings,
    client_id: str | None = None,
    sink: MessageSink | None = None,
    on_connection: Callable[[bool, int], None] | None = None,
) -> MessageClient:
    """The client ``settings.transport`` names."""
    if settings.transport == "ros2":
        from delegation.runtime.ros2 import Ros2Client

        return Ros2Client(settings, client_id, sink=sink, on_connection=on_connection)
    return MqttClient(settings, client_id, sink=sink, on_connection=on_connection)
