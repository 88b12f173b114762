"""Catching up from the units themselves (`delegation.service.unit_catch_up`, issue 22 item 1) at
the core: the service keeps the task-uuid of each start-task its engine sends; when the engine
leaves ``query-tst`` unanswered (or refuses it: no such extension), it asks the units
``query-status`` and ends the mission as the answers decide."""

from __future__ import annotations

from typing import Any

from delegation.messages import ExecResponse, MissionStatus, StartTask, TaskSpecMsg, encode
from delegation.runtime.core import Effects
from delegation.service import ServiceConfig, ServiceCore
from delegation.service.missions import MissionBook, mission_from_record, mission_record
from delegation.service.unit_catch_up import decide, frozen, task_of, tasks_by_unit
from delegation.tst.node import TstNode, parse_tree, walk
from test_service_core import BASE, ENGINE, _unit_topic, engine_answers, on, run_jobs, start_tst
from test_service_redelegation import _task, _tree, feedback, fleet, started_mission, statuses


def _sent(core: ServiceCore, uid: str) -> TstNode:
    """The task node ``uid`` as the tree sent to the engine has it (instantiated)."""
    mission = core.book.of_node(uid)
    assert mission is not None
    return next(n for _, n in walk(parse_tree(mission.current_tst)) if n.node_uuid == uid)


def _start(node: TstNode, unit: str, task_uuid: str, sender: str = "op0") -> StartTask:
    return StartTask(execution_unit=unit, sender=sender, task_uuid=task_uuid,
                     task=TaskSpecMsg(name=node.name, params=node.params))


def _start_task(core: ServiceCore, unit: str, node: dict[str, Any], task_uuid: str, now: float,
                sender: str = "op0") -> Effects:
    """The engine's start-task for ``node`` as the service sees it on ``unit``'s exec/command."""
    cmd = _start(_sent(core, node["common_params"]["node-uuid"]), unit, task_uuid, sender)
    return core.on_message(_unit_topic(unit, "exec/command"), encode(cmd), now)


def _unit_answers(core: ServiceCore, query: dict[str, Any], unit: str, response: str,
                  now: float) -> Effects:
    answer = ExecResponse(response=response, response_to=query["com-uuid"],
                          task_uuid=query["task-uuid"])
    return core.on_message(_unit_topic(unit, "exec/response"), encode(answer), now)


def _queries(effects: Effects) -> dict[str, dict[str, Any]]:
    """unit -> the query-status sent to it."""
    out = {}
    for o in effects.publish:
        if o.topic.endswith("/exec/command"):
            unit = o.topic.split("/")[-3]
            out[unit] = on(Effects(publish=[o]), "exec/command")[0]
            assert out[unit]["command"] == "query-status", out[unit]
    return out


N0, N1 = _task("n0", "/u0"), _task("n1", "/u1")


def _restarted_with_conc() -> ServiceCore:
    """Mission ``root-1`` (a conc of n0 on u0 and n1 on u1) running, its start-tasks seen; then
    the service restarted from what it stored, the engine and the units heard again."""
    first = ServiceCore(ServiceConfig(prefix="t"))
    fleet(first, 100.0)
    started_mission(first, _tree("conc", "root-1", N0, N1))
    _start_task(first, "u0", N0, "task-0", 101.2)
    _start_task(first, "u1", N1, "task-1", 101.2)
    # Noted as a change of the mission, so that the store writes it (before anything goes out).
    assert first.book.changed_at["root-1"] == first.book.revision
    feedback(first, "n0", "running", 101.5)
    assert first.book.get("root-1").node_tasks == {"n0": ("u0", "task-0"),
                                                   "n1": ("u1", "task-1")}
    second = ServiceCore(ServiceConfig(prefix="t"))
    book = MissionBook()
    book.add(mission_from_record(mission_record(first.book.get("root-1"))))  # as stored
    second.book = book
    fleet(second, 200.0)
    [query] = on(second.on_tick(200.1), "op0/tst/command")
    assert query["command"] == "query-tst"
    return second


# --------------------------------------------------------------------------- pure decisions


def test_the_tasks_decide_the_tree_as_the_engine_would() -> None:
    tree = parse_tree(_tree("seq", "r", _tree("conc", "c", _task("a", "/u0"), _task("b", "/u1")),
                            _task("d", "/u0")))
    ok = ("succeeded", "")
    assert decide(tree, {"a": ok, "b": ok, "d": ok}) == {"c": ok, "r": ok}
    assert decide(tree, {"a": ok, "b": ok}) == {"c": ok}  # d not known: the seq is open
    failed = decide(tree, {"b": ("failed", "engine stalled")})  # a is still on: a failure decides
    assert failed["c"] == ("failed", "root/children[0]/children[1] (move-to) failed: "
                                     "engine stalled")
    assert failed["r"][0] == "failed" and "root/children[0] (conc) failed" in failed["r"][1]
    aborted = decide(tree, {"a": ("aborted", "pilot"), "b": ok})
    assert aborted["c"][0] == "aborted" and aborted["r"][0] == "aborted"
    assert decide(tree, {"a": ("aborted", "pilot")}) == {}  # a conc ends once all ended
    assert decide(tree, {"a": ok, "b": ("revoked", ""), "d": ok})["r"] == ok


