"""Re-delegation, lost engines and fleet commitments in the service core, without a broker.

The core is fed heartbeats, engine feedback and ticks with explicit times; planning jobs run with
the real planner, as the service's worker would.
"""

from __future__ import annotations

import json
from typing import Any

from delegation.messages import HeartBeat, MissionStatus, TstFeedback, encode
from delegation.runtime.core import Effects
from delegation.service import ServiceConfig, ServiceCore
from delegation.service.redelegation import first_origin, remaining_tree, unfinished_on
from delegation.tst.node import parse_tree, walk
from test_service_core import (
    BASE,
    ENGINE,
    PREFIX,
    engine_answers,
    feed_engine,
    feed_unit,
    on,
    run_jobs,
    start_tst,
)

MOVE = ["move-to"]


def _wp(lat: float, lon: float) -> dict[str, Any]:
    return {"latitude": lat, "longitude": lon, "altitude": 20.0}


def _task(uid: str, unit: str = "*", name: str = "move-to") -> dict[str, Any]:
    return {"name": name, "common_params": {"execunit": unit, "node-uuid": uid},
            "params": {"waypoint": _wp(57.7611, 16.6805)}}


def _tree(name: str, uid: str, *children: dict[str, Any]) -> dict[str, Any]:
    return {"name": name, "common_params": {"node-uuid": uid}, "children": list(children)}


def fleet(core: ServiceCore, now: float, names: tuple[str, ...] = ("u0", "u1", "u2")) -> None:
    for i, name in enumerate(names):
        feed_unit(core, name, 57.760 + i * 0.001, 16.680, MOVE, now)
    feed_engine(core, now)


def feedback(core: ServiceCore, uid: str, status: str, now: float, root: bool = False,
             reason: str = "") -> Effects:
    fb = TstFeedback(node_uuid=uid, status=status, root_flag=root, fail_reason=reason)
    return core.on_message(f"{ENGINE}/tst/feedback", encode(fb), now)


def started_mission(core: ServiceCore, tree: dict[str, Any], now: float = 101.0) -> Effects:
    planned = run_jobs(core, core.on_message(f"{BASE}/tst/command", start_tst(tree), now), now)
    engine_answers(core, planned, "started", now)
    return planned


def statuses(effects: Effects) -> list[str]:
    return [f["status"] for f in on(effects, "delegation/feedback")]


# --------------------------------------------------------------------------- the remaining tree


def test_the_remaining_tree_keeps_structure_drops_what_succeeded_and_frees_the_lost_unit() -> None:
    tree = parse_tree(_tree("seq", "r", _task("a", "/u0"), _tree("conc", "c", _task("b", "/u1"),
                                                                  _task("d", "/u0")),
                            _task("e", "/u1")))
    status = {"a": "succeeded", "b": "running", "d": "running"}
    assert unfinished_on(tree, status, "u1") == ["b", "e"]
    ids = iter(f"x{i}" for i in range(10))
    rem = remaining_tree(tree, status, {"u1"}, lambda: next(ids))
    assert rem is not None
    kept = [(n.name, n.execunit, rem.origin[n.node_uuid or ""]) for _, n in walk(rem.tree)]
    assert kept == [("seq", None, "r"), ("conc", None, "c"), ("move-to", "", "b"),
                    ("move-to", "/u0", "d"), ("move-to", "", "e")]
    assert {rem.origin[u] for u in rem.freed} == {"b", "e"}
    assert remaining_tree(tree, {k: "succeeded" for k in "abde"}, {"u1"}, lambda: "z") is None
    assert first_origin({"y": "x", "x": "a"}, "y") == "a"


# --------------------------------------------------------------------------- a lost unit


