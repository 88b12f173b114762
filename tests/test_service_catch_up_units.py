"""The service killed -9 while a mission runs, with an engine that does not answer ``query-tst``
(the public op0 has no such extension): the mission's tasks end while no service is up, and the
restarted service learns it from the units themselves (``query-status``, seed 12.1) and reports
the mission final within 10 s of its return (issue 22 item 1, DESIGN 3.13).

Real processes and a real broker: the simulated fleet in this process (`LocalSystem`, without
engine or service), our engine beside it with ``answers_query_tst=False``, the service ``python -m
delegation serve`` in a subprocess (`Serve`), killed with SIGKILL.
"""

from __future__ import annotations

import logging
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from conftest import one_broker
from delegation.engine import TstEngine
from delegation.fleet import make_unit
from delegation.geo import LocalFrame
from delegation.local import LocalSystem
from delegation.runtime.settings import BrokerSettings
from delegation.service import ServiceConfig
from test_service_state_faults import (  # noqa: F401  (serves: the fixture)
    Serve,
    _request,
    _wait_new_heartbeat,
    _wait_seen_after_start,
    serves,
)

pytestmark = [pytest.mark.mqtt, pytest.mark.slow, one_broker()]

FRAME = LocalFrame(57.7605, 16.6815)
SPEEDS = {"slow": 4.0, "standard": 8.0, "fast": 14.0}


def _move(unit: str, east: float) -> dict[str, Any]:
    return {"name": "move-to", "common_params": {"execunit": f"/{unit}"},
            "params": {"waypoint": FRAME.geopoint(east, 40, 30).to_wire()}}


def test_a_mission_that_ended_while_the_service_was_down_is_final_from_its_units(
    mqtt_settings: BrokerSettings, prefix: str, tmp_path: Path,
    collector: Callable[..., Any], serves: Callable[[str, str], Serve],  # noqa: F811
) -> None:
    name = f"svc{uuid.uuid4().hex[:6]}"
    config = ServiceConfig(prefix=prefix, name=name)
    base = config.base_topic
    state = str(tmp_path / "state.sqlite")
    watch = collector(f"{base}/#", f"{prefix}/unit/+/+/op0/tst/#",
                      f"{prefix}/unit/+/+/+/exec/#", f"{prefix}/unit/+/+/+/heartbeat",
                      f"{prefix}/unit/+/+/+/sensor/position")
    units = [make_unit(u, "air", FRAME.geopoint(i * 20.0, 0, 30), ["move-to"], speeds=SPEEDS)
             for i, u in enumerate(("dji0", "dji1"))]
    # About 200 m at 8 m/s each = 25 s of mission time; x10: 2.5 s of wall time.
    with LocalSystem(units, settings=mqtt_settings, config=config, service=False, engine=False,
                     speedup=10.0, rates={"dji0": 5.0, "dji1": 5.0}):
        engine = TstEngine(mqtt_settings, "op0", prefix=prefix, answers_query_tst=False)
        engine.start()
        try:
            assert engine.wait_for_units(["dji0", "dji1"], 15)
            first = serves(name, state)
            first_uuid = _wait_new_heartbeat(watch, base, set(), timeout=30)
            for topic in ("op0/heartbeat", "dji0/heartbeat", "dji1/heartbeat",
                          "dji0/sensor/position", "dji1/sensor/position"):
                _wait_seen_after_start(watch, base, f"{prefix}/unit/+/+/{topic}", first_uuid)
            tree = {"name": "conc", "children": [_move("dji0", 200), _move("dji1", 220)]}
            started = _request(watch, base, {"command": "delegate", "start": True, "tst": tree,
                                             "sender": "test"}, timeout=30)
            assert started["response"] == "started", started
            sent = started["plan"]["tst"]
            root = sent["common_params"]["node-uuid"]
            tasks = [c["common_params"]["node-uuid"] for c in sent["children"]]
            # Both tasks running as the service relays them: it saw both start-tasks first
            # (and stored them before it published anything after).
            for task in tasks:
                watch.wait_json(f"{base}/tst/feedback",
                                lambda d, t=task: d.get("node-uuid") == t
                                and d.get("status") == "running",
                                timeout=20, what=f"task {task} running")

            first.kill()
            watch.wait_json(f"{prefix}/unit/+/+/op0/tst/feedback",
                            lambda d: d.get("node-uuid") == root
                            and d.get("status") == "succeeded",
                            timeout=30, what="the tree ended while no service was up")
            second = serves(name, state)
            _wait_new_heartbeat(watch, base, {first_uuid}, timeout=30)
            back = time.monotonic()
            watch.wait_json(f"{base}/delegation/feedback",
                            lambda d: d.get("root-uuid") == root
                            and d.get("status") == "succeeded",
                            timeout=10, what="the end missed while down, reported")
            logging.getLogger(__name__).info("the missed end reported %.2f s after the restart",
                                             time.monotonic() - back)

            # The engine was asked and said nothing; the units were asked about their tasks.
            queries = [d for d in watch.json_on(f"{prefix}/unit/+/+/op0/tst/command")
                       if d.get("command") == "query-tst"]
            assert queries, "the restarted service never asked the engine"
            assert not [d for d in watch.json_on(f"{prefix}/unit/+/+/op0/tst/response")
                        if d.get("response-to") in {q["com-uuid"] for q in queries}]
            start_tasks = [d for d in watch.json_on(f"{prefix}/unit/+/+/+/exec/command")
                           if d.get("command") == "start-task"]
            asked = [d for d in watch.json_on(f"{prefix}/unit/+/+/+/exec/command")
                     if d.get("command") == "query-status" and d.get("sender") == name]
            assert {d["task-uuid"] for d in asked} == {d["task-uuid"] for d in start_tasks}
            assert len({d["task-uuid"] for d in start_tasks}) == 2  # nothing ran twice

            done = _request(watch, base, {"command": "query-mission", "root-uuid": root,
                                          "sender": "test"})
            assert done["mission"]["status"] == "succeeded", done
            assert all(n["status"] == "succeeded" for n in done["mission"]["nodes"]), done
            second.stop()
            assert second.proc.returncode == 0, second.output()[-2000:]
        finally:
            engine.stop()
