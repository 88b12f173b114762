"""The shipped mosquitto ACL (deploy/mosquitto.acl) with the whole system, each part logged in
with its own username and password: the service, the engine and the units work; a mission client
commands the service on its own topics; a user without grants can neither command the engine nor
speak for a unit."""

from __future__ import annotations

import json
import queue
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from delegation.fleet import make_unit
from delegation.geo import LocalFrame
from delegation.local import LocalSystem
from delegation.messages import HeartBeat, encode
from delegation.runtime.broker import PrivateMosquitto, mosquitto_binary
from delegation.runtime.mqtt import MqttClient, MqttConnectError
from delegation.runtime.settings import BrokerSettings
from delegation.service import ServiceConfig
from pki import HAVE_TOOLS, make_password_file

pytestmark = [
    pytest.mark.mqtt,
    pytest.mark.skipif(
        mosquitto_binary() is None or not HAVE_TOOLS,
        reason="needs mosquitto, mosquitto_passwd and openssl",
    ),
]

ACL = Path(__file__).resolve().parents[1] / "deploy" / "mosquitto.acl"
FRAME = LocalFrame(57.7605, 16.6815)
USERS = ["delegator0", "op0", "dji0", "dji1", "operator1", "client1", "mallory"]
BASE = "waraps/unit/ground/simulation/delegator0"


@pytest.fixture(scope="module")
def acl_broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[PrivateMosquitto]:
    d = tmp_path_factory.mktemp("acl")
    passwords = make_password_file(d / "passwords", {u: f"pw-{u}" for u in USERS})
    broker = PrivateMosquitto(password_file=str(passwords), acl_file=str(ACL))
    broker.start()
    try:
        yield broker
    finally:
        broker.stop()


def login(broker: PrivateMosquitto, user: str) -> BrokerSettings:
    return broker.settings().model_copy(update={"username": user, "password": f"pw-{user}"})


def client(broker: PrivateMosquitto, user: str, *patterns: str) -> MqttClient:
    c = MqttClient(login(broker, user), f"{user}-{uuid.uuid4().hex[:6]}")
    for p in patterns:
        c.subscribe(p)
    c.connect()
    return c


def wait_json(c: MqttClient, topic: str, pred: Any, timeout: float = 20.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            msg = c.messages.get(timeout=max(0.01, deadline - time.monotonic()))
        except queue.Empty:
            break
        if msg.topic == topic:
            data = json.loads(msg.payload)
            if pred(data):
                return dict(data)
    raise AssertionError(f"nothing matching on {topic} within {timeout} s")


def test_anonymous_is_refused(acl_broker: PrivateMosquitto) -> None:
    with pytest.raises(MqttConnectError):
        MqttClient(acl_broker.settings()).connect(timeout=5)


def test_the_system_works_under_the_acl(acl_broker: PrivateMosquitto) -> None:
    units = [
        make_unit("dji0", "air", FRAME.geopoint(0, 0, 30), ["move-to"]),
        make_unit("dji1", "air", FRAME.geopoint(100, 0, 30), ["move-to"]),
    ]
    creds = {u: login(acl_broker, u) for u in ("delegator0", "op0", "dji0", "dji1")}
    config = ServiceConfig(prefix="waraps", operators=frozenset({"operator1"}))
    mine = f"{BASE}/delegation/response/client1"
    with LocalSystem(
        units, settings=login(acl_broker, "mallory"), config=config, speedup=20.0, credentials=creds
    ) as system:  # ready: the service and engine see the fleet
        assert system.engine is not None and system.service is not None
        c1 = client(acl_broker, "client1", mine, f"{BASE}/delegation/feedback")
        ops = client(acl_broker, "operator1", f"{BASE}/delegation/response")
        evil = client(acl_broker, "mallory")
        try:
            tree = {
                "name": "move-to",
                "common_params": {"node-uuid": "acl-root"},
                "params": {"waypoint": FRAME.geopoint(30, 0, 30).to_wire()},
            }
            c1.publish(
                f"{BASE}/delegation/command/client1",
                json.dumps({"com-uuid": "c1", "command": "delegate", "tst": tree, "start": True}),
                qos=1,
            )
            started = wait_json(c1, mine, lambda d: d.get("response-to") == "c1")
            assert started["response"] == "started", started
            wait_json(
                c1,
                f"{BASE}/delegation/feedback",
                lambda d: d["root-uuid"] == "acl-root" and d["status"] == "succeeded",
                60,
            )

            ops.publish(
                f"{BASE}/delegation/command",
                json.dumps({"com-uuid": "o1", "command": "list-missions", "sender": "operator1"}),
                qos=1,
            )
            listed = wait_json(
                ops, f"{BASE}/delegation/response", lambda d: d.get("response-to") == "o1"
            )
            assert [(m["root-uuid"], m["owner"]) for m in listed["missions"]] == [
                ("acl-root", "client1")
            ]

            # mallory has no grants: a tree straight to the engine, a unit's heartbeat and a
            # command on the service's shared topic are all dropped by the broker.
            engine_cmd = "waraps/unit/ground/simulation/op0/tst/command"
            evil.publish(
                engine_cmd,
                json.dumps(
                    {"com-uuid": "e1", "command": "start-tst", "sender": "mallory", "tst": tree}
                ),
                qos=1,
            )
            hb = HeartBeat(
                agent_type="air",
                agent_uuid="evil",
                levels=["direct execution"],
                name="dji0",
                rate=20.0,
                stamp=time.time(),
            )
            evil.publish("waraps/unit/air/evil/dji0/heartbeat", encode(hb), qos=1)
            evil.publish(
                f"{BASE}/delegation/command",
                json.dumps(
                    {"com-uuid": "m1", "command": "cancel-mission", "root-uuid": "acl-root"}
                ),
                qos=1,
            )
            engine = system.engine
            assert not engine.wait_until(lambda core: "evil" in str(core.bases), 1.5)
            assert engine.inspect(lambda core: core.commands.get(("tst", "e1"))) is None
            assert (
                system.service.inspect(lambda core: core.commands.get(("delegation", "m1"))) is None
            )
        finally:
            for c in (c1, ops, evil):
                c.disconnect()
