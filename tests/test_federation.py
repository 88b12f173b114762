"""Delegation between delegators (DESIGN 3.14, docs/protocol.md §15), message by message.

Pure: the service core and the fleet registry are fed bytes with ``now``; planning jobs run with
the real planner, as the unit's worker would.
"""

from __future__ import annotations

import json
from typing import Any

import pytest

from delegation.fleet import FleetRegistry
from delegation.messages import DelegationInfo, HeartBeat, TstResponse, decode, encode
from delegation.runtime.core import Effects
from delegation.service import ServiceConfig, ServiceCore
from delegation.tst.node import parse_tree, walk
from test_service_core import PREFIX, delegation, feed_engine, feed_unit, on, run_jobs

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
    def info_of(core: ServiceCore) -> dict[str, Any]:
        [info] = [json.loads(o.payload) for o in core.status(101.0, 1e9)
                  if o.topic.endswith("/delegation_info")]
        return dict(info)

    # Planning for whatever it hears, a service claims nothing (no race to claim first) ...
    assert info_of(two_fleets())["units-managed"] == []
    # ... its fleet named (serve --fleet), it claims that fleet's live units.
    info = info_of(two_fleets(ServiceConfig(prefix=PREFIX, fleet=frozenset({"dji0"}))))
    assert info["tasks-available"] == ["move-to", "search-area"]
    assert info["units-managed"] == ["dji0"]
    # Another service reading it sees a delegator.
    reg = FleetRegistry()
    feed_delegator(reg, 5.0, tasks=info["tasks-available"], managed=info["units-managed"])
    assert reg.managed_by(5.0) == {"dji0": "delegator-b"}


def _delegation(core: ServiceCore, command: dict[str, Any], now: float = 101.0) -> Any:
    return delegation(core, command, now)


# --------------------------------------------------------------------------- item 2: offers

GRANSO = (57.7605, 16.6815)
LINKOPING = (58.3900, 15.5700)
B_BASE = f"{PREFIX}/unit/ground/simulation/delegator-b"


def _move(uuid: str, lat: float, lon: float) -> dict[str, Any]:
    return {"name": "move-to", "common_params": {"node-uuid": uuid},
            "params": {"waypoint": {"latitude": lat, "longitude": lon, "altitude": 20.0}}}


def two_site_tree() -> dict[str, Any]:
    """One task near each fleet: the best plan sends each to the fleet near it."""
    return {"name": "conc", "common_params": {"node-uuid": "root-f"},
            "children": [_move("near-a", GRANSO[0] + 0.002, GRANSO[1]),
                         _move("near-b", LINKOPING[0] + 0.002, LINKOPING[1])]}


def partner(partners: frozenset[str] = frozenset({"delegator0", "op-a"})) -> ServiceCore:
    """delegator-b: its own service with b-air0 and its engine, hearing delegator0 as one."""
    b = ServiceCore(ServiceConfig(prefix=PREFIX, name="delegator-b", engine="op-b",
                                  partners=partners))
    feed_unit(b, "b-air0", *LINKOPING, ["move-to"], 100.0)
    hb = HeartBeat(agent_type="ground", agent_uuid="engine-b", levels=["tst execution"],
                   name="op-b", rate=1.0, stamp=100.0)
    b.on_message(f"{PREFIX}/unit/ground/simulation/op-b/heartbeat", encode(hb), 100.0)
    feed_delegator(b, 100.0, name="delegator0", tasks=["move-to", "search-area"],
                   managed=["dji0"])
    return b


def _delegate(core: ServiceCore, tree: dict[str, Any], now: float, com: str = "fed-1",
              **extra: Any) -> Any:
    command = {"com-uuid": com, "sender": "test", "command": "delegate", "tst": tree, **extra}
    return core.on_message(f"{PREFIX}/unit/ground/simulation/delegator0/delegation/command",
                           json.dumps(command).encode(), now)


def _asks(effects: Any) -> list[tuple[str, dict[str, Any]]]:
    return [(o.topic, json.loads(o.payload)) for o in effects.publish
            if "/delegation/command/" in o.topic]


