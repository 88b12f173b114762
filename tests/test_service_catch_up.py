"""Catching up (`delegation.service.catch_up`, issue 22 items 1-2) at the core: after a restart,
a reconnect or the engine's return the service asks the engine (``query-tst``) about every open
mission before judging it; a tree the engine does not know is sent again, unfinished part only,
same uuids, same start-tst com-uuid; a ``start-tst`` whose answer never came is confirmed, not
assumed failed."""

from __future__ import annotations

from typing import Any

from delegation.messages import HeartBeat, MissionStatus, TstResponse, encode
from delegation.runtime.core import Effects
from delegation.service import ServiceConfig, ServiceCore
from delegation.service.catch_up import unfinished
from delegation.service.engine_link import start_command_uuid
from delegation.service.missions import MissionBook
from delegation.tst.node import parse_tree, to_dict, walk
from test_service_core import BASE, ENGINE, engine_answers, feed_unit, on, run_jobs, start_tst
from test_service_redelegation import MOVE, _task, _tree, feedback, fleet, started_mission, statuses


def _answer(core: ServiceCore, sent: dict[str, Any], response: str, now: float,
            **fields: Any) -> Effects:
    resp = TstResponse(response=response, response_to=sent["com-uuid"], **fields)
    return core.on_message(f"{ENGINE}/tst/response", encode(resp), now)


def _two_tasks(core: ServiceCore) -> dict[str, Any]:
    """A started mission ``root-1``: a seq of n0 (u0) then n1 (u1); returns its start-tst."""
    planned = started_mission(core, _tree("seq", "root-1", _task("n0", "/u0"),
                                          _task("n1", "/u1")))
    [start] = on(planned, "op0/tst/command")
    return start


def _only_query(effects: Effects) -> dict[str, Any]:
    [query] = on(effects, "op0/tst/command")
    assert query["command"] == "query-tst", query
    return query


def test_unfinished_keeps_uuids_and_drops_what_succeeded_and_empty_control_nodes() -> None:
    tree = parse_tree(_tree("seq", "r", _tree("conc", "c", _task("a", "/u0"), _task("b", "/u1")),
                            _task("d", "/u0")))
    left = unfinished(tree, {"a": "succeeded", "b": "succeeded", "d": "running"})
    assert left is not None
    assert [n.node_uuid for _, n in walk(left)] == ["r", "d"]
    assert unfinished(tree, {"a": "succeeded", "b": "revoked", "d": "succeeded"}) is None


def test_after_a_reconnect_a_tree_that_ended_meanwhile_ends_its_mission() -> None:
    core = ServiceCore(ServiceConfig(prefix="t"))
    fleet(core, 100.0)
    _two_tasks(core)
    feedback(core, "n0", "running", 101.5)
    core.on_disconnect(102.0)
    core.on_reconnect(110.0)
    query = _only_query(core.on_tick(110.1))
    assert query["node-uuid"] == "root-1"
    nodes = [{"node-uuid": u, "status": "succeeded", "fail-reason": ""}
             for u in ("root-1", "n0", "n1")]
    out = _answer(core, query, "ok", 110.2, nodes=nodes)
    assert statuses(out) == ["succeeded"]  # the root's status, applied last
    relayed = [f["node-uuid"] for f in on(out, f"{BASE}/tst/feedback")]
    assert relayed[-1] == "root-1" and set(relayed) == {"root-1", "n0", "n1"}
    mission = core.book.get("root-1")
    assert mission.status is MissionStatus.SUCCEEDED and mission.node_status["n1"] == "succeeded"


def test_a_restarted_service_asks_about_the_missions_its_store_gave_it() -> None:
    first = ServiceCore(ServiceConfig(prefix="t"))
    fleet(first, 100.0)
    _two_tasks(first)
    second = ServiceCore(ServiceConfig(prefix="t"))  # the store's book, handed over as at start
    book = MissionBook()
    book.add(first.book.get("root-1"))
    second.book = book
    assert on(second.on_tick(200.0), "op0/tst/command") == []  # the engine not heard yet
    fleet(second, 200.1)
    query = _only_query(second.on_tick(200.2))
    assert query["node-uuid"] == "root-1"
    aborted = [{"node-uuid": "root-1", "status": "aborted", "fail-reason": "n1 aborted"},
               {"node-uuid": "n0", "status": "succeeded", "fail-reason": ""},
               {"node-uuid": "n1", "status": "aborted", "fail-reason": "by its operator"}]
    out = _answer(second, query, "ok", 200.3, nodes=aborted)
    assert statuses(out) == ["aborted"], out
    assert second.book.get("root-1").fail_reason == "n1 aborted"


