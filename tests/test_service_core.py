"""The service core, message by message, without a broker: every decision it makes.

The core is fed raw bytes on topics plus ``now`` and returns what it would publish and plan; the
planning jobs are run here with the real planner (``run_job``), as the unit's worker would.
"""

from __future__ import annotations

import json
from typing import Any

import pytest

from delegation.messages import (
    DirectExecutionInfo,
    HeartBeat,
    TaskAvailable,
    TstFeedback,
    TstResponse,
    encode,
)
from delegation.runtime.core import JobDone
from delegation.service import Effects, Outgoing, ServiceConfig, ServiceCore, run_job
from delegation.tst.node import parse_tree, walk

PREFIX = "t"
BASE = f"{PREFIX}/unit/ground/simulation/delegator0"
ENGINE = f"{PREFIX}/unit/ground/simulation/op0"


def _unit_topic(name: str, rest: str, kind: str = "air") -> str:
    return f"{PREFIX}/unit/{kind}/simulation/{name}/{rest}"


def feed_unit(core: ServiceCore, name: str, lat: float, lon: float, tasks: list[str],
              now: float, kind: str = "air") -> None:
    hb = HeartBeat(agent_type=kind, agent_uuid=f"uuid-{name}",
                   levels=["sensor", "direct execution"], name=name, rate=1.0, stamp=now)
    dei = DirectExecutionInfo(name=name, rate=1.0, stamp=now,
                              tasks_available=[TaskAvailable(name=t) for t in tasks])
    pos = {"latitude": lat, "longitude": lon, "altitude": 10.0, "rostype": "GeoPoint"}
    for rest, payload in (("heartbeat", encode(hb)), ("direct_execution_info", encode(dei)),
                          ("sensor/position", json.dumps(pos).encode())):
        core.on_message(_unit_topic(name, rest, kind), payload, now)


def feed_engine(core: ServiceCore, now: float) -> None:
    hb = HeartBeat(agent_type="ground", agent_uuid="engine", levels=["tst execution"],
                   name="op0", rate=1.0, stamp=now)
    core.on_message(f"{ENGINE}/heartbeat", encode(hb), now)


def _wp(lat: float, lon: float) -> dict[str, Any]:
    return {"latitude": lat, "longitude": lon, "altitude": 20.0}


def partial_tree() -> dict[str, Any]:
    return {
        "name": "conc",
        "common_params": {"node-uuid": "root-1"},
        "children": [
            {"name": "move-to", "common_params": {"execunit": "*", "node-uuid": "n1"},
             "params": {"waypoint": _wp(57.7611, 16.6805)}, "meta": {"keep": True}},
            {"name": "move-to", "common_params": {"node-uuid": "n2"},
             "params": {"speed": "fast", "waypoint": _wp(57.7620, 16.6830)}},
        ],
    }


@pytest.fixture
def core() -> ServiceCore:
    c = ServiceCore(ServiceConfig(prefix=PREFIX))
    feed_unit(c, "dji0", 57.7605, 16.6815, ["move-to", "move-path", "search-area"], 100.0)
    feed_unit(c, "dji1", 57.7600, 16.6800, ["move-to"], 100.0)
    feed_engine(c, 100.0)
    return c


def on(effects: Effects, topic_end: str) -> list[dict[str, Any]]:
    return [json.loads(o.payload) for o in effects.publish if o.topic.endswith(topic_end)]


def run_jobs(core: ServiceCore, effects: Effects, now: float) -> Effects:
    out = Effects(publish=list(effects.publish))
    for job in effects.jobs:
        out.extend(core.on_job_done(JobDone(job, run_job(job)), now))
    return out


def start_tst(tree: dict[str, Any], com: str = "c-1") -> bytes:
    return json.dumps({"com-uuid": com, "command": "start-tst", "receiver": "delegator0",
                       "sender": "test", "tst": tree}).encode()


def engine_answers(core: ServiceCore, effects: Effects, response: str, now: float,
                   fail_reason: str = "") -> Effects:
    """The engine answers the (single) command the core sent it."""
    sent = on(effects, "op0/tst/command")
    assert len(sent) == 1, effects.publish
    resp = TstResponse(response=response, response_to=sent[0]["com-uuid"],
                       fail_reason=fail_reason, root_uuid=sent[0].get("tst", {}).get(
                           "common_params", {}).get("node-uuid"))
    return core.on_message(f"{ENGINE}/tst/response", encode(resp), now)