def test_restart_a_lost_unit_is_re_delegated_and_the_new_tree_ends_the_mission() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX, repair="restart"))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0"), _task("n1", "/u1")))
    feedback(core, "n0", "running", 101.5)
    feedback(core, "n1", "running", 101.5)
    fleet(core, 104.0, ("u0", "u2"))  # u1 has been silent since 100.0
    assert core.on_tick(104.9).jobs == []
    lost = core.on_tick(105.0)  # 5 s without a heartbeat (3 periods at 1 Hz, at least 5 s)
    assert len(lost.jobs) == 1 and core.book.get("root-1").redelegating
    done = run_jobs(core, lost, 105.2)
    to_engine = on(done, "op0/tst/command")
    assert [c["command"] for c in to_engine] == ["signal-tst-tree", "start-tst"]
    assert to_engine[0]["node-uuid"] == "root-1" and to_engine[0]["signal"] == "$abort"
    moved = on(done, "delegation/feedback")
    assert [m["status"] for m in moved] == ["re-delegated"]
    assert "/u1 lost" in moved[0]["fail-reason"]
    assert [(t["replaces"], t["unit"]) for t in moved[0]["tasks"]] == [("n1", "/u2")]
    new_tree = parse_tree(to_engine[1]["tst"])
    units = sorted(n.execunit for _, n in walk(new_tree) if not n.is_control)
    assert units == ["/u0", "/u2"]  # n0 stays on its healthy unit, n1 moved to u2
    mission = core.book.get("root-1")
    assert mission.current_root == new_tree.node_uuid and mission.redelegations == 1
    # The old tree's end (aborted) does not end the mission; the new tree's does.
    assert statuses(feedback(core, "root-1", "aborted", 106.0, root=True)) == []
    assert not core.book.get("root-1").ended
    end = feedback(core, new_tree.node_uuid or "", "succeeded", 120.0, root=True)
    assert statuses(end) == ["succeeded"]
    assert core.book.get("root-1").to_json()["re-delegations"] == 1


def test_restart_a_rebooted_unit_is_re_delegated_at_once() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX, repair="restart"))
    fleet(core, 100.0)
    started_mission(core, _tree("seq", "root-1", _task("n0", "/u0"), _task("n1", "/u1")))
    feedback(core, "n0", "succeeded", 102.0)
    feedback(core, "n1", "running", 102.5)
    hb = HeartBeat(agent_type="air", agent_uuid="a-new-one", levels=["direct execution"],
                   name="u1", rate=1.0, stamp=103.0)
    rebooted = core.on_message(f"{PREFIX}/unit/air/simulation/u1/heartbeat", encode(hb), 103.0)
    done = run_jobs(core, rebooted, 103.1)
    start = [c for c in on(done, "op0/tst/command") if c["command"] == "start-tst"]
    tasks = [n for _, n in walk(parse_tree(start[0]["tst"])) if not n.is_control]
    assert len(tasks) == 1 and tasks[0].execunit in ("/u0", "/u2")  # n0 succeeded: not redone
    assert "rebooted" in on(done, "delegation/feedback")[0]["fail-reason"]


def test_when_nobody_can_take_the_task_the_mission_fails_naming_unit_and_task() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0, ("u0", "u1"))
    feed_unit(core, "s0", 57.761, 16.681, ["search-area", "move-to"], 100.0)
    area = {"name": "search-area", "common_params": {"execunit": "/s0", "node-uuid": "sa"},
            "params": {"area": [_wp(57.76, 16.68), _wp(57.761, 16.68), _wp(57.761, 16.681)]}}
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0"), area))
    fleet(core, 104.0, ("u0", "u1"))
    done = run_jobs(core, core.on_tick(105.0), 105.1)
    assert statuses(done) == ["failed"]
    reason = core.book.get("root-1").fail_reason
    assert "/s0 lost" in reason and "search-area" in reason and "nobody can take" in reason
    assert [c["signal"] for c in on(done, "op0/tst/command")] == ["$abort"]


def test_a_failing_task_is_retried_within_its_budget_then_fails_the_mission() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX, max_retries=1))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0")))
    failed = feedback(core, "n0", "failed", 102.0, reason="/u0 refused move-to: motor fault")
    assert len(failed.jobs) == 1
    # The engine's root "failed" that follows does not end the mission being re-delegated.
    assert statuses(feedback(core, "root-1", "failed", 102.0, root=True)) == []
    done = run_jobs(core, failed, 102.1)
    moved = on(done, "delegation/feedback")[0]
    assert moved["status"] == "re-delegated" and moved["tasks"][0]["unit"] != "/u0"
    assert "motor fault" in moved["fail-reason"]
    engine_answers(core, Effects(publish=[o for o in done.publish
                                          if b"start-tst" in o.payload]), "started", 102.2)
    new = moved["tasks"][0]["node-uuid"]
    again = feedback(core, new, "failed", 103.0, reason="also broken")
    assert again.jobs == []  # budget spent: the failure ends the mission as usual
    root = core.book.get("root-1").current_root
    assert statuses(feedback(core, root, "failed", 103.0, root=True)) == ["failed"]