def test_an_unanswered_query_is_asked_again_a_bounded_number_of_times() -> None:
    core = ServiceCore(ServiceConfig(prefix="t", catch_up_attempts=2))
    fleet(core, 100.0)
    _two_tasks(core)
    core.on_reconnect(101.0)
    first = _only_query(core.on_tick(101.1))
    second = _only_query(core.on_tick(103.2))  # catch_up_timeout 2 s
    assert second["com-uuid"] != first["com-uuid"]
    assert on(core.on_tick(105.3), "op0/tst/command") == []  # given up (logged)
    assert core.book.get("root-1").status is MissionStatus.STARTED


def test_a_restarted_engine_gets_the_unfinished_part_under_the_first_com_uuid() -> None:
    core = ServiceCore(ServiceConfig(prefix="t"))
    fleet(core, 100.0)
    start = _two_tasks(core)
    feedback(core, "n0", "succeeded", 102.0)
    feedback(core, "n1", "running", 102.5)
    hb = HeartBeat(agent_type="ground", agent_uuid="engine-2", levels=["tst execution"],
                   name="op0", rate=1.0, stamp=103.0)
    assert statuses(core.on_message(f"{ENGINE}/heartbeat", encode(hb), 103.0)) == []
    query = _only_query(core.on_tick(103.1))
    out = _answer(core, query, "unknown", 103.2, fail_reason="no tree root-1")
    [again] = on(out, "op0/tst/command")
    assert again["command"] == "start-tst" and again["resume"] is True
    assert again["com-uuid"] == start["com-uuid"]  # the engine derives the same start-tasks
    assert [n.node_uuid for _, n in walk(parse_tree(again["tst"]))] == ["root-1", "n1"]
    started = _answer(core, again, "started", 103.3, root_uuid="root-1")
    assert on(started, "delegation/response") == [] and statuses(started) == []
    done = feedback(core, "root-1", "succeeded", 110.0, root=True)
    assert statuses(done)[-1] == "succeeded"


def test_a_restarted_engine_with_nothing_left_to_do_means_the_mission_succeeded() -> None:
    core = ServiceCore(ServiceConfig(prefix="t"))
    fleet(core, 100.0)
    _two_tasks(core)
    feedback(core, "n0", "succeeded", 102.0)
    feedback(core, "n1", "succeeded", 102.5)
    core.repair.catch_up.want_open()
    query = _only_query(core.on_tick(103.1))
    out = _answer(core, query, "unknown", 103.2)
    assert on(out, "op0/tst/command") == [] and statuses(out)[-1] == "succeeded"


def test_a_lost_engine_back_in_time_is_asked_and_the_mission_goes_on() -> None:
    core = ServiceCore(ServiceConfig(prefix="t", engine_return_timeout=20.0))
    fleet(core, 100.0)
    _two_tasks(core)
    for name in ("u0", "u1", "u2"):
        feed_unit(core, name, 57.76, 16.68, MOVE, 106.0)
    assert statuses(core.on_tick(106.0)) == []  # lost (5 s), waited for
    assert on(core.on_tick(106.2), "op0/tst/command") == []
    hb = HeartBeat(agent_type="ground", agent_uuid="engine", levels=["tst execution"],
                   name="op0", rate=1.0, stamp=110.0)
    core.on_message(f"{ENGINE}/heartbeat", encode(hb), 110.0)  # the same instance, back
    query = _only_query(core.on_tick(110.1))
    nodes = [{"node-uuid": "root-1", "status": "running", "fail-reason": ""}]
    _answer(core, query, "ok", 110.2, nodes=nodes)
    assert core.book.get("root-1").status is MissionStatus.RUNNING


def _unanswered_start(core: ServiceCore) -> dict[str, Any]:
    fleet(core, 100.0)
    planned = core.on_message(f"{BASE}/tst/command",
                              start_tst(_tree("conc", "root-1", _task("n0", "/u0"))), 101.0)
    [start] = on(run_jobs(core, planned, 101.0), "op0/tst/command")
    fleet(core, 114.0)  # everyone still heard: only the answer is missing
    return start


