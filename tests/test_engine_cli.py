"""``delegation engine`` and ``delegation sim`` run on a broker and execute a tree together."""

from __future__ import annotations

import threading
import uuid
from pathlib import Path

import pytest
import yaml

from delegation.cli import main
from delegation.runtime.settings import BrokerSettings

START = {"latitude": 57.7605, "longitude": 16.6815, "altitude": 40.0}
GOAL = {"latitude": 57.7610, "longitude": 16.6815, "altitude": 40.0}  # ~56 m north


def _run(argv: list[str], results: dict[str, int]) -> threading.Thread:
    t = threading.Thread(target=lambda: results.setdefault(argv[0], main(argv)), daemon=True)
    t.start()
    return t


@pytest.mark.mqtt
@pytest.mark.slow
def test_engine_and_sim_commands(
    mqtt_settings: BrokerSettings, prefix: str, collector, tmp_path: Path
) -> None:
    scenario = {
        "name": "cli",
        "description": "one drone",
        "agents": [
            {"name": "dji0", "type": "air", "position": START, "tasks": ["move-to"], "rate": 5}
        ],
        "mission": {"name": "move-to", "params": {"waypoint": GOAL}},
    }
    path = tmp_path / "cli.yaml"
    path.write_text(yaml.safe_dump(scenario))
    broker = ["--broker", mqtt_settings.host, "--port", str(mqtt_settings.port), "--prefix", prefix]
    c = collector(f"{prefix}/#")
    results: dict[str, int] = {}
    threads = [
        _run(["sim", str(path), "--speedup", "20", "--duration", "5", *broker], results),
        _run(["engine", "--duration", "5", *broker], results),
    ]
    try:
        engine_base = f"{prefix}/unit/ground/simulation/op0"
        c.wait_json(f"{engine_base}/heartbeat", timeout=10)
        c.wait_json(f"{prefix}/unit/air/simulation/dji0/heartbeat", timeout=10)
        cmd = {
            "com-uuid": str(uuid.uuid4()),
            "command": "start-tst",
            "sender": "test",
            "tst": {
                "name": "move-to",
                "common_params": {"execunit": "/dji0", "node-uuid": "n1"},
                "params": {"waypoint": GOAL, "speed": "fast"},
            },
        }
        c.publish(f"{engine_base}/tst/command", cmd)
        final = c.wait_json(
            f"{engine_base}/tst/feedback",
            lambda d: d["root-flag"] and d["status"] in ("succeeded", "failed", "aborted"),
            timeout=8,
        )
        assert final["status"] == "succeeded"
    finally:
        for t in threads:
            t.join(15)
    assert results == {"sim": 0, "engine": 0}
