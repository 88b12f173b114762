"""An offer round cut by ``kill -9`` (docs/protocol.md §15.2, "Offer rounds and restarts").

The round is not stored, by design: it lives at most the bid window, and what it decides is kept
by what follows it (the plan's answer, the mission). The command that opened it is stored as
pending before the asks go out, so a restarted service answers it ``failed`` (nothing was
started), and an offer that arrives for the old round is ignored. Real processes: ``delegation
serve`` in a subprocess with an SQLite state file, killed with SIGKILL; the fleet and the engine
in this process; the partner a fake delegator that never answers in time.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

import cli_forks
from delegation.fleet import make_unit
from delegation.local import LocalSystem
from delegation.runtime.broker import PrivateMosquitto
from delegation.runtime.settings import BrokerSettings
from delegation.service import ServiceConfig
from test_e2e_service import AIR_TASKS, FRAME, move_to

pytestmark = [pytest.mark.mqtt, pytest.mark.slow]


@pytest.fixture
def mqtt_settings(mosquitto: PrivateMosquitto) -> BrokerSettings:
    """This module's own mosquitto only: what is tested is the store and the round, not the
    broker (both brokers are covered by tests/test_federation_mqtt.py), and every run here
    starts two service processes."""
    return mosquitto.settings()


@pytest.fixture
def serve(mqtt_settings: BrokerSettings, prefix: str, tmp_path: Path
          ) -> Iterator[Callable[[str], cli_forks.Forked]]:
    """Starts ``delegation serve NAME`` (state in tmp_path, a 30 s bid window, fleet dji0), a
    process of its own forked with the CLI imported (`cli_forks`); every process started is
    ended at the end."""
    started: list[cli_forks.Forked] = []

    def start(name: str) -> cli_forks.Forked:
        proc = cli_forks.spawn(
            ["-v", "serve", "--broker", mqtt_settings.host,
             "--port", str(mqtt_settings.port), "--prefix", prefix, "--name", name,
             "--state", str(tmp_path / "state.sqlite"), "--bid-window", "30",
             "--fleet", "dji0"], dict(os.environ), tmp_path / f"serve{len(started)}.log")
        started.append(proc)
        return proc

    yield start
    for proc in started:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)


def _request(watch: Any, base: str, body: dict[str, Any], timeout: float = 20.0
             ) -> dict[str, Any]:
    """Publish a command; its newest answer (a re-send is answered again)."""
    seen = sum(1 for d in watch.json_on(f"{base}/delegation/response")
               if d.get("response-to") == body["com-uuid"])
    watch.publish(f"{base}/delegation/command", body)
    watch.wait_for(lambda m: sum(1 for d in watch.json_on(f"{base}/delegation/response")
                                 if d.get("response-to") == body["com-uuid"]) > seen,
                   timeout=timeout, what=f"answer to {body['com-uuid']}")
    return [d for d in watch.json_on(f"{base}/delegation/response")
            if d.get("response-to") == body["com-uuid"]][-1]


def test_a_restart_mid_round_answers_the_command_failed_and_ignores_the_old_offers(
        mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any],
        serve: Callable[[str], cli_forks.Forked]) -> None:
    name = f"fed{uuid.uuid4().hex[:6]}"
    config = ServiceConfig(prefix=prefix, name=name)
    base = config.base_topic
    mute = f"{prefix}/unit/ground/simulation/mute"
    watch = collector(f"{base}/#", f"{mute}/#", f"{prefix}/unit/+/+/op0/tst/command",
                      f"{prefix}/unit/+/+/dji0/heartbeat")

    def mute_says_hello() -> None:
        watch.publish(f"{mute}/heartbeat", {
            "agent-type": "ground", "agent-uuid": "mute", "levels": ["tst execution",
                                                                     "delegation"],
            "name": "mute", "rate": 1.0, "stamp": time.time(), "type": "HeartBeat"})
        watch.publish(f"{mute}/delegation_info", {
            "name": "mute", "rate": 1.0, "stamp": time.time(), "tasks-available": ["move-to"],
            "units-managed": [], "type": "DelegationInfo"})

    units = [make_unit("dji0", "air", FRAME.geopoint(0, 0, 30), AIR_TASKS)]
    tree = {"name": "conc", "common_params": {"node-uuid": str(uuid.uuid4())},
            "children": [move_to(100, 0), move_to(0, 100)]}
    command = {"com-uuid": "c-1", "sender": "test", "command": "delegate", "tst": tree,
               "start": True}
    with LocalSystem(units, settings=mqtt_settings, config=config, service=False,
                     rates={"dji0": 5.0}):
        first = serve(name)
        known = watch.wait_json(f"{base}/heartbeat", timeout=30.0, what="the service up")
        deadline = time.monotonic() + 30.0
        while not any(a.get("name") == "mute" and a.get("delegator") for a in _request(
                watch, base, {"com-uuid": str(uuid.uuid4()), "sender": "test",
                              "command": "list-agents"}, timeout=30.0)["agents"]):
            assert time.monotonic() < deadline, "mute never listed as a delegator"
            mute_says_hello()
        watch.publish(f"{base}/delegation/command", command)
        watch.wait_json(f"{mute}/delegation/command/{name}", timeout=20.0,
                        what="an offer request")
        first.send_signal(signal.SIGKILL)  # mid-round: the window is 30 s
        first.wait(10)
        assert not [d for d in watch.json_on(f"{base}/delegation/response")
                    if d.get("response-to") == "c-1"]
        asks = watch.json_on(f"{mute}/delegation/command/{name}")

        second = serve(name)
        watch.wait_json(f"{base}/heartbeat", lambda d: d["agent-uuid"] != known["agent-uuid"],
                        timeout=30.0, what="the new instance up")  # (subscribed before it beats)
        deadline = time.monotonic() + 30.0
        while not any(a.get("name") == "dji0" for a in _request(
                watch, base, {"com-uuid": str(uuid.uuid4()), "sender": "test",
                              "command": "list-agents"}, timeout=30.0)["agents"]):
            assert time.monotonic() < deadline, "the new instance never heard dji0"
            watch.wait_for(lambda m: m.topic.endswith("/dji0/heartbeat"), timeout=5.0,
                           what="dji0's heartbeat")
        for ask in asks:  # the old round's offers, late: nobody waits for them
            watch.publish(f"{mute}/delegation/response/{name}", {
                "com-uuid": str(uuid.uuid4()), "response-to": ask["com-uuid"],
                "response": "ok", "plan": {"feasible": True, "makespan": 1.0,
                                           "total-time": 1.0, "total-distance": 1.0,
                                           "assignments": []}})
        again = _request(watch, base, command)
        assert again["response"] == "failed", again
        assert "restarted while this command was being worked on" in again["fail-reason"]
        assert "nothing was started" in again["fail-reason"]
        # Sent again with a new com-uuid it is planned (mute is not heard by this instance).
        fresh = _request(watch, base, {**command, "com-uuid": "c-2"}, timeout=30.0)
        assert fresh["response"] == "started", fresh
        assert len([d for d in watch.json_on(f"{base}/delegation/response")
                    if d.get("response-to") == "c-1"]) == 1  # the late offers changed nothing
        trees = [d for d in watch.json_on(f"{prefix}/unit/+/+/op0/tst/command")
                 if d.get("command") == "start-tst"]
        assert len(trees) == 1  # only c-2's
        assert second.poll() is None