def test_start_tst_plans_instantiates_and_starts(core: ServiceCore) -> None:
    first = core.on_message(f"{BASE}/tst/command", start_tst(partial_tree()), 101.0)
    assert first.publish == [] and len(first.jobs) == 1  # planning happens off the receive path
    planned = run_jobs(core, first, 101.1)
    sent = on(planned, "op0/tst/command")
    assert len(sent) == 1 and sent[0]["command"] == "start-tst" and sent[0]["receiver"] == "op0"
    tree = parse_tree(sent[0]["tst"])
    for _, node in walk(tree):
        assert isinstance(node.execunit, str) and node.execunit.startswith("/"), node
        assert node.node_uuid
    uuids = {n.node_uuid for _, n in walk(tree)}
    assert {"root-1", "n1", "n2"} <= uuids
    n1 = next(n for _, n in walk(tree) if n.node_uuid == "n1")
    assert n1.extra == {"meta": {"keep": True}} and n1.params["speed"] == "standard"
    assert on(planned, "delegation/feedback")[0]["status"] == "planned"
    assert on(planned, "tst/response") == []  # answered once the engine accepted

    started = engine_answers(core, planned, "started", 101.2)
    answer = on(started, f"{BASE}/tst/response")
    assert answer == [{"com-uuid": answer[0]["com-uuid"], "fail-reason": "", "response": "started",
                       "response-to": "c-1", "root-uuid": "root-1"}]
    assert [f["status"] for f in on(started, "delegation/feedback")] == ["started"]

    fb = TstFeedback(node_uuid="n1", status="running")
    relayed = core.on_message(f"{ENGINE}/tst/feedback", encode(fb), 102.0)
    # The leaf's feedback relayed unchanged; the root (kept in the sent tree) is the engine's.
    assert [(f["node-uuid"], f["status"]) for f in on(relayed, f"{BASE}/tst/feedback")] == [
        ("n1", "running")]
    done = core.on_message(f"{ENGINE}/tst/feedback",
                           encode(TstFeedback(node_uuid="root-1", root_flag=True,
                                              status="succeeded")), 110.0)
    assert on(done, f"{BASE}/tst/feedback")[0]["root-flag"] is True
    assert [f["status"] for f in on(done, "delegation/feedback")] == ["succeeded"]
    # Feedback for a tree the engine got from someone else is not relayed.
    other = core.on_message(f"{ENGINE}/tst/feedback",
                            encode(TstFeedback(node_uuid="foreign", status="running")), 111.0)
    assert other.publish == []


def test_resend_gets_identical_answer_and_runs_once(core: ServiceCore) -> None:
    payload = start_tst(partial_tree(), com="same")
    first = core.on_message(f"{BASE}/tst/command", payload, 101.0)
    again_pending = core.on_message(f"{BASE}/tst/command", payload, 101.05)
    assert again_pending.publish == [] and again_pending.jobs == []  # still planning: nothing new
    planned = run_jobs(core, first, 101.1)
    started = engine_answers(core, planned, "started", 101.2)
    answer = [o for o in started.publish if o.topic == f"{BASE}/tst/response"]
    again_done = core.on_message(f"{BASE}/tst/command", payload, 102.0)
    assert again_done.jobs == []
    assert again_done.publish == answer  # the very same bytes


def test_infeasible_tree_fails_naming_each_node_and_sends_nothing(core: ServiceCore) -> None:
    tree = partial_tree()
    tree["children"].append({"name": "search-around-position",
                             "common_params": {"node-uuid": "sap"},
                             "params": {"geopoint": _wp(57.76, 16.68), "radius": 20.0}})
    effects = run_jobs(core, core.on_message(f"{BASE}/tst/command", start_tst(tree), 101.0),
                       101.1)
    assert on(effects, "op0/tst/command") == []
    answer = on(effects, f"{BASE}/tst/response")
    assert answer[0]["response"] == "failed"
    reason = answer[0]["fail-reason"]
    assert "sap" in reason and "search-around-position" in reason


