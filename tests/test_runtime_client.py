"""The service client on a real broker: answers it keeps, answers it ignores."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from typing import Any

import pytest

from delegation.runtime.client import ServiceClient, ServiceUnavailable
from delegation.runtime.core import Identity, heartbeat
from delegation.runtime.settings import BrokerSettings

pytestmark = pytest.mark.mqtt


def test_client_keeps_only_the_answers_it_waits_for(
    mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any]
) -> None:
    """Every client sees every answer on the service's response topics; it must keep only its
    own, or a long-running client grows with everyone else's traffic."""
    me = Identity(name="delegator0", agent_type="ground", agent_uuid="x", prefix=prefix)
    fake = collector(f"{me.base}/delegation/command")
    with ServiceClient(mqtt_settings, prefix=prefix, service_timeout=5.0) as client:
        hb = heartbeat(me, ["delegation"], 0.0)
        for _ in range(50):  # until the client's subscriptions are surely active
            fake.publish(hb.topic, hb.payload)
            try:
                client.wait_service(0.1)
                break
            except ServiceUnavailable:
                continue
        client.wait_service(0.0)
        for i in range(50):  # answers to other clients' commands
            fake.publish(f"{me.base}/delegation/response",
                         {"response-to": f"someone-else-{i}", "response": "ok"})

        def answer_when_asked() -> None:
            cmd = fake.wait_json(f"{me.base}/delegation/command", timeout=10.0)
            fake.publish(f"{me.base}/delegation/response",
                         {"response-to": cmd["com-uuid"], "response": "pong"})

        helper = threading.Thread(target=answer_when_asked)
        helper.start()
        try:
            answer = client.request({"command": "ping"}, timeout=10.0)
        finally:
            helper.join(15.0)
        assert answer["response"] == "pong"
        assert client.answers_held == 0
        with pytest.raises(ServiceUnavailable, match="did not answer"):
            client.request({"command": "ping"}, timeout=0.3, resend_every=0.1)
        assert client.answers_held == 0
    assert json.loads(hb.payload)["levels"] == ["delegation"]