def _answer_asks(b: ServiceCore, a: ServiceCore, asks: list[tuple[str, dict[str, Any]]],
                 now: float) -> Any:
    """delegator-b plans each ask (its worker), its answers reach delegator0."""
    released = []
    for topic, ask in asks:
        answered = run_jobs(b, b.on_message(topic, json.dumps(ask).encode(), now), now)
        assert answered.jobs == []  # b asked nobody: the caller is a delegator
        for o in answered.publish:
            if o.topic.endswith("/delegation/response/delegator0"):
                released.extend(a.on_message(o.topic, o.payload, now).jobs)
    return released


def test_offers_are_asked_in_parallel_and_compete_with_own_units() -> None:
    a, b = two_fleets(), partner()
    held = _delegate(a, two_site_tree(), 101.0)
    assert held.jobs == []  # planning waits for the offers
    asks = _asks(held)
    # The child near b's unit (not the one nearer ours); a lone child makes no bundle.
    assert [ask["tst"]["common_params"]["node-uuid"] for _, ask in asks] == ["near-b"]
    for topic, ask in asks:
        assert topic == f"{B_BASE}/delegation/command/delegator0"
        assert ask["preview"] is True and ask["sender"] == "delegator0"
    jobs = _answer_asks(b, a, asks, 101.2)
    assert len(jobs) == 1 and len(jobs[0].offers) == 1
    answer = on(run_jobs(a, Effects(jobs=jobs), 101.3), "delegation/response")[0]
    plan = answer["plan"]
    assert answer["response"] == "ok" and plan["feasible"] is True
    units = {x["node-uuid"]: x["execunit"] for x in plan["assignments"]}
    assert units == {"near-a": "/dji0", "near-b": "/delegator-b"}
    tree = plan["tst"]
    assert tree["common_params"]["node-uuid"] == "root-f"
    sent = {c["common_params"]["node-uuid"]: c["common_params"]["execunit"]
            for c in tree["children"]}
    assert sent == {"near-a": "/dji0", "near-b": "/delegator-b"}
    assert any("offer taken: root/children[1]" in n and "delegator-b" in n for n in plan["notes"])
    # Own fleet alone would fly dji0 ~70 km: the federated makespan is far below it.
    own_only = ServiceCore(ServiceConfig(prefix=PREFIX, federate=False))
    feed_unit(own_only, "dji0", *GRANSO, ["move-to", "search-area"], 100.0)
    feed_engine(own_only, 100.0)
    alone = on(run_jobs(own_only, _delegate(own_only, two_site_tree(), 101.0), 101.0),
               "delegation/response")[0]["plan"]
    assert plan["makespan"] < 0.1 * alone["makespan"]


def test_a_silent_delegator_is_left_out_at_the_end_of_the_window() -> None:
    a = two_fleets(ServiceConfig(prefix=PREFIX, bid_window=0.8))
    held = _delegate(a, two_site_tree(), 101.0)
    assert held.jobs == [] and len(_asks(held)) == 1
    assert a.on_tick(101.7).jobs == []  # within the window: still waiting
    [job] = a.on_tick(101.8).jobs  # the window ends: planned without it
    assert job.offers == ()
    assert any("delegator-b did not answer within 0.8 s: left out of root/children[1]" in n
               for n in job.notes)
    assert len(a.offers.durations) == 1 and abs(a.offers.durations[0] - 0.8) < 1e-9


def test_a_refusal_is_said_in_the_notes_and_a_late_answer_ignored() -> None:
    a = two_fleets()
    [(_, ask)] = _asks(_delegate(a, two_site_tree(), 101.0))
    refuse = {"com-uuid": "r1", "response": "failed", "response-to": ask["com-uuid"],
              "fail-reason": "not today"}
    # From someone we did not ask: ignored.
    other = f"{PREFIX}/unit/ground/simulation/mallory/delegation/response/delegator0"
    assert a.on_message(other, json.dumps(refuse).encode(), 101.1).jobs == []
    topic = f"{B_BASE}/delegation/response/delegator0"
    [job] = a.on_message(topic, json.dumps(refuse).encode(), 101.2).jobs
    assert job.offers == ()
    refused = [n for n in job.notes if "made no offer" in n]
    assert refused == ["delegator-b made no offer for root/children[1] (move-to near-b): not today"]
    late = a.on_message(topic, json.dumps(refuse).encode(), 101.3)
    assert late.jobs == [] and late.publish == []