def test_a_start_task_is_matched_to_its_node_by_unit_name_and_params() -> None:
    core = ServiceCore(ServiceConfig(prefix="t"))
    fleet(core, 100.0)
    twin = _task("n2", "/u0")  # the same name and params as n0 on the same unit
    started_mission(core, _tree("seq", "root-1", N0, twin, N1))
    mission = core.book.get("root-1")
    index = tasks_by_unit(mission.current_tst)

    def start(unit: str, node: dict[str, Any], task_uuid: str) -> StartTask:
        return _start(_sent(core, node["common_params"]["node-uuid"]), unit, task_uuid)

    assert task_of(mission, index, "u0", start("u0", N0, "t-0")) == "n0"
    mission.node_tasks["n0"] = ("u0", "t-0")
    assert task_of(mission, index, "u0", start("u0", N0, "t-0")) == "n0"  # a re-send
    assert task_of(mission, index, "u0", start("u0", N0, "t-2")) == "n2"  # the twin's turn
    mission.node_tasks["n2"] = ("u0", "t-2")
    mission.node_status["n0"] = "succeeded"
    assert task_of(mission, index, "u0", start("u0", N0, "t-3")) == "n2"  # tried again
    assert task_of(mission, index, "u2", start("u2", N0, "t-4")) is None  # no task on u2
    elsewhere = _sent(core, "n1").with_params({"waypoint": {"latitude": 1.0, "longitude": 2.0,
                                                           "altitude": 3.0}})
    assert task_of(mission, index, "u1", _start(elsewhere, "u1", "t-5")) is None


def test_a_start_task_from_anyone_but_the_engine_is_not_kept() -> None:
    core = ServiceCore(ServiceConfig(prefix="t"))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", N0, N1))
    _start_task(core, "u0", N0, "task-x", 101.2, sender="someone")
    assert core.book.get("root-1").node_tasks == {}


def test_tasks_by_unit_walks_the_json_as_the_parsed_tree_reads() -> None:
    """The index is made from the JSON the service sent, without parsing it again: the same
    (unit, name) -> [(uuid, params)] in tree order as a walk of the parsed tree."""
    other = {"name": "look-at", "common-params": {"execunit": "u1", "node-uuid": "n4"},
             "params": {"target": [1, 2]}}
    tree = _tree("seq", "r", _tree("conc", "c", _task("a", "/u0"), _task("b", "/u1"), other),
                 _task("d", "/u0"), _tree("seq", "s", _task("e", "/u0", name="land")))
    parsed: dict[tuple[str, str], list[tuple[str, dict[str, Any]]]] = {}
    for _, node in walk(parse_tree(tree)):
        if not node.is_control and node.node_uuid:
            parsed.setdefault((node.execunit.strip("/"), node.name), []).append(
                (node.node_uuid, node.params))
    assert tasks_by_unit(tree) == parsed
    assert [uid for uid, _ in tasks_by_unit(tree)[("u0", "move-to")]] == ["a", "d"]


def test_the_start_task_index_keeps_in_step_with_the_book() -> None:
    """`start_seen` looks only at the missions with such a task on that unit: a mission added
    later, a task moved to another unit (its tree replaced) and a mission ended are seen."""
    core = ServiceCore(ServiceConfig(prefix="t"))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", N0, N1))
    _start_task(core, "u0", N0, "task-0", 101.0)
    n2, n3 = _task("n2", "/u0"), _task("n3", "/u2")
    n2["params"] = {"waypoint": {**n2["params"]["waypoint"], "latitude": 57.7621}}  # not n0's
    planned = run_jobs(core, core.on_message(f"{BASE}/tst/command",
                                             start_tst(_tree("conc", "root-2", n2, n3), "c-2"),
                                             101.5), 101.5)
    engine_answers(core, planned, "started", 101.5)  # a mission added after the index was made
    _start_task(core, "u0", n2, "task-2", 102.0)
    assert core.book.get("root-2").node_tasks == {"n2": ("u0", "task-2")}
    mission = core.book.get("root-1")
    core.book.rebind(mission, {"n1": "/u2"})  # n1 now runs on u2
    _start_task(core, "u2", N1, "task-1", 103.0)
    assert mission.node_tasks == {"n0": ("u0", "task-0"), "n1": ("u2", "task-1")}
    catch_up = core.unit_catch_up
    u0 = [roots for (unit, _, _), roots in catch_up._by_task.items() if unit == "u0"]
    assert sorted(list(roots) for roots in u0) == [["root-1"], ["root-2"]]  # n0's, n2's
    core.book.set_status("root-2", MissionStatus.SUCCEEDED, 104.0)
    _start_task(core, "u0", N0, "task-0", 105.0)  # a re-send: the index is brought in step
    assert "root-2" not in catch_up._index
    assert [set(r) for (unit, _, _), r in catch_up._by_task.items() if unit == "u0"] == [
        {"root-1"}]