@pytest.mark.parametrize(
    ("payload", "expect"),
    [
        (b"{not json", "invalid JSON"),
        (json.dumps({"com-uuid": "x", "command": "dance", "sender": "t"}).encode(), "dance"),
        (start_tst({"name": "move-to", "params": {"speed": "warp"}}, com="bad-tree"),
         "params.speed"),
        (start_tst({"name": "fly-to-moon", "params": {}}, com="bad-task"), "fly-to-moon"),
    ],
)
def test_bad_tst_commands_fail_with_a_reason(core: ServiceCore, payload: bytes,
                                            expect: str) -> None:
    effects = run_jobs(core, core.on_message(f"{BASE}/tst/command", payload, 101.0), 101.0)
    answer = on(effects, f"{BASE}/tst/response")
    assert len(answer) == 1 and answer[0]["response"] == "failed"
    assert expect in answer[0]["fail-reason"]
    assert on(effects, "op0/tst/command") == []


def delegation(core: ServiceCore, command: dict[str, Any], now: float = 101.0,
               com: str | None = None) -> Effects:
    command = {"com-uuid": com or f"d-{command['command']}", "sender": "test", **command}
    return run_jobs(core, core.on_message(f"{BASE}/delegation/command",
                                          json.dumps(command).encode(), now), now)


def test_delegation_api_answers(core: ServiceCore) -> None:
    pong = on(delegation(core, {"command": "ping"}), "delegation/response")
    assert pong[0]["response"] == "pong" and pong[0]["response-to"] == "d-ping"

    agents = on(delegation(core, {"command": "list-agents"}), "delegation/response")[0]["agents"]
    assert [a["name"] for a in agents] == ["dji0", "dji1"]  # not the engine, not the service
    assert agents[0]["tasks-available"] == ["move-path", "move-to", "search-area"]

    bids = on(delegation(core, {"command": "get-bids", "tst": partial_tree()}),
              "delegation/response")[0]["bids"]
    assert len(bids) == 4 and all("travel-time" in b and b["distance"] > 0 for b in bids)
    area = [_wp(57.7610, 16.6800), _wp(57.7610, 16.6810), _wp(57.7615, 16.6810)]
    search = {"name": "search-area", "common_params": {"node-uuid": "s1"},
              "params": {"area": area}}
    bids = on(delegation(core, {"command": "get-bids", "tst": search}, 101.5, com="bids-2"),
              "delegation/response")[0]["bids"]
    by_unit = {b["unit"]: b for b in bids}
    assert by_unit["/dji1"]["reason"] == "dji1 does not offer search-area"
    assert by_unit["/dji0"]["work-time"] > 0 and by_unit["/dji0"]["node-uuid"] == "s1"

    plan = on(delegation(core, {"command": "delegate", "tst": partial_tree(),
                                "strategy": "nearest"}), "delegation/response")[0]
    assert plan["response"] == "ok" and plan["plan"]["strategy"] == "nearest"
    assert {a["node-uuid"] for a in plan["plan"]["assignments"]} == {"n1", "n2"}

    query = on(delegation(core, {"command": "query-mission", "root-uuid": "root-1"}),
               "delegation/response")[0]
    assert query["response"] == "ok" and query["mission"]["status"] == "planned"
    missions = on(delegation(core, {"command": "list-missions"}), "delegation/response")[0]
    assert [m["root-uuid"] for m in missions["missions"]] == ["root-1"]

    cancel = delegation(core, {"command": "cancel-mission", "root-uuid": "root-1"})
    assert on(cancel, "delegation/response")[0]["response"] == "ok"  # never started
    assert on(cancel, "op0/tst/command") == []
    assert on(cancel, "delegation/feedback")[0]["status"] == "aborted"


