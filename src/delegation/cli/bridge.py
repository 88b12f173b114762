"""``delegation bridge``: a ROS 2 domain and an MQTT broker as one WARA-PS world (docs/ros2.md).

Runs until interrupted (or for ``--duration`` seconds); logs what went through every
``--report`` seconds.
"""

from __future__ import annotations

import argparse
import gc
import logging
import threading
from typing import Any

from delegation.cli.connect import add_broker_args, client_settings, require_ros2
from delegation.cli.options import add_duration_arg, positive_float
from delegation.topics import AGENT_TYPES, ROLES

log = logging.getLogger(__name__)


def register(subparsers: Any) -> None:
    bridge = subparsers.add_parser(
        "bridge",
        help="join a ROS 2 domain and an MQTT broker, both ways",
        description="Forwards every unit topic both ways: <prefix>/unit/<type>/<role>/<name>/... "
        "on MQTT is /<name>/<prefix>/... on ROS 2 (ROS_DOMAIN_ID; DDS settings from "
        "FASTDDS_DEFAULT_PROFILES_FILE). ROS 2 units appear on MQTT with the type their "
        "heartbeat says and --role; MQTT units keep theirs. No echo loops, bounded queues. "
        "Needs the [ros2] extra. The broker flags name the MQTT side (--transport is ignored).",
    )
    bridge.add_argument("--role", default="real", choices=ROLES,
                        help="role of ROS 2 units on MQTT (default real)")
    bridge.add_argument("--agent-type", default=None, choices=AGENT_TYPES,
                        help="type of a ROS 2 unit before its heartbeat says one (default: wait "
                        "for the heartbeat)")
    bridge.add_argument("--units", default="", metavar="NAME,...",
                        help="bridge only these units (default: every unit either side shows)")
    add_duration_arg(bridge)
    bridge.add_argument("--report", type=positive_float, default=60.0, metavar="SECONDS",
                        help="log the counts every SECONDS (default 60)")
    add_broker_args(bridge)
    bridge.set_defaults(func=_bridge)


def _bridge(args: argparse.Namespace) -> int:
    require_ros2()
    args.transport = "mqtt"  # the broker flags name the MQTT side
    settings = client_settings(args)
    from delegation.runtime.ros_bridge import Bridge

    units = [u.strip().strip("/") for u in args.units.split(",") if u.strip()]
    bridge = Bridge(settings, prefix=args.prefix, role=args.role, agent_type=args.agent_type,
                    units=units)
    bridge.start()
    # What start-up built (rclpy, pydantic, paho) lives as long as the process: out of the
    # collector's sight, each full collection walks only what forwarding allocates.
    gc.freeze()
    print(f"bridging ROS 2 and {settings.describe()} under {args.prefix}/ "
          f"({', '.join(units) if units else 'every unit'}); Ctrl-C stops", flush=True)
    done = threading.Event()
    waited = 0.0
    try:
        while args.duration is None or waited < args.duration:
            step = args.report if args.duration is None else min(args.report,
                                                                  args.duration - waited)
            done.wait(step)
            waited += step
            log.info("bridge: %s, queued %s", bridge.counts, bridge.queued())
    finally:
        bridge.stop()
        log.info("bridge stopped: %s", bridge.counts)
    return 0