def test_frozen_json_values_are_equal_exactly_when_the_values_are() -> None:
    values = [{"a": 1, "b": [1, 2.5]}, {"b": [1, 2.5], "a": 1.0}, {"a": 1, "b": [2.5, 1]},
              {}, [], {"a": None}, {"a": "1"}, {"a": True}, {"a": {"x": [1]}}]
    for x in values:
        for y in values:
            assert (frozen(x) == frozen(y)) == (x == y), (x, y)
            if x == y:
                assert hash(frozen(x)) == hash(frozen(y))


# --------------------------------------------------------------------------- the service


def test_an_engine_silent_on_query_tst_the_units_say_the_tree_succeeded() -> None:
    core = _restarted_with_conc()
    asked = _queries(core.on_tick(202.2))  # catch_up_timeout (2 s): the units are asked
    assert {u: q["task-uuid"] for u, q in asked.items()} == {"u0": "task-0", "u1": "task-1"}
    first = _unit_answers(core, asked["u0"], "u0", "success", 202.3)
    assert first.publish == []  # applied once every unit asked answered (or did not in time)
    out = _unit_answers(core, asked["u1"], "u1", "success", 202.4)
    assert statuses(out) == ["succeeded"]
    relayed = [(f["node-uuid"], f["status"]) for f in on(out, f"{BASE}/tst/feedback")]
    assert relayed == [("n0", "succeeded"), ("n1", "succeeded"), ("root-1", "succeeded")]
    mission = core.book.get("root-1")
    assert mission.status is MissionStatus.SUCCEEDED
    assert mission.node_status == {"root-1": "succeeded", "n0": "succeeded", "n1": "succeeded"}
    assert on(out, "op0/tst/command") == []


def test_a_failed_task_fails_the_mission_naming_it_and_the_tree_is_aborted() -> None:
    core = _restarted_with_conc()
    asked = _queries(core.on_tick(202.2))
    _unit_answers(core, asked["u0"], "u0", "running", 202.3)
    out = _unit_answers(core, asked["u1"], "u1", "failed", 202.4)
    assert statuses(out) == ["failed"]
    mission = core.book.get("root-1")
    assert "root/children[1] (move-to) failed" in mission.fail_reason, mission.fail_reason
    assert out.jobs == []  # not re-delegated: the tree ended with it
    [abort] = on(out, "op0/tst/command")
    assert abort["command"] == "signal-tst-tree" and abort["signal"] == "$abort"
    assert abort["node-uuid"] == "root-1"  # n0 still flies: the engine is asked to stop it


def test_an_engine_refusing_query_tst_sends_the_service_to_the_units_at_once() -> None:
    core = _restarted_with_conc()
    query = [q for q in on(core.on_tick(200.1), "op0/tst/command")]
    assert query == []  # one query at a time
    pending = next(iter(core.engine.pending))
    from delegation.messages import TstResponse

    resp = TstResponse(response="failed", response_to=pending,
                       fail_reason="query-tst is not supported")
    out = core.on_message(f"{ENGINE}/tst/response", encode(resp), 200.2)
    assert set(_queries(out)) == {"u0", "u1"}


def test_what_the_units_cannot_tell_leaves_the_mission_open() -> None:
    """u0 never answers (the public example agent does not), u1 says success: n0 is unknown, so
    the conc is open; the next silent query-tst asks again."""
    core = _restarted_with_conc()
    asked = _queries(core.on_tick(202.2))
    out = _unit_answers(core, asked["u1"], "u1", "success", 202.3)
    assert statuses(out) == []
    out = core.on_tick(204.3)  # u0's query expired; the second query-tst expired too
    assert core.book.get("root-1").status is MissionStatus.STARTED
    assert core.book.get("root-1").node_status["n1"] == "succeeded"
    again = _queries(out)
    assert set(again) == {"u0"}  # only what is still open is asked about
    out = _unit_answers(core, again["u0"], "u0", "success", 204.4)
    assert statuses(out) == ["succeeded"]


def test_a_task_never_seen_started_is_not_asked_about_and_decides_nothing() -> None:
    first = ServiceCore(ServiceConfig(prefix="t"))
    fleet(first, 100.0)
    started_mission(first, _tree("seq", "root-1", N0, N1))
    _start_task(first, "u0", N0, "task-0", 101.2)  # n1's start-task came while it was down
    core = ServiceCore(ServiceConfig(prefix="t"))
    book = MissionBook()
    book.add(mission_from_record(mission_record(first.book.get("root-1"))))
    core.book = book
    fleet(core, 200.0)
    core.on_tick(200.1)
    asked = _queries(core.on_tick(202.2))
    assert set(asked) == {"u0"}
    out = _unit_answers(core, asked["u0"], "u0", "success", 202.3)
    assert statuses(out) == []
    assert core.book.get("root-1").node_status["n0"] == "succeeded"
    # The engine's feedback still ends it as usual.
    assert statuses(feedback(core, "root-1", "succeeded", 203.0, root=True)) == ["succeeded"]