@pytest.mark.parametrize(
    ("command", "expect"),
    [
        ({"command": "query-mission", "root-uuid": "nope"}, "unknown mission 'nope'"),
        ({"command": "cancel-mission", "root-uuid": "nope"}, "unknown mission 'nope'"),
        ({"command": "delegate", "tst": {"name": "seq"}, "strategy": "magic"}, "magic"),
        ({"command": "delegate", "tst": {"name": "seq"}, "objective": "fun"}, "fun"),
        ({"command": "delegate", "tst": {"name": "seq"}, "time-limit": 3600}, "maximum of 60 s"),
        ({"command": "delegate", "tst": {"name": "move-to", "params": {}}}, "waypoint"),
        ({"command": "delegate"}, "tst"),
        ({"command": "launch"}, "launch"),
    ],
)
def test_bad_delegation_commands_fail_with_a_reason(core: ServiceCore, command: dict[str, Any],
                                                   expect: str) -> None:
    answer = on(delegation(core, command), "delegation/response")
    assert len(answer) == 1 and answer[0]["response"] == "failed", answer
    assert expect in answer[0]["fail-reason"]
    assert answer[0]["response-to"] == f"d-{command['command']}"


def test_delegate_with_start_and_cancel_waits_for_engine(core: ServiceCore) -> None:
    planned = delegation(core, {"command": "delegate", "tst": partial_tree(), "start": True})
    assert on(planned, "delegation/response") == []
    started = engine_answers(core, planned, "started", 101.5)
    answer = on(started, "delegation/response")[0]
    assert answer["response"] == "started" and answer["plan"]["feasible"] is True

    cancel = delegation(core, {"command": "cancel-mission", "root-uuid": "root-1"}, 102.0)
    sent = on(cancel, "op0/tst/command")
    assert sent[0]["command"] == "signal-tst-tree" and sent[0]["signal"] == "$abort"
    assert sent[0]["node-uuid"] == "root-1"
    assert on(cancel, "delegation/response") == []  # not before the engine confirmed
    accepted = engine_answers(core, cancel, "ok", 102.1)
    assert on(accepted, "delegation/response") == []  # the abort is not confirmed yet
    aborted = core.on_message(f"{ENGINE}/tst/feedback", encode(TstFeedback(
        node_uuid="root-1", root_flag=True, status="aborted")), 103.0)
    assert on(aborted, "delegation/response")[0]["response"] == "ok"


def test_a_cancel_the_engine_does_not_confirm_is_answered_pending(core: ServiceCore) -> None:
    planned = delegation(core, {"command": "delegate", "tst": partial_tree(), "start": True})
    engine_answers(core, planned, "started", 101.5)
    cancel = delegation(core, {"command": "cancel-mission", "root-uuid": "root-1"}, 102.0)
    engine_answers(core, cancel, "ok", 102.1)
    feed_engine(core, 110.0)
    feed_engine(core, 120.0)
    assert on(core.on_tick(122.0), "delegation/response") == []
    (pending,) = on(core.on_tick(122.1), "delegation/response")
    assert pending["response"] == "pending" and "not confirmed within 20 s" in pending[
        "fail-reason"]


def test_signals_are_forwarded_and_answered(core: ServiceCore) -> None:
    started = engine_answers(
        core, run_jobs(core, core.on_message(f"{BASE}/tst/command", start_tst(partial_tree()),
                                             101.0), 101.0), "started", 101.1)
    assert started.publish
    for cmd in ({"command": "signal-tst-node", "node-uuid": "n1", "signal": "$pause"},
                {"command": "signal-tst-tree", "node-uuid": "root-1", "signal": "$continue"},
                {"command": "signal-unit", "unit": "/dji0", "signal": "$abort"}):
        payload = json.dumps({"com-uuid": f"s-{cmd['command']}", "sender": "test", **cmd}).encode()
        fwd = core.on_message(f"{BASE}/tst/command", payload, 102.0)
        sent = on(fwd, "op0/tst/command")[0]
        assert sent["command"] == cmd["command"] and sent["signal"] == cmd["signal"]
        answer = on(engine_answers(core, fwd, "ok", 102.1), f"{BASE}/tst/response")
        assert answer[0]["response"] == "ok" and answer[0]["response-to"] == f"s-{cmd['command']}"
    unknown = json.dumps({"com-uuid": "s-x", "command": "signal-tst-node", "sender": "t",
                          "node-uuid": "who", "signal": "$abort"}).encode()
    answer = on(core.on_message(f"{BASE}/tst/command", unknown, 103.0), f"{BASE}/tst/response")
    assert answer[0]["response"] == "failed" and "'who'" in answer[0]["fail-reason"]