def test_no_offers_asked_without_offerable_subtrees_or_for_a_delegator() -> None:
    a = two_fleets()
    single = _move("only", *GRANSO)
    assert len(_delegate(a, single, 101.0, com="one").jobs) == 1  # a lone task: not offered
    fixed = two_site_tree()  # near-b would be offered, but the caller named a unit for it
    fixed["children"][1]["common_params"]["execunit"] = "/dji0"
    effects = _delegate(a, fixed, 101.0, com="fixed")
    assert _asks(effects) == [] and len(effects.jobs) == 1
    b = partner()  # delegator0 is a delegator to b: b plans its ask with its own fleet
    command = {"com-uuid": "ask", "sender": "delegator0", "command": "delegate", "preview": True,
               "tst": two_site_tree()}
    got = b.on_message(f"{B_BASE}/delegation/command/delegator0", json.dumps(command).encode(),
                       101.0)
    assert len(got.jobs) == 1 and _asks(got) == []


def test_the_tasks_at_a_partners_site_are_offered_to_it_as_one_bundle() -> None:
    a, b = two_fleets(), partner()
    feed_unit(b, "b-air1", LINKOPING[0], LINKOPING[1] + 0.01, ["move-to"], 100.0)
    tree = two_site_tree()
    tree["children"].append(_move("near-b2", LINKOPING[0] - 0.003, LINKOPING[1]))
    asks = _asks(_delegate(a, tree, 101.0))
    [bundle] = [ask for _, ask in asks if ask["tst"]["name"] == "conc"]
    assert [c["common_params"]["node-uuid"] for c in bundle["tst"]["children"]] == [
        "near-b", "near-b2"]
    assert len(asks) == 3  # the two children at b's site, and their bundle
    [job] = _answer_asks(b, a, asks, 101.2)
    plan = on(run_jobs(a, Effects(jobs=[job]), 101.3), "delegation/response")[0]["plan"]
    units = {x["node-uuid"]: x["execunit"] for x in plan["assignments"]}
    assert units == {"near-a": "/dji0", "near-b": "/delegator-b", "near-b2": "/delegator-b"}
    [sent] = [c for c in plan["tst"]["children"]
              if c["common_params"].get("execunit") == "/delegator-b"]
    assert sent["name"] == "conc"
    assert sent["common_params"]["node-uuid"] == bundle["tst"]["common_params"]["node-uuid"]
    assert any(n.startswith("offer taken: root/children[1] (move-to near-b), root/children[2] "
                            "(move-to near-b2) goes to delegator-b") for n in plan["notes"])


def test_a_subtree_another_delegators_engine_hands_us_is_not_offered_again() -> None:
    b = partner()
    hb = HeartBeat(agent_type="ground", agent_uuid="op-a", levels=["tst execution"], name="op-a",
                   rate=1.0, stamp=100.0)
    b.on_message(f"{PREFIX}/unit/ground/simulation/op-a/heartbeat", encode(hb), 100.0)
    start = {"com-uuid": "from-op-a", "command": "start-tst", "sender": "op-a",
             "receiver": "delegator-b", "tst": two_site_tree()}
    got = b.on_message(f"{B_BASE}/tst/command", json.dumps(start).encode(), 101.0)
    assert len(got.jobs) == 1 and _asks(got) == []
    # The same from an operator asks delegator0 first (b has not heard where dji0 is: every
    # child delegator0 can take is offered to it).
    operator = {**start, "com-uuid": "from-op", "sender": "operator"}
    asked = b.on_message(f"{B_BASE}/tst/command", json.dumps(operator).encode(), 101.0)
    assert asked.jobs == [] and [a["tst"]["common_params"]["node-uuid"]
                                 for _, a in _asks(asked)] == ["near-a", "near-b"]