def test_a_start_tst_never_answered_but_running_is_confirmed_not_failed() -> None:
    core = ServiceCore(ServiceConfig(prefix="t"))
    start = _unanswered_start(core)
    confirm = _only_query(core.on_tick(116.1))  # engine_timeout 15 s: ask, do not assume
    assert confirm["node-uuid"] == start["tst"]["common_params"]["node-uuid"] == "root-1"
    assert core.book.get("root-1").status is MissionStatus.PLANNED
    nodes = [{"node-uuid": "root-1", "status": "running", "fail-reason": ""},
             {"node-uuid": "n0", "status": "running", "fail-reason": ""}]
    out = _answer(core, confirm, "ok", 116.2, nodes=nodes)
    [answer] = on(out, f"{BASE}/tst/response")
    assert answer["response"] == "started" and answer["response-to"] == "c-1"
    assert core.book.get("root-1").status is MissionStatus.RUNNING


def test_a_start_tst_the_engine_never_got_fails_without_an_abort() -> None:
    core = ServiceCore(ServiceConfig(prefix="t"))
    _unanswered_start(core)
    confirm = _only_query(core.on_tick(116.1))
    out = _answer(core, confirm, "unknown", 116.2)
    [answer] = on(out, f"{BASE}/tst/response")
    assert answer["response"] == "failed" and "it was not started" in answer["fail-reason"]
    assert on(out, "op0/tst/command") == [] and statuses(out) == ["failed"]


def test_a_start_tst_the_engine_says_nothing_about_fails_and_is_aborted() -> None:
    core = ServiceCore(ServiceConfig(prefix="t"))
    _unanswered_start(core)
    _only_query(core.on_tick(116.1))
    fleet(core, 128.0)
    out = core.on_tick(131.2)  # the confirmation unanswered too
    [abort] = on(out, "op0/tst/command")
    assert abort["command"] == "signal-tst-tree" and abort["signal"] == "$abort"
    assert abort["node-uuid"] == "root-1"
    [answer] = on(out, f"{BASE}/tst/response")
    assert answer["response"] == "failed" and "$abort sent" in answer["fail-reason"]
    assert core.book.get("root-1").status is MissionStatus.FAILED
    assert answer["response-to"] == "c-1"


def test_the_start_tst_com_uuid_is_the_same_for_the_same_command_and_new_for_another() -> None:
    one, two = ServiceCore(ServiceConfig(prefix="t")), ServiceCore(ServiceConfig(prefix="t"))
    fleet(one, 100.0)
    fleet(two, 100.0)
    a = _two_tasks(one)
    b = _two_tasks(two)
    assert a["com-uuid"] == b["com-uuid"]  # the service, the command and the mission
    assert a["com-uuid"] == start_command_uuid("delegator0", ("tst", "c-1"), "root-1")
    # Another service, command or mission: never taken by the engine for a re-send.
    assert len({start_command_uuid(*args) for args in (
        ("delegator0", ("tst", "c-1"), "root-1"), ("delegator1", ("tst", "c-1"), "root-1"),
        ("delegator0", ("delegation", "c-1"), "root-1"), ("delegator0", ("tst", "c-2"), "root-1"),
        ("delegator0", ("tst", "c-1"), "root-2"))}) == 5
    other = start_tst(_tree("seq", "root-2", _task("m0", "/u2")), com="c-2")
    c = run_jobs(one, one.on_message(f"{BASE}/tst/command", other, 102.0), 102.0)
    engine_answers(one, c, "started", 102.0)
    assert on(c, "op0/tst/command")[0]["com-uuid"] != a["com-uuid"]
    assert to_dict(parse_tree(a["tst"]))["common_params"]["node-uuid"] == "root-1"


def test_a_cancel_while_the_start_is_being_confirmed_aborts_on_the_engine() -> None:
    core = ServiceCore(ServiceConfig(prefix="t"))
    _unanswered_start(core)
    _only_query(core.on_tick(116.1))
    cmd = (b'{"com-uuid": "k-1", "command": "cancel-mission", "root-uuid": "root-1", '
           b'"sender": "test"}')
    out = core.on_message(f"{BASE}/delegation/command", cmd, 116.5)
    [abort] = on(out, "op0/tst/command")  # not "cancelled before it started": it may run
    assert abort["command"] == "signal-tst-tree" and abort["signal"] == "$abort"