def test_no_engine_or_silent_engine_fails_clearly() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX, engine_timeout=5.0))
    feed_unit(core, "dji0", 57.7605, 16.6815, ["move-to"], 100.0)
    tree = partial_tree()
    # just started: the command waits (a bounded while) for the engine to be heard ...
    assert core.on_message(f"{BASE}/tst/command", start_tst(tree), 100.5) == Effects()
    assert core.on_tick(102.9) == Effects()
    # ... and is refused, naming the engine, once ``listen_first`` has passed without it
    answer = on(core.on_tick(103.0), "tst/response")
    assert answer[0]["response"] == "failed" and "op0" in answer[0]["fail-reason"]

    feed_engine(core, 104.0)
    planned = run_jobs(core, core.on_message(f"{BASE}/tst/command", start_tst(tree, "c-2"), 104.0),
                       104.0)
    assert on(planned, "op0/tst/command")
    assert core.on_tick(108.0).publish == []
    expired = core.on_tick(109.5)
    answer = on(expired, "tst/response")
    assert answer[0]["response"] == "failed" and "did not answer" in answer[0]["fail-reason"]
    assert on(expired, "delegation/feedback")[0]["status"] == "failed"


def test_a_command_that_arrives_before_the_engine_is_heard_waits_for_it() -> None:
    """A service that has just started has not heard the (unretained) heartbeats yet: a start
    sent at once is neither refused nor planned for a partial fleet; it goes on when the engine
    is heard, and a later command is not held at all."""
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    assert core.on_message(f"{BASE}/tst/command", start_tst(partial_tree()), 50.0) == Effects()
    feed_unit(core, "dji0", 57.7605, 16.6815, ["move-to"], 50.4)
    hb = HeartBeat(agent_type="ground", agent_uuid="engine", levels=["tst execution"],
                   name="op0", rate=1.0, stamp=50.6)
    released = core.on_message(f"{ENGINE}/heartbeat", encode(hb), 50.6)
    assert [j.key for j in released.jobs] == [("tst", "c-1")]
    assert [u.name for u in released.jobs[0].units] == ["dji0"]
    assert on(run_jobs(core, released, 50.7), "op0/tst/command")
    bids = json.dumps({"com-uuid": "b-1", "command": "get-bids", "tst": partial_tree()}).encode()
    assert [j.key for j in core.on_message(f"{BASE}/delegation/command", bids, 50.8).jobs] == [
        ("delegation", "b-1")]


def test_a_started_service_listens_a_round_of_heartbeats_before_it_plans() -> None:
    # ``listen_round`` (``delegation serve``: 1.2 s): hearing the engine is not enough, a unit's
    # beat of the same second may come after it; the command waits for the round to pass.
    core = ServiceCore(ServiceConfig(prefix=PREFIX, listen_round=1.2))
    assert core.on_message(f"{BASE}/tst/command", start_tst(partial_tree()), 50.0) == Effects()
    feed_unit(core, "dji0", 57.7605, 16.6815, ["move-to"], 50.4)
    hb = HeartBeat(agent_type="ground", agent_uuid="engine", levels=["tst execution"],
                   name="op0", rate=1.0, stamp=50.6)
    assert core.on_message(f"{ENGINE}/heartbeat", encode(hb), 50.6).jobs == []
    feed_unit(core, "dji1", 57.7610, 16.6820, ["move-to"], 50.7)  # after the engine
    assert core.on_tick(51.0).jobs == []
    released = core.on_tick(51.2)
    assert [j.key for j in released.jobs] == [("tst", "c-1")]
    assert [u.name for u in released.jobs[0].units] == ["dji0", "dji1"]
    bids = json.dumps({"com-uuid": "b-1", "command": "get-bids", "tst": partial_tree()}).encode()
    assert [j.key for j in core.on_message(f"{BASE}/delegation/command", bids, 51.4).jobs] == [
        ("delegation", "b-1")]


