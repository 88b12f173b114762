"""Time is when a message arrived (issue 22 item 5): a backlog of slow work on a real broker never
makes a live engine or unit look lost.

The service's core is made slow (each delegation command takes 15 ms, as a heavy step would) and
given a burst of 400 commands: 6 s of queued work, six times the 1 s after which these tests
judge a silent peer lost. Meanwhile the engine and a simulated unit keep their heartbeats coming at
10 Hz; they wait in the inbox behind the burst. Judged at the time they were processed (before this
issue) both were declared lost once the first batch of work was done; judged at arrival, neither is.
"""

from __future__ import annotations

import json
import logging
import time
import uuid
from collections.abc import Callable
from typing import Any

import pytest

from delegation.engine.unit import TstEngine
from delegation.fleet import make_unit
from delegation.geo import LocalFrame
from delegation.local import LocalSystem
from delegation.runtime.core import Effects
from delegation.runtime.settings import BrokerSettings
from delegation.service import DelegationService, ServiceConfig

pytestmark = pytest.mark.mqtt

FRAME = LocalFrame(57.7605, 16.6815)
BURST = 400
STEP_SECONDS = 0.015


def test_a_backlog_of_slow_work_never_declares_a_live_engine_or_unit_lost(
    mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any],
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="delegation.service.core")
    config = ServiceConfig(name="svc-backlog", prefix=prefix, engine="op7",
                           min_heartbeat_timeout=1.0, max_heartbeat_timeout=1.0)
    units = [make_unit("dji0", "air", FRAME.geopoint(0, 0, 30), ["move-to"])]
    with LocalSystem(units, settings=mqtt_settings, prefix=prefix, rates={"dji0": 10.0},
                     engine=False, service=False):
        engine = TstEngine(mqtt_settings, "op7", prefix=prefix, rate=10.0)
        service = DelegationService(mqtt_settings, config)
        real = service.core.on_message
        command_topic = f"{config.base_topic}/delegation/command"

        def slow(topic: str, payload: bytes, now: float) -> Effects:
            if topic == command_topic:
                time.sleep(STEP_SECONDS)  # a heavy step: the loop thread is busy
            return real(topic, payload, now)

        service.core.on_message = slow  # type: ignore[method-assign]
        engine.start()
        service.start()
        try:
            assert service.wait_ready(["dji0"], timeout=10.0)
            watch = collector(f"{config.base_topic}/delegation/response")
            coms = [str(uuid.uuid4()) for _ in range(BURST)]
            began = time.monotonic()
            for com in coms:
                watch.publish(command_topic, json.dumps(
                    {"command": "ping", "com-uuid": com, "sender": "test"}).encode())
            last = coms[-1]
            watch.wait_json(f"{config.base_topic}/delegation/response",
                            lambda d: d.get("response-to") == last, timeout=60.0,
                            what="the answer to the burst's last command")
            busy = time.monotonic() - began
            answered = {d.get("response-to") for d in
                        watch.json_on(f"{config.base_topic}/delegation/response")}
            assert set(coms) <= answered
            assert busy > 3 * config.min_heartbeat_timeout  # the backlog outlasted the timeout
            lost = [r.getMessage() for r in caplog.records
                    if r.getMessage().startswith("unit ") and " appeared" not in r.getMessage()]
            assert lost == [], lost
            assert service.inspect(lambda core: core.ready(["dji0"], True, service.clock()))
        finally:
            service.stop()
            engine.stop()
