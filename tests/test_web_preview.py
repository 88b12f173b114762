"""Plan previews cost at most one plan in flight per user (issue 23: ``["optimal"] * 500``
queued 500 delegate commands that held the page's threads and the service's planner for hours).

The page in front of a bridge whose `plan` blocks until the test lets it go: what reaches the
bridge, and when a second preview is refused, is decided by the page alone."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from delegation.runtime.settings import BrokerSettings
from delegation.web.app import create_app
from delegation.web.auth import read_users
from delegation.web.bridge import Bridge
from delegation.web.server import WebServer

MISSION = {"name": "move-to", "params": {"waypoint": {"latitude": 57.76, "longitude": 16.68,
                                                      "altitude": 30.0}}}


class HeldBridge(Bridge):
    """Records each preview asked of it and holds it until ``release`` is set."""

    def __init__(self) -> None:
        super().__init__(BrokerSettings(host="127.0.0.1", port=1))  # never started: no I/O
        self.asked: list[tuple[str, list[str]]] = []
        self.arrived = threading.Semaphore(0)
        self.release = threading.Event()

    def plan(self, tree: dict[str, Any], strategies: list[str], objective: str | None,
             time_limit: float | None, sender: str) -> dict[str, Any]:
        self.asked.append((sender, strategies))
        self.arrived.release()
        assert self.release.wait(30.0)
        return {s: {"fail-reason": "held"} for s in strategies}


@pytest.fixture
def held(tmp_path: Path) -> Iterator[tuple[HeldBridge, str]]:
    users = tmp_path / "users"
    users.write_text("alice-token-1 alice\nbob-token-22 bob\n")
    bridge = HeldBridge()
    server = WebServer(create_app(bridge, users=read_users(users)), "127.0.0.1", 0).start()
    try:
        yield bridge, server.url
    finally:
        bridge.release.set()
        server.stop()
        bridge.stop()


def _post(url: str, token: str, body: dict[str, Any]) -> httpx.Response:
    return httpx.post(f"{url}/api/plan", json=body, timeout=30.0,
                      headers={"Authorization": f"Bearer {token}"})


def test_strategies_are_deduplicated_and_limited_to_the_registrys(
        held: tuple[HeldBridge, str]) -> None:
    bridge, url = held
    bridge.release.set()
    many = _post(url, "alice-token-1", {"mission": MISSION, "strategies": ["optimal"] * 500
                                        + ["nearest", "optimal"]})
    assert many.status_code == 200, many.text
    assert bridge.asked == [("alice", ["optimal", "nearest"])]
    unknown = _post(url, "alice-token-1", {"mission": MISSION, "strategies": ["optimal", "x"]})
    assert unknown.status_code == 400 and "strategy" in unknown.json()["fail-reason"]
    assert len(bridge.asked) == 1


def test_one_preview_in_flight_per_user(held: tuple[HeldBridge, str]) -> None:
    bridge, url = held
    first: list[httpx.Response] = []
    thread = threading.Thread(target=lambda: first.append(
        _post(url, "alice-token-1", {"mission": MISSION, "strategies": ["optimal"]})))
    thread.start()
    try:
        assert bridge.arrived.acquire(timeout=20.0), "the first preview never reached the bridge"
        for _ in range(3):
            again = _post(url, "alice-token-1", {"mission": MISSION})
            assert again.status_code == 429, again.text
            assert "in flight" in again.json()["fail-reason"]
        other: list[httpx.Response] = []  # another user is not held up by alice
        bobs = threading.Thread(target=lambda: other.append(
            _post(url, "bob-token-22", {"mission": MISSION, "strategies": ["nearest"]})))
        bobs.start()
        assert bridge.arrived.acquire(timeout=20.0), "bob's preview never reached the bridge"
    finally:
        bridge.release.set()
        thread.join(30.0)
    bobs.join(30.0)
    assert first[0].status_code == 200 and other[0].status_code == 200
    assert [who for who, _ in bridge.asked] == ["alice", "bob"]
    after = _post(url, "alice-token-1", {"mission": MISSION, "strategies": ["nearest"]})
    assert after.status_code == 200, after.text  # free again once the first one ended


def test_a_start_names_a_preview_by_its_id_or_is_refused(held: tuple[HeldBridge, str]) -> None:
    _, url = held
    for bad in (5, "", "x" * 129, ["p-1"]):
        answer = httpx.post(f"{url}/api/missions", json={"mission": MISSION, "preview": bad},
                            timeout=30.0, headers={"Authorization": "Bearer alice-token-1"})
        assert answer.status_code == 400 and "preview" in answer.json()["fail-reason"], bad