def test_a_delegator_plans_only_for_the_partners_it_trusts() -> None:
    b = partner()
    stranger = partner(frozenset())
    hb = HeartBeat(agent_type="ground", agent_uuid="op-x", levels=["tst execution"],
                   name="op-x", rate=1.0, stamp=100.0)
    stranger.on_message(f"{PREFIX}/unit/ground/simulation/op-x/heartbeat", encode(hb), 100.0)
    ask = {"com-uuid": "ask", "sender": "delegator0", "command": "delegate", "preview": True,
           "tst": two_site_tree()}
    topic = f"{B_BASE}/delegation/command/delegator0"
    refused = on(stranger.on_message(topic, json.dumps(ask).encode(), 101.0),
                 "delegation/response/delegator0")
    assert refused[0]["response"] == "failed"
    assert "delegator0 is another delegator (or its engine) that delegator-b does not trust: " \
           "start it with --partner delegator0" in refused[0]["fail-reason"]
    start = {"com-uuid": "st", "command": "start-tst", "sender": "op-x", "tst": two_site_tree()}
    answer = on(stranger.on_message(f"{B_BASE}/tst/command", json.dumps(start).encode(), 101.0),
                "tst/response")
    assert answer[0]["response"] == "failed" and "op-x" in answer[0]["fail-reason"]
    # Trusted (a partner), and anyone who is no delegator (an operator's C2 tool): planned.
    assert len(b.on_message(topic, json.dumps(ask).encode(), 101.0).jobs) == 1
    plain = {**start, "com-uuid": "st2", "sender": "c2-tool"}
    went = stranger.on_message(f"{B_BASE}/tst/command", json.dumps(plain).encode(), 101.0)
    assert on(went, "tst/response") == [] and (went.jobs or _asks(went))


# --------------------------------------------------------------------------- the demo


def test_the_federated_demo_splits_the_fleet_by_where_the_units_are() -> None:
    from delegation.cli.demo import split_partners
    from delegation.fleet import make_unit
    from delegation.geo import LocalFrame

    frame = LocalFrame(*GRANSO)
    units = [make_unit(f"u{x}", "air", frame.geopoint(x * 1000.0, (x % 2) * 50.0, 30),
                       ["move-to"]) for x in (3, 0, 2, 1)]
    ours, theirs = split_partners(units)
    assert [u.name for u in ours] == ["u0", "u1"] and [u.name for u in theirs] == ["u2", "u3"]
    assert split_partners(units[:1]) == (units[:1], [])


