"""Delegation between delegators (DESIGN 3.14, docs/protocol.md §15), message by message.

Pure: the service core and the fleet registry are fed bytes with ``now``; planning jobs run with
the real planner, as the unit's worker would.
"""

from __future__ import annotations

import json
from typing import Any

from delegation.fleet import FleetRegistry
from delegation.messages import DelegationInfo, HeartBeat, encode
from delegation.service import ServiceConfig, ServiceCore
from test_service_core import PREFIX, feed_engine, feed_unit, on

OTHER = f"{PREFIX}/unit/ground/simulation/delegator-b"


def feed_delegator(core: ServiceCore | FleetRegistry, now: float, *, name: str = "delegator-b",
                   tasks: list[str] | None = None, managed: list[str] | None = None,
                   levels: tuple[str, ...] = ("tst execution", "delegation")) -> None:
    """Another delegation service's heartbeat and ``delegation_info``."""
    base = f"{PREFIX}/unit/ground/simulation/{name}"
    hb = HeartBeat(agent_type="ground", agent_uuid=f"uuid-{name}", levels=list(levels),
                   name=name, rate=1.0, stamp=now)
    info = DelegationInfo(name=name, rate=1.0, stamp=now,
                          tasks_available=["move-to"] if tasks is None else tasks,
                          units_managed=["b-air0"] if managed is None else managed)
    for rest, payload in (("heartbeat", encode(hb)), ("delegation_info", encode(info))):
        if isinstance(core, FleetRegistry):
            from delegation.messages import decode

            core.observe(f"{base}/{rest}", decode(f"{base}/{rest}", payload), now)
        else:
            core.on_message(f"{base}/{rest}", payload, now)


def two_fleets(config: ServiceConfig | None = None) -> ServiceCore:
    """Our unit dji0 near Granso, delegator-b managing b-air0 (which we also hear)."""
    core = ServiceCore(config or ServiceConfig(prefix=PREFIX))
    feed_unit(core, "dji0", 57.7605, 16.6815, ["move-to", "search-area"], 100.0)
    feed_unit(core, "b-air0", 58.3900, 15.5700, ["move-to"], 100.0)
    feed_engine(core, 100.0)
    feed_delegator(core, 100.0)
    return core


# --------------------------------------------------------------------------- item 1


def test_delegation_info_reads_the_fleet_summary_in_either_spelling() -> None:
    info = DelegationInfo.model_validate(
        {"name": "b", "rate": 1.0, "stamp": 1.0, "units-managed": ["/b-air0"],
         "tasks-available": ["move-to", {"name": "search-area", "signals": []}]})
    assert info.tasks_available == ["move-to", "search-area"]
    assert info.to_wire()["units-managed"] == ["/b-air0"]


def test_a_unit_with_delegation_level_and_info_is_a_delegator() -> None:
    reg = FleetRegistry()
    feed_delegator(reg, 10.0, managed=["/b-air0", "b-air1"])
    feed_delegator(reg, 10.0, name="engine-only", levels=("tst execution",))
    [d] = reg.delegators(10.0)
    assert (d.name, d.execunit, d.units_managed) == ("delegator-b", "/delegator-b",
                                                     frozenset({"b-air0", "b-air1"}))
    assert d.can_take(["move-to"]) and not d.can_take(["move-to", "search-area"])
    assert not d.can_take([])
    assert reg.managed_by(10.0) == {"b-air0": "delegator-b", "b-air1": "delegator-b"}
    assert reg.delegators(100.0) == [] and reg.managed_by(100.0) == {}  # lost: manages nobody
    row = next(r for r in reg.agents(10.0) if r["name"] == "delegator-b")
    assert row["delegator"] is True and row["delegates-tasks"] == ["move-to"]
    assert "delegator" not in next(r for r in reg.agents(10.0) if r["name"] == "engine-only")


def test_units_another_delegator_manages_are_not_planned_directly() -> None:
    core = two_fleets()
    assert [u.name for u in core.units(101.0)] == ["dji0"]
    agents = {r["name"]: r for r in on(_delegation(core, {"command": "list-agents"}),
                                       "delegation/response")[0]["agents"]}
    assert agents["delegator-b"]["delegator"] is True
    assert agents["delegator-b"]["units-managed"] == ["b-air0"]
    assert agents["b-air0"]["managed-by"] == "delegator-b" and "speeds" not in agents["b-air0"]
    assert "speeds" in agents["dji0"]
    # ``fleet`` names the own units outright.
    named = two_fleets(ServiceConfig(prefix=PREFIX, fleet=frozenset({"dji0", "b-air0"})))
    assert [u.name for u in named.units(101.0)] == ["b-air0", "dji0"]


def test_our_delegation_info_says_what_our_fleet_can_do_and_whom_we_manage() -> None:
    core = two_fleets()
    [info] = [json.loads(o.payload) for o in core.status(101.0, 1e9)
              if o.topic.endswith("/delegation_info")]
    assert info["tasks-available"] == ["move-to", "search-area"]
    assert info["units-managed"] == ["dji0"]
    # Another service reading it sees a delegator.
    reg = FleetRegistry()
    feed_delegator(reg, 5.0, tasks=info["tasks-available"], managed=info["units-managed"])
    assert reg.managed_by(5.0) == {"dji0": "delegator-b"}


def _delegation(core: ServiceCore, command: dict[str, Any], now: float = 101.0) -> Any:
    from test_service_core import delegation

    return delegation(core, command, now)