# --------------------------------------------------------------------------- the engine


def test_a_lost_engine_not_back_in_time_fails_its_missions_with_the_reason() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX, engine_return_timeout=8.0))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0")))
    for now in (105.2, 109.2, 113.1):  # lost at 105.2 (5 s without a heartbeat), waited for
        for name in ("u0", "u1", "u2"):
            feed_unit(core, name, 57.76, 16.68, MOVE, now)
        assert statuses(core.on_tick(now)) == []
    gone = core.on_tick(113.3)
    assert statuses(gone) == ["failed"]
    assert "engine op0 lost (no heartbeat) and not back within 8 s" in core.book.get(
        "root-1").fail_reason


def test_a_restarted_engine_does_not_fail_its_missions_it_is_asked_about_them() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0")))
    hb = HeartBeat(agent_type="ground", agent_uuid="engine-2", levels=["tst execution"],
                   name="op0", rate=1.0, stamp=102.0)
    assert statuses(core.on_message(f"{ENGINE}/heartbeat", encode(hb), 102.0)) == []
    [query] = on(core.on_tick(102.1), "op0/tst/command")
    assert query["command"] == "query-tst" and query["node-uuid"] == "root-1"
    assert core.book.get("root-1").status is MissionStatus.STARTED


def test_cancel_without_a_live_engine_ends_the_mission_at_once() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX, max_heartbeat_timeout=60.0))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0")))
    core.fleet.forget("op0")
    cmd = json.dumps({"com-uuid": "k-1", "command": "cancel-mission", "root-uuid": "root-1",
                      "sender": "test"})
    out = core.on_message(f"{BASE}/delegation/command", cmd.encode(), 103.0)
    assert on(out, "delegation/response")[0]["response"] == "ok"
    assert statuses(out) == ["aborted"]
    assert "no TST engine" in core.book.get("root-1").fail_reason


# --------------------------------------------------------------------------- commitments


def test_units_busy_in_a_running_mission_or_low_on_battery_are_left_out_and_said() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX, commitments="exclude"))
    fleet(core, 100.0)
    core.on_message(f"{PREFIX}/unit/air/simulation/u2/sensor/battery_state", b"0.1", 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0")))
    second = core.on_message(f"{BASE}/tst/command",
                             start_tst(_tree("conc", "root-2", _task("m0")), com="c-2"), 101.5)
    job = second.jobs[0]
    assert [u.name for u in job.units] == ["u1"]
    assert any("u0: left out, busy in mission root-1" in n for n in job.notes)
    assert any("u2: left out, battery 10% is below 20%" in n for n in job.notes)
    done = run_jobs(core, second, 101.6)
    plan = on(done, "op0/tst/command")[0]["tst"]
    assert [n.execunit for _, n in walk(parse_tree(plan)) if not n.is_control] == ["/u1"]


def test_a_start_plan_waiting_behind_another_is_made_around_the_unit_it_took() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX, commitments="exclude"))
    fleet(core, 100.0, ("u0", "u1"))
    first = core.on_message(f"{BASE}/tst/command",
                            start_tst(_tree("conc", "root-1", _task("n0")), com="c-1"), 101.0)
    second = core.on_message(f"{BASE}/tst/command",
                             start_tst(_tree("conc", "root-2", _task("m0")), com="c-2"), 101.0)
    one = run_jobs(core, first, 101.1)
    used = [n.execunit for _, n in walk(parse_tree(on(one, "op0/tst/command")[0]["tst"]))
            if not n.is_control]
    # the second start plan waits for the first, then is made with the units as they are then
    assert second.jobs == [] and [j.com_uuid for j in one.jobs] == ["c-2"]
    two = run_jobs(core, Effects(jobs=one.jobs), 101.2)
    again = [n.execunit for _, n in walk(parse_tree(on(two, "op0/tst/command")[0]["tst"]))
             if not n.is_control]
    assert set(again).isdisjoint(used)