@pytest.mark.mqtt
@pytest.mark.slow
def test_demo_federated_runs_to_success_with_the_partner_doing_its_half(
        tmp_path: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    from delegation.cli import main

    for var in ("WARAPS_BROKER", "WARAPS_PORT"):
        monkeypatch.delenv(var, raising=False)  # the demo starts its own broker
    out = tmp_path / "out"
    # A long window: the round ends when delegator-b's offers are in, and on a loaded machine
    # (the suite on 2 cores) a fresh partner's first offers can take longer than the 1 s default.
    assert main(["demo", "--federated", "--speedup", "100", "--bid-window", "20",
                 "--out", str(out)]) == 0
    plan = json.loads((out / "plan.json").read_text())
    assert plan["feasible"]
    assert "/delegator-b" in {a["execunit"] for a in plan["assignments"]}
    assert any(n.startswith("offer taken") for n in plan["notes"])


def test_the_page_shows_which_delegator_manages_each_unit() -> None:
    from delegation.web.view import LiveView
    from test_web_view import live_unit

    view = LiveView()
    b_base = f"{PREFIX}/unit/ground/simulation/delegator-b"
    view.delegation_info(b_base, "delegator-b", {"units-managed": ["dji0", "/b1"]})
    live_unit(view)  # heard after the info: shown as delegator-b's at once
    [dji0] = view.units_since(0)
    assert dji0["name"] == "dji0" and dji0["managed-by"] == "delegator-b"
    seq = view.seq
    view.delegation_info(b_base, "delegator-b", {"units-managed": ["b1"]})  # no longer
    [changed] = view.units_since(seq)
    assert "managed-by" not in changed
    view.delegation_info(b_base, "delegator-b", {"units-managed": "not a list"})
    assert view.units["dji0"].managed_by == ""


def test_a_lost_delegator_s_single_task_is_re_delegated_like_a_lost_unit_s() -> None:
    from test_service_core import engine_answers

    a, b = two_fleets(), partner()
    held = _delegate(a, two_site_tree(), 101.0, start=True)
    planned = run_jobs(a, Effects(jobs=_answer_asks(b, a, _asks(held), 101.2)), 101.3)
    started = engine_answers(a, planned, "started", 101.4)
    assert on(started, "delegation/response")[0]["response"] == "started"
    for t in (105.0, 110.0, 115.0):  # dji0 and the engine go on, delegator-b falls silent
        feed_unit(a, "dji0", *GRANSO, ["move-to", "search-area"], t)
        feed_engine(a, t)
    moved = run_jobs(a, a.on_tick(116.0), 116.1)
    # Our dji0 takes it in its place in the running tree (the engine holds a delegated subtree
    # as one node: its replacement runs under that uuid); nothing else is touched.
    [rebind] = on(moved, "op0/tst/command")
    assert rebind["command"] == "rebind-tst-nodes" and rebind["execunits"] == {}
    [(uid, sub)] = rebind["subtrees"].items()
    assert uid == "near-b" and sub["common_params"]["node-uuid"] == "near-b"
    assert sub["name"] == "move-to" and sub["common_params"]["execunit"] == "/dji0"
    done = engine_answers(a, moved, "ok", 116.2)
    [event] = on(done, "delegation/feedback")
    assert event["status"] == "re-delegated" and "/delegator-b lost" in event["fail-reason"]
    assert [(t["replaces"], t["unit"]) for t in event["tasks"]] == [("near-b", "/dji0")]
    mission = a.book.get("root-f")
    assert "/delegator-b" not in json.dumps(mission.current_tst)
    assert mission.current_root == "root-f"  # the same tree runs on


def test_a_lost_delegator_s_bundle_is_re_delegated_task_by_task() -> None:
    from test_service_core import engine_answers

    a, b = two_fleets(), partner()
    feed_unit(b, "b-air1", LINKOPING[0], LINKOPING[1] + 0.01, ["move-to"], 100.0)
    tree = two_site_tree()
    tree["children"].append(_move("near-b2", LINKOPING[0] - 0.003, LINKOPING[1]))
    held = _delegate(a, tree, 101.0, start=True)
    planned = run_jobs(a, Effects(jobs=_answer_asks(b, a, _asks(held), 101.2)), 101.3)
    [sent] = on(planned, "op0/tst/command")
    [bundle] = [c for c in sent["tst"]["children"] if c["name"] == "conc"]
    # The tasks inside are named for the delegator too (it chooses; our engine unnames them).
    assert {c["common_params"]["execunit"] for c in bundle["children"]} == {"/delegator-b"}
    engine_answers(a, planned, "started", 101.4)
    for t in (105.0, 110.0, 115.0):
        feed_unit(a, "dji0", *GRANSO, ["move-to", "search-area"], t)
        feed_engine(a, t)
    moved = run_jobs(a, a.on_tick(116.0), 116.1)
    [rebind] = on(moved, "op0/tst/command")
    assert rebind["command"] == "rebind-tst-nodes"
    [(uid, sub)] = rebind["subtrees"].items()
    assert uid == bundle["common_params"]["node-uuid"] == sub["common_params"]["node-uuid"]
    assert {n.execunit for _, n in walk(parse_tree(sub)) if not n.is_control} == {"/dji0"}
    done = engine_answers(a, moved, "ok", 116.2)
    [event] = on(done, "delegation/feedback")
    assert sorted((t["replaces"], t["unit"]) for t in event["tasks"]) == [
        ("near-b", "/dji0"), ("near-b2", "/dji0")]
    # The new task nodes stand for the old: the operator hears them under the old uuids.
    mission = a.book.get("root-f")
    news = {t["node-uuid"]: t["replaces"] for t in event["tasks"]}
    assert all(mission.origin[new] == old for new, old in news.items())
    from test_service_redelegation import feedback

    relayed = feedback(a, next(iter(news)), "running", 117.0)
    assert [f["node-uuid"] for f in on(relayed, "tst/feedback")] == [news[next(iter(news))]]


def test_a_partners_plan_is_checked_not_trusted() -> None:
    from delegation.service.federated import Offer
    from delegation.tst.node import parse_tree

    child = parse_tree(_move("near-b", *LINKOPING))
    good = {"feasible": True, "makespan": 10.0, "total-time": 10.0, "total-distance": 50.0,
            "assignments": [{"node-uuid": "near-b", "name": "move-to", "start": 0.0,
                             "end": 10.0, "travel-time": 10.0, "work-time": 0.0,
                             "distance": 50.0}]}
    offer = Offer.of("delegator-b", child, good, ("near-b",))
    assert isinstance(offer, Offer) and offer.makespan == 10.0
    bad_time = {**good, "assignments": [{**good["assignments"][0], "start": "soon"}]}
    assert Offer.of("delegator-b", child, bad_time, ("near-b",)) == \
        "its plan has an assignment without finite times"
    assert Offer.of("delegator-b", child, {**good, "makespan": True}, ("near-b",)) == \
        "its plan has no makespan/total-time/total-distance"
    assert Offer.of("delegator-b", child, {**good, "assignments": []}, ("near-b",)) == \
        "its plan does not assign every task of the subtree"
    assert Offer.of("delegator-b", child, {**good, "feasible": False}, ("near-b",)) == \
        "its plan is infeasible"


NORRKOPING = (58.5877, 16.1924)


def three_partners(a: ServiceCore) -> tuple[ServiceCore, ServiceCore, Any]:
    """delegator-b (b-air0 at Linkoping) and delegator-c (c-air0 at Norrkoping) for ``a``; a
    mission with a task near each fleet, started with each partner's offer taken; returns b, c
    and ``c_is_alive(t)`` (c and its unit heard by ``a``)."""
    from test_service_core import engine_answers

    b = partner()
    c = ServiceCore(ServiceConfig(prefix=PREFIX, name="delegator-c", engine="op-c",
                                  partners=frozenset({"delegator0", "op-a"})))
    feed_unit(c, "c-air0", *NORRKOPING, ["move-to"], 100.0)
    hb = HeartBeat(agent_type="ground", agent_uuid="engine-c", levels=["tst execution"],
                   name="op-c", rate=1.0, stamp=100.0)
    c.on_message(f"{PREFIX}/unit/ground/simulation/op-c/heartbeat", encode(hb), 100.0)
    feed_delegator(c, 100.0, name="delegator0", tasks=["move-to", "search-area"],
                   managed=["dji0"])

    def c_is_alive(t: float) -> None:
        feed_unit(a, "c-air0", *NORRKOPING, ["move-to"], t)
        feed_delegator(a, t, name="delegator-c", managed=["c-air0"])

    c_is_alive(100.0)
    tree = two_site_tree()
    tree["children"].append(_move("near-c", NORRKOPING[0] + 0.002, NORRKOPING[1]))
    jobs = []
    for topic, ask in _asks(_delegate(a, tree, 101.0, start=True)):
        partner_core = b if "/delegator-b/" in topic else c
        jobs += _answered(partner_core, a, topic, ask, 101.1)
    planned = run_jobs(a, Effects(jobs=jobs), 101.3)
    [sent] = on(planned, "op0/tst/command")
    assert {ch["common_params"]["node-uuid"]: ch["common_params"]["execunit"]
            for ch in sent["tst"]["children"]} == {
        "near-a": "/dji0", "near-b": "/delegator-b", "near-c": "/delegator-c"}
    engine_answers(a, planned, "started", 101.4)
    for t in (105.0, 110.0, 115.0):  # delegator-b falls silent, the others go on
        feed_unit(a, "dji0", *GRANSO, ["move-to", "search-area"], t)
        feed_engine(a, t)
        c_is_alive(t)
    return b, c, c_is_alive


def _answered(partner_core: ServiceCore, a: ServiceCore, topic: str, ask: dict[str, Any],
              now: float) -> list[Any]:
    """A partner plans one offer request; the jobs its answer releases at ``a``."""
    answered = run_jobs(partner_core, partner_core.on_message(
        topic, json.dumps(ask).encode(), now), now)
    return [j for o in answered.publish if o.topic.endswith("/delegation/response/delegator0")
            for j in a.on_message(o.topic, o.payload, now).jobs]


def test_with_two_partners_one_lost_the_others_part_stays_with_it() -> None:
    from test_service_core import engine_answers

    a = two_fleets()  # no --fleet: b-air0, no longer delegator-b's, is ours and nearest
    three_partners(a)
    moved = run_jobs(a, a.on_tick(116.0), 116.1)
    [rebind] = on(moved, "op0/tst/command")  # no abort, no new tree: near-c runs on with c
    assert rebind["command"] == "rebind-tst-nodes" and list(rebind["subtrees"]) == ["near-b"]
    done = engine_answers(a, moved, "ok", 116.2)
    [event] = on(done, "delegation/feedback")
    assert event["status"] == "re-delegated"
    assert [(t["replaces"], t["unit"]) for t in event["tasks"]] == [("near-b", "/dji0")]
    mission = a.book.get("root-f")
    leaves = [n.execunit for _, n in walk(parse_tree(mission.current_tst)) if not n.is_control]
    assert sorted(leaves) == ["/delegator-c", "/dji0", "/dji0"]  # near-c stays with c


def test_a_lost_partners_part_goes_whole_to_another_partner_and_nothing_restarts() -> None:
    """delegator-b lost: its subtree is offered to delegator-c (nearer to it than our dji0),
    taken, and moved there within the running tree (rebind-tst-nodes of the subtree's root, uuids
    kept): delegator-c's own part and dji0's task run on, nothing is aborted or started again."""
    from test_service_core import ENGINE

    a = two_fleets(ServiceConfig(prefix=PREFIX, fleet=frozenset({"dji0"})))
    _, c, c_is_alive = three_partners(a)
    held = a.on_tick(116.0)
    assert held.jobs == [] and on(held, "delegation/feedback") == []  # waiting for offers
    [(topic, ask)] = _asks(held)
    assert "/delegator-c/" in topic and ask["preview"] is True
    assert "/delegator-b" not in json.dumps(ask["tst"])  # the lost one's names are cleared
    feed_unit(c, "c-air0", *NORRKOPING, ["move-to"], 116.0)  # c plans its offer with it
    hb = HeartBeat(agent_type="ground", agent_uuid="engine-c", levels=["tst execution"],
                   name="op-c", rate=1.0, stamp=116.0)
    c.on_message(f"{PREFIX}/unit/ground/simulation/op-c/heartbeat", encode(hb), 116.0)
    moved = run_jobs(a, Effects(jobs=_answered(c, a, topic, ask, 116.2)), 116.3)
    [rebind] = on(moved, "op0/tst/command")
    assert rebind["command"] == "rebind-tst-nodes"
    assert rebind["execunits"] == {"near-b": "/delegator-c"}  # the engine holds it as one node
    assert on(moved, "delegation/feedback") == []  # told once the engine has moved it
    answer = TstResponse(response="ok", response_to=rebind["com-uuid"])
    done = a.on_message(f"{ENGINE}/tst/response", encode(answer), 116.4)
    [event] = on(done, "delegation/feedback")
    assert event["status"] == "re-delegated" and "/delegator-b lost" in event["fail-reason"]
    assert [(t["node-uuid"], t["replaces"], t["unit"]) for t in event["tasks"]] == [
        ("near-b", "near-b", "/delegator-c")]
    assert not [m for m in on(done, "op0/tst/command")]  # no abort, no new tree
    book = a.book.find("root-f")
    assert book is not None and book.retries == {"near-b": 1}  # the budget counts per task
    mission = _delegation(a, {"command": "query-mission", "root-uuid": "root-f"}, 116.5)
    nodes = {n["node-uuid"]: n for n in on(mission, "delegation/response")[0]["mission"]["nodes"]}
    assert nodes["near-b"]["execunit"] == "/delegator-c"
    assert nodes["near-c"]["execunit"] == "/delegator-c" and nodes["near-a"]["execunit"] == "/dji0"
    c_is_alive(120.0)
    assert not run_jobs(a, a.on_tick(121.0), 121.1).jobs  # nobody else is lost: no repair again


def test_a_handover_needs_the_whole_subtree_given_to_a_live_delegator() -> None:
    from delegation.service.federated import handover, without_units

    current = parse_tree({"name": "conc", "common_params": {"node-uuid": "r"}, "children": [
        {"name": "seq", "common_params": {"node-uuid": "s", "execunit": "/delegator-b"},
         "children": [_move("t1", *LINKOPING), _move("t2", *LINKOPING)]},
        _move("t3", *GRANSO)]})
    cleared = without_units(current, {"delegator-b"})
    assert [n.execunit for _, n in walk(cleared)][:2] == [None, ""]
    origin = {"r2": "r", "s2": "s", "u1": "t1", "u2": "t2"}

    def planned(unit: str, tasks: tuple[str, ...] = ("u1", "u2")) -> Any:
        return parse_tree({"name": "conc", "common_params": {"node-uuid": "r2"}, "children": [
            {"name": "seq", "common_params": {"node-uuid": "s2", "execunit": unit},
             "children": [{**_move(t, *LINKOPING), "common_params": {"node-uuid": t,
                                                                   "execunit": unit}}
                          for t in tasks]}]})

    args = ({"u1", "u2"}, {"delegator-b"}, {"delegator-c"}, {})
    moves = handover(current, planned("/delegator-c"), origin, *args)
    assert moves is not None and moves.engine == {"s": "/delegator-c"}
    assert moves.book == {"s": "/delegator-c"}  # (its tasks were left free by the caller)
    assert [t["node-uuid"] for t in moves.tasks] == ["t1", "t2"]
    assert handover(current, planned("/dji0"), origin, *args) is None  # our own units: replace
    assert handover(current, planned("/delegator-b"), origin, *args) is None  # the lost one
    assert handover(current, planned("/delegator-c", ("u2",)), origin, {"u2"},
                    *args[1:3], {"t1": "succeeded"}) is None  # not whole: t1 would run again
    assert handover(current, planned("/delegator-c"), origin, {"u1", "u2", "x"},
                    *args[1:]) is None  # something else freed too (a lost unit of ours)


def test_a_lost_partners_part_is_taken_back_by_our_units_only_when_the_plan_runs_it_whole_here(
) -> None:
    from delegation.service.federated import take_back
    from delegation.tst.node import parse_tree

    def move(uid: str, unit: str) -> dict[str, Any]:
        return {"name": "move-to", "common_params": {"node-uuid": uid, "execunit": unit},
                "params": {"waypoint": {"latitude": 58.4, "longitude": 15.6, "altitude": 20.0}}}

    def tree(root: str, a: str, bundle: str, b1: str, b2: str, units: tuple[str, str, str],
             bundle_unit: str) -> dict[str, Any]:
        kids = [move(b1, units[1]), move(b2, units[2])]
        return {"name": "conc", "common_params": {"node-uuid": root}, "children": [
            move(a, units[0]),
            {"name": "conc", "common_params": {"node-uuid": bundle, "execunit": bundle_unit},
             "children": kids}]}

    b = "/delegator-b"
    current = parse_tree(tree("root-f", "near-a", "bundle", "b1", "b2", ("/dji0", b, b), b))
    origin = {"x-root": "root-f", "x-a": "near-a", "x-bundle": "bundle", "x-b1": "b1",
              "x-b2": "b2"}
    freed = {"x-b1", "x-b2"}

    def planned(units: tuple[str, str, str]) -> Any:
        return parse_tree(tree("x-root", "x-a", "x-bundle", "x-b1", "x-b2", units, "/op0"))

    args = (origin, freed, {"delegator-b"}, {"delegator-b", "delegator-c"}, {})
    taken = take_back(current, planned(("/dji0", "/dji0", "/dji1")), *args)
    assert taken is not None
    [(uid, sub)] = taken.subtrees.items()
    assert uid == "bundle" == sub["common_params"]["node-uuid"]
    assert [c["common_params"]["node-uuid"] for c in sub["children"]] == ["x-b1", "x-b2"]
    assert taken.origin == {"x-b1": "b1", "x-b2": "b2"}
    assert [(t["node-uuid"], t["replaces"], t["unit"]) for t in taken.tasks] == [
        ("x-b1", "b1", "/dji0"), ("x-b2", "b2", "/dji1")]
    # A part for another delegator: our engine would start its tasks itself (not folded).
    assert take_back(current, planned(("/dji0", "/delegator-c", "/dji1")), *args) is None
    # Something else freed too (one of our own units lost meanwhile): the tree is replaced.
    assert take_back(current, planned(("/dji0", "/dji0", "/dji1")), origin,
                     freed | {"x-a"}, *args[2:]) is None
    # What the partner finished is not run again: the part is what is left of it.
    done = {"b1": "succeeded"}
    left = parse_tree({"name": "conc", "common_params": {"node-uuid": "x-root"}, "children": [
        move("x-a", "/dji0"), {"name": "conc", "common_params": {"node-uuid": "x-bundle"},
                               "children": [move("x-b2", "/dji1")]}]})
    part = take_back(current, left, origin, {"x-b2"}, {"delegator-b"}, {"delegator-b"}, done)
    assert part is not None and [t["replaces"] for t in part.tasks] == ["b2"]
    # The plan regrouped or shared it into parts of its own: not the subtree's tasks.
    shared = parse_tree({"name": "conc", "common_params": {"node-uuid": "x-root"}, "children": [
        move("x-a", "/dji0"), {"name": "conc", "common_params": {"node-uuid": "x-bundle"},
                               "children": [move("p1", "/dji0"), move("p2", "/dji1")]}]})
    assert take_back(current, shared, *args) is None