def test_status_messages(core: ServiceCore) -> None:
    out: list[Outgoing] = core.status(123.0, 123.0)
    topics = {o.topic.rsplit("/", 1)[1]: json.loads(o.payload) for o in out}
    assert topics["heartbeat"]["levels"] == ["tst execution", "delegation"]
    assert topics["heartbeat"]["name"] == "delegator0"
    assert topics["tst_execution_info"]["type"] == "TstExecutionInfo"
    assert "auction" in topics["delegation_info"]["strategies"]


def test_engine_refusal_and_infeasible_delegate(core: ServiceCore) -> None:
    planned = run_jobs(core, core.on_message(f"{BASE}/tst/command", start_tst(partial_tree()),
                                             101.0), 101.0)
    refused = engine_answers(core, planned, "failed", 101.1, fail_reason="unit /dji0 unknown")
    answer = on(refused, f"{BASE}/tst/response")[0]
    assert answer["response"] == "failed"
    assert answer["fail-reason"] == "engine op0 refused the tree: unit /dji0 unknown"
    assert [f["status"] for f in on(refused, "delegation/feedback")] == ["failed"]

    tree = partial_tree()
    tree["common_params"]["node-uuid"] = "root-2"
    tree["children"][0]["common_params"]["node-uuid"] = "m1"
    tree["children"][1]["common_params"]["node-uuid"] = "m2"
    tree["children"].append({"name": "look-at-bearing", "common_params": {"node-uuid": "lab"},
                             "params": {"bearing": 90.0}})
    answer = on(delegation(core, {"command": "delegate", "tst": tree}), "delegation/response")[0]
    assert answer["response"] == "failed" and answer["plan"]["feasible"] is False
    assert "root/children[2] (look-at-bearing lab)" in answer["fail-reason"]
    assert [u["node-uuid"] for u in answer["plan"]["unassigned"]] == ["lab"]


def test_fleet_events_are_logged_and_do_not_pile_up(caplog) -> None:
    import json
    import logging

    from delegation.service import ServiceCore

    core = ServiceCore()
    beat = {"agent-type": "air", "agent-uuid": "a1", "levels": ["sensor", "direct execution"],
            "name": "dji9", "rate": 1.0, "stamp": 1.0, "type": "HeartBeat"}
    topic = "waraps/unit/air/simulation/dji9/heartbeat"
    with caplog.at_level(logging.INFO, logger="delegation.service"):
        core.on_message(topic, json.dumps(beat).encode(), 1.0)
        core.on_message(topic, json.dumps({**beat, "agent-uuid": "a2"}).encode(), 2.0)
    assert "unit dji9 appeared" in caplog.text
    assert "unit dji9 rebooted" in caplog.text
    assert core.fleet.drain_events() == []


def test_list_missions_pages(core: ServiceCore) -> None:
    for i in range(3):
        tree = {"name": "move-to", "common_params": {"node-uuid": f"r{i}"},
                "params": {"waypoint": _wp(57.7611, 16.6805)}}
        delegation(core, {"command": "delegate", "tst": tree}, now=101.0 + i, com=f"p{i}")
    first = on(delegation(core, {"command": "list-missions", "limit": 2}, com="l1"),
               "delegation/response")[0]
    assert [m["root-uuid"] for m in first["missions"]] == ["r0", "r1"]
    assert first["total"] == 3 and first["next"] == 2
    last = on(delegation(core, {"command": "list-missions", "offset": 2, "limit": 2}, com="l2"),
              "delegation/response")[0]
    assert [m["root-uuid"] for m in last["missions"]] == ["r2"] and "next" not in last
    bad = on(delegation(core, {"command": "list-missions", "limit": 0}, com="l3"),
             "delegation/response")[0]
    assert bad["response"] == "failed" and "limit" in bad["fail-reason"]


@pytest.mark.parametrize("field,value", [("repair", "rebnd"), ("repair_sweep", "all"),
                                         ("commitments", "queue"), ("hold_failed", -1.0),
                                         ("hold_failed", float("nan"))])
def test_a_service_setting_with_no_meaning_is_refused_by_name(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=f"ServiceConfig.{field}"):
        ServiceConfig(**{field: value})  # type: ignore[arg-type]