def test_nobody_is_lost_while_the_service_itself_is_off_the_broker() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0")))
    core.on_disconnect(101.0)
    assert core.on_tick(116.0) == Effects()  # 15 s of outage: nobody judged
    core.on_reconnect(116.0)
    [query] = on(core.on_tick(116.1), "op0/tst/command")  # what happened meanwhile?
    assert query["command"] == "query-tst"
    # A full timeout (5 s) after the peers' reconnect back-off (reconnect_grace 10 s).
    assert statuses(core.on_tick(130.9)) == []
    feed_unit(core, "u0", 57.76, 16.68, MOVE, 130.0)
    assert statuses(core.on_tick(131.0)) == []  # the engine did not come back: waited for
    gone = core.on_tick(161.1)  # engine_return_timeout (30 s)
    assert statuses(gone) == ["failed"] and "engine op0 lost" in core.book.get(
        "root-1").fail_reason


def test_a_cancel_while_re_delegating_aborts_the_old_tree_and_ends_the_mission() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0")))
    failed = feedback(core, "n0", "failed", 102.0, reason="motor fault")
    assert len(failed.jobs) == 1
    cmd = json.dumps({"com-uuid": "k-2", "command": "cancel-mission", "root-uuid": "root-1",
                      "sender": "test"})
    out = core.on_message(f"{BASE}/delegation/command", cmd.encode(), 102.1)
    assert on(out, "delegation/response")[0]["response"] == "ok"
    assert [(c["node-uuid"], c["signal"]) for c in on(out, "op0/tst/command")] == [
        ("root-1", "$abort")]
    assert statuses(out) == ["aborted"]
    assert run_jobs(core, Effects(jobs=failed.jobs), 102.2).publish == []  # nothing restarts


def test_a_busy_unit_is_planned_from_when_and_where_it_becomes_free() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))  # commitments: wait
    feed_unit(core, "u0", 57.7600, 16.6800, MOVE, 100.0)
    feed_engine(core, 100.0)
    far = {"name": "move-to", "common_params": {"execunit": "/u0", "node-uuid": "n0"},
           "params": {"waypoint": _wp(57.7700, 16.6800)}}  # about 1.1 km north
    first = started_mission(core, _tree("conc", "root-1", far))
    end1 = on(first, "op0/tst/command")[0]
    plan1 = core.book.get("root-1").plan["assignments"][0]
    assert end1 and plan1["execunit"] == "/u0"
    second = core.on_message(f"{BASE}/tst/command", start_tst(
        _tree("conc", "root-2", _task("m0")), com="c-2"), 101.0)  # mission 1 started at 101.0
    (job,) = second.jobs
    (u0,) = job.units
    assert abs(u0.available_at - plan1["end"]) < 1e-6  # when it becomes free ...
    assert (u0.position.latitude, u0.position.longitude) == (57.7700, 16.6800)  # ... and where
    assert any("planned from when and where it becomes free" in n for n in job.notes)
    done = run_jobs(core, second, 101.1)
    plan2 = json.loads(next(o.payload for o in done.publish if b"start-tst" in o.payload))
    assignment = core.book.get("root-2").plan["assignments"][0]
    assert plan2 and assignment["execunit"] == "/u0"
    assert assignment["start"] >= plan1["end"] - 1e-6  # never double-booked


def test_the_schedule_starts_a_busy_units_first_task_when_it_is_free() -> None:
    from delegation.allocation import plan_mission
    from delegation.fleet import make_unit
    from delegation.geo import GeoPoint

    here = GeoPoint(latitude=57.76, longitude=16.68, altitude=20.0)
    tree = parse_tree(_tree("conc", "r", _task("a", "/u0")))
    free = plan_mission(tree, [make_unit("u0", "air", here, MOVE)])
    busy = plan_mission(tree, [make_unit("u0", "air", here, MOVE, available_at=50.0)])
    (a_free,), (a_busy,) = free.assignments, busy.assignments
    assert a_free.start == 0.0 and a_busy.start == 50.0
    assert abs(a_busy.end - (a_free.end + 50.0)) < 1e-9 and busy.makespan == a_busy.end
