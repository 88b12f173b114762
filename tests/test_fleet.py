"""The fleet registry: liveness, reboots, busy/idle, positions, profiles (explicit ``now``)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from delegation.fleet import (
    DEFAULT_SPEEDS,
    FleetEventKind,
    FleetRegistry,
    UnitState,
    make_unit,
)
from delegation.geo import GeoPoint
from delegation.messages import INFO, decode
from delegation.topics import split_unit_topic

BASE = "waraps/unit/air/simulation/dji0"
BOAT = "waraps/unit/surface/real/piraya0"


def feed(reg: FleetRegistry, topic: str, payload: Any, now: float) -> None:
    """Publish-like: encode JSON, decode it as the service does, observe it."""
    reg.observe(topic, decode(topic, json.dumps(payload).encode()), now)


def heartbeat(
    name: str = "dji0", uuid: str = "uuid-1", rate: float = 1.0, **kw: Any
) -> dict[str, Any]:
    return {
        "agent-type": kw.pop("agent_type", "air"),
        "agent-uuid": uuid,
        "levels": kw.pop("levels", ["sensor", "direct execution"]),
        "name": name,
        "rate": rate,
        "stamp": 1614080475.1,
        "type": "HeartBeat",
    }


def dei(
    name: str = "dji0",
    tasks: tuple[str, ...] = ("move-to", "search-area"),
    executing: list[dict[str, str]] | None = None,
) -> dict[str, Any]:
    msg: dict[str, Any] = {
        "name": name,
        "rate": 1.0,
        "stamp": 1614080836.5,
        "type": "DirectExecutionInfo",
        "tasks-available": [{"name": t, "signals": ["$abort", "$enough"]} for t in tasks],
    }
    if executing is not None:
        msg["tasks-executing"] = executing
    return msg


POSITION = {
    "altitude": 40.0,
    "latitude": 57.7611363,
    "longitude": 16.6805011,
    "rostype": "GeoPoint",
}


def live_unit(reg: FleetRegistry, base: str = BASE, now: float = 100.0, **hb: Any) -> None:
    name = base.rsplit("/", 1)[-1]
    feed(reg, f"{base}/heartbeat", heartbeat(name, **hb), now)
    feed(reg, f"{base}/direct_execution_info", dei(name), now)
    feed(reg, f"{base}/sensor/position", POSITION, now)


def only(reg: FleetRegistry, now: float) -> UnitState:
    units = reg.snapshot(now)
    assert len(units) == 1
    return units[0]


# --------------------------------------------------------------------------- liveness


def test_alive_for_three_periods_but_at_least_five_seconds() -> None:
    reg = FleetRegistry()
    live_unit(reg, rate=1.0, now=100.0)  # 3 periods = 3 s -> 5 s minimum
    assert only(reg, 100.0).alive
    assert only(reg, 104.9).alive
    assert not only(reg, 105.0).alive
    slow = FleetRegistry(max_timeout=60.0)
    live_unit(slow, rate=0.1, now=100.0)  # 3 periods = 30 s
    assert only(slow, 129.0).alive
    assert not only(slow, 130.5).alive


def test_a_very_low_advertised_rate_is_capped() -> None:
    reg = FleetRegistry()  # max_timeout 15 s
    live_unit(reg, rate=1e-4, now=100.0)  # 3 periods = 30,000 s
    assert only(reg, 114.9).alive
    assert not only(reg, 115.0).alive
    assert reg.timeout(1e-4) == 15.0


def test_check_reports_a_lost_unit_once_until_it_comes_back() -> None:
    reg = FleetRegistry()
    live_unit(reg, rate=1.0, now=100.0)
    reg.drain_events()
    assert reg.check(104.0) == []
    lost = reg.check(105.0)
    assert [(e.kind, e.name, e.at) for e in lost] == [(FleetEventKind.LOST, "dji0", 105.0)]
    assert reg.check(106.0) == []
    assert [e.kind for e in reg.drain_events()] == [FleetEventKind.LOST]
    live_unit(reg, rate=1.0, now=110.0)
    assert reg.check(112.0) == []
    assert [e.kind for e in reg.check(115.0)] == [FleetEventKind.LOST]


def test_liveness_is_configurable() -> None:
    reg = FleetRegistry(min_timeout=1.0, periods=2.0)
    live_unit(reg, rate=3.0, now=10.0)  # 2/3 s -> 1 s minimum
    assert reg.is_alive("dji0", 10.9)
    assert not reg.is_alive("dji0", 11.0)
    assert reg.timeout(0.25) == 8.0
    assert reg.timeout(None) == 1.0
    assert reg.timeout(0.0) == 1.0


def test_a_fresh_heartbeat_revives_a_unit() -> None:
    reg = FleetRegistry()
    live_unit(reg, now=0.0)
    assert not reg.is_alive("dji0", 60.0)
    feed(reg, f"{BASE}/heartbeat", heartbeat(), 60.0)
    assert reg.is_alive("/dji0", 60.0)


def test_info_without_heartbeat_is_not_alive() -> None:
    reg = FleetRegistry()
    feed(reg, f"{BASE}/direct_execution_info", dei(), 5.0)
    feed(reg, f"{BASE}/sensor/position", POSITION, 5.0)
    unit = only(reg, 5.0)
    assert not unit.alive
    assert unit.tasks == frozenset({"move-to", "search-area"})


# --------------------------------------------------------------------------- busy, reboots


def test_busy_from_tasks_executing_in_both_spellings() -> None:
    reg = FleetRegistry()
    live_unit(reg)
    assert not only(reg, 100.0).busy  # tasks-executing missing is normal
    feed(
        reg,
        f"{BASE}/direct_execution_info",
        dei(executing=[{"task-name": "move-to", "task-uuid": "t1"}]),
        101.0,
    )
    assert only(reg, 101.0).busy
    assert reg.executing("dji0") == [("move-to", "t1")]
    feed(reg, f"{BASE}/direct_execution_info", dei(executing=[]), 102.0)
    assert not only(reg, 102.0).busy
    feed(
        reg,
        f"{BASE}/direct_execution_info",
        dei(executing=[{"name": "move-path", "uuid": "t2"}]),
        103.0,
    )
    assert reg.executing("dji0") == [("move-path", "t2")]


def test_a_new_agent_uuid_means_a_reboot_that_lost_the_tasks() -> None:
    reg = FleetRegistry()
    live_unit(reg, uuid="boot-1", now=10.0)
    assert [e.kind for e in reg.drain_events()] == [FleetEventKind.APPEARED]
    feed(
        reg,
        f"{BASE}/direct_execution_info",
        dei(executing=[{"task-name": "move-to", "task-uuid": "t1"}]),
        11.0,
    )
    feed(reg, f"{BASE}/heartbeat", heartbeat(uuid="boot-1"), 12.0)
    assert only(reg, 12.0).busy
    assert reg.drain_events() == []  # same uuid: no reboot
    feed(reg, f"{BASE}/heartbeat", heartbeat(uuid="boot-2"), 13.0)
    unit = only(reg, 13.0)
    assert not unit.busy and unit.alive
    events = reg.drain_events()
    assert [(e.kind, e.name, e.at) for e in events] == [(FleetEventKind.REBOOTED, "dji0", 13.0)]
    assert reg.agents(13.0)[0]["reboots"] == 1
    assert reg.drain_events() == []


# --------------------------------------------------------------------------- what a unit looks like


def test_snapshot_view_of_a_unit() -> None:
    reg = FleetRegistry()
    live_unit(reg)
    unit = only(reg, 100.0)
    assert unit.name == "dji0"
    assert unit.agent_type == "air"
    assert unit.position == GeoPoint(latitude=57.7611363, longitude=16.6805011, altitude=40.0)
    assert unit.speeds == DEFAULT_SPEEDS["air"]
    assert unit.base_topic == BASE
    assert reg.base_topic("dji0") == BASE
    assert reg.base_topic("nobody") is None


def test_base_topic_is_the_heartbeat_topic_minus_heartbeat() -> None:
    reg = FleetRegistry()
    feed(reg, "lab-7/unit/ground/simulation/spot1/sensor/position", POSITION, 1.0)
    feed(
        reg,
        "lab-7/unit/ground/simulation/spot1/heartbeat",
        heartbeat("spot1", agent_type="ground"),
        1.0,
    )
    assert reg.base_topic("spot1") == "lab-7/unit/ground/simulation/spot1"
    assert split_unit_topic("a/b/c/sensor/position") == ("a/b/c", "sensor/position")
    assert split_unit_topic("a/b/c/exec/feedback") == ("a/b/c", "exec/feedback")
    assert split_unit_topic("something/else") is None
    for info in INFO:  # every info topic the messages know is read under its unit
        assert split_unit_topic(f"a/b/c/{info}") == ("a/b/c", info)


def test_position_updates_and_bare_sensor_values() -> None:
    reg = FleetRegistry()
    live_unit(reg)
    moved = GeoPoint(latitude=57.77, longitude=16.69, altitude=10.0)
    reg.observe(f"{BASE}/sensor/position", moved, 101.0)  # a value from parse_sensor
    assert only(reg, 101.0).position == moved
    feed(reg, f"{BASE}/sensor/speed", 3.0, 101.0)  # read, not needed for planning
    assert only(reg, 101.0).position == moved


@pytest.mark.parametrize(
    ("payload", "expected"),
    [(0.42, 0.42), (87.0, 0.87), ({"percentage": 0.3, "voltage": 24.1}, 0.3)],
)
def test_battery_sensor(payload: Any, expected: float) -> None:
    reg = FleetRegistry(profiles={"dji0": {"endurance": 1000.0}})
    live_unit(reg)
    feed(reg, f"{BASE}/sensor/battery_state", payload, 101.0)
    unit = only(reg, 101.0)
    assert unit.battery == pytest.approx(expected)
    assert unit.remaining_endurance == pytest.approx(expected * 1000.0)


def test_profiles_by_name_override_profiles_by_type() -> None:
    profiles = {
        "air": {"speeds": {"slow": 5.0, "standard": 10.0, "fast": 20.0}, "endurance": 900.0},
        "dji0": {
            "speeds": {"standard": 8.0},
            "home": POSITION,
            "camera-fov": 90.0,
            "sweep-altitude": 60.0,
        },
    }
    reg = FleetRegistry(profiles=profiles)
    live_unit(reg)
    live_unit(reg, base="waraps/unit/air/simulation/dji1")
    live_unit(reg, base=BOAT, agent_type="surface")
    units = {u.name: u for u in reg.snapshot(100.0)}
    assert units["dji0"].speeds == {"slow": 4.0, "standard": 8.0, "fast": 16.0}
    assert units["dji0"].home == GeoPoint.model_validate(POSITION)
    assert units["dji0"].camera_fov_deg == 90.0 and units["dji0"].sweep_altitude == 60.0
    assert units["dji0"].endurance == 900.0  # from the type profile
    assert units["dji1"].speeds == {"slow": 5.0, "standard": 10.0, "fast": 20.0}
    assert units["piraya0"].speeds == DEFAULT_SPEEDS["surface"]
    assert units["piraya0"].endurance is None


def test_engines_and_units_without_position_are_not_planned_for() -> None:
    reg = FleetRegistry()
    live_unit(reg)
    feed(
        reg,
        "waraps/unit/ground/real/op0/heartbeat",
        heartbeat("op0", agent_type="ground", levels=["tst execution"]),
        100.0,
    )
    feed(
        reg, f"{BOAT}/heartbeat", heartbeat("piraya0", agent_type="surface"), 100.0
    )  # no position yet
    assert [u.name for u in reg.snapshot(100.0)] == ["dji0"]
    assert reg.names() == ["dji0", "op0", "piraya0"]
    rows = {r["name"]: r for r in reg.agents(100.0)}
    assert rows["piraya0"]["position"] is None and rows["piraya0"]["alive"]
    assert rows["op0"]["levels"] == ["tst execution"]
    assert rows["dji0"]["tasks-available"] == ["move-to", "search-area"]
    assert rows["dji0"]["state"] == "idle"
    assert [r["name"] for r in reg.agents(200.0, alive_only=True)] == []


def test_direct_execution_level_spelled_with_underscore() -> None:
    reg = FleetRegistry()
    feed(reg, f"{BASE}/heartbeat", heartbeat(levels=["sensor", "direct_execution"]), 1.0)
    feed(reg, f"{BASE}/sensor/position", POSITION, 1.0)
    assert only(reg, 1.0).alive


def test_other_messages_only_refresh_last_seen() -> None:
    reg = FleetRegistry()
    live_unit(reg, now=1.0)
    feedback = {"agent-uuid": "uuid-1", "com-uuid": "c1", "status": "running", "task-uuid": "t1"}
    feed(reg, f"{BASE}/exec/feedback", feedback, 3.0)
    assert reg.last_seen("dji0") == 3.0
    assert not only(reg, 7.0).alive  # feedback is no heartbeat
    reg.observe("not/a/unit", object(), 8.0)  # ignored
    reg.forget("dji0")
    assert reg.snapshot(8.0) == []


def test_remaining_endurance() -> None:
    p = GeoPoint(latitude=58.0, longitude=15.0)
    assert make_unit("a", "air", p, ["move-to"]).remaining_endurance is None
    assert make_unit("a", "air", p, ["move-to"], endurance=600.0).remaining_endurance == 600.0
    assert (
        make_unit("a", "air", p, ["move-to"], endurance=600.0, battery=0.5).remaining_endurance
        == 300.0
    )
