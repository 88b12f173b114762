"""Repairs that move only what must move, in the service core (issue 22 item 3, docs/protocol.md
§11): a lost unit's unfinished tasks are planned again and moved within the running tree
(``rebind-tst-nodes``); the tree is neither aborted nor sent again, so healthy units' tasks go on.
An engine that refuses (or does not answer) the rebind gets the old remedy: the tree replaced.

Fed with explicit times, planning jobs run with the real planner, no broker."""

from __future__ import annotations

from delegation.messages import HeartBeat, encode
from delegation.runtime.core import Effects
from delegation.service import ServiceConfig, ServiceCore
from delegation.tst.node import parse_tree, walk
from test_service_core import PREFIX, engine_answers, on, run_jobs
from test_service_redelegation import _task, _tree, feedback, fleet, started_mission, statuses


def _lost_u1(core: ServiceCore) -> Effects:
    """A conc of n0 on u0 and n1 on u1, both running; u1 falls silent: the repair's plan."""
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0"), _task("n1", "/u1")))
    feedback(core, "n0", "running", 101.5)
    feedback(core, "n1", "running", 101.5)
    fleet(core, 104.0, ("u0", "u2"))
    lost = core.on_tick(105.0)
    assert len(lost.jobs) == 1
    # The tree runs on while the repair is planned: the mission is not re-delegating.
    assert not core.book.get("root-1").redelegating
    return run_jobs(core, lost, 105.2)


def test_a_lost_units_task_moves_within_the_running_tree() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    planned = _lost_u1(core)
    [cmd] = on(planned, "op0/tst/command")  # no $abort, no start-tst: one rebind
    assert cmd["command"] == "rebind-tst-nodes" and list(cmd["execunits"]) == ["n1"]
    unit = cmd["execunits"]["n1"]
    assert unit in ("/u0", "/u2")
    assert on(planned, "delegation/feedback") == []  # told once the engine has moved it
    done = engine_answers(core, planned, "ok", 105.3)
    [moved] = on(done, "delegation/feedback")
    assert moved["status"] == "re-delegated" and "/u1 lost" in moved["fail-reason"]
    assert [(t["node-uuid"], t["replaces"], t["unit"]) for t in moved["tasks"]] == [
        ("n1", "n1", unit)]
    mission = core.book.get("root-1")
    assert mission.current_root == "root-1" and mission.redelegations == 1
    assert mission.nodes["n1"].execunit == unit and mission.retries == {"n1": 1}
    sent = {n.node_uuid: n.execunit for _, n in walk(parse_tree(mission.current_tst))}
    assert sent["n1"] == unit and sent["n0"] == "/u0"
    # The same tree's root ends the mission.
    feedback(core, "n1", "active", 105.4)
    feedback(core, "n0", "succeeded", 110.0)
    feedback(core, "n1", "succeeded", 115.0)
    assert statuses(feedback(core, "root-1", "succeeded", 115.0, root=True)) == ["succeeded"]


def test_a_rebind_the_engine_refuses_replaces_the_tree_instead() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    planned = _lost_u1(core)
    refused = engine_answers(core, planned, "failed", 105.3,
                             fail_reason="'rebind-tst-nodes' is not supported")
    assert core.book.get("root-1").redelegating and len(refused.jobs) == 1
    done = run_jobs(core, refused, 105.5)
    assert [c["command"] for c in on(done, "op0/tst/command")] == ["signal-tst-tree",
                                                                   "start-tst"]
    [moved] = on(done, "delegation/feedback")
    assert "did not move the tasks" in moved["fail-reason"] and "not supported" in \
        moved["fail-reason"]


def test_an_unanswered_rebind_replaces_the_tree_after_the_engine_timeout() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX, engine_timeout=5.0))
    _lost_u1(core)
    fleet(core, 109.0, ("u0", "u2"))
    assert core.on_tick(110.1).jobs == []  # the deadline is 105.2 + 5 s
    expired = core.on_tick(110.3)
    assert len(expired.jobs) == 1 and core.book.get("root-1").redelegating


def test_a_rebooted_units_running_task_moves_too() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started_mission(core, _tree("seq", "root-1", _task("n0", "/u0"), _task("n1", "/u1")))
    feedback(core, "n0", "succeeded", 102.0)
    feedback(core, "n1", "running", 102.5)
    hb = HeartBeat(agent_type="air", agent_uuid="a-new-one", levels=["direct execution"],
                   name="u1", rate=1.0, stamp=103.0)
    rebooted = core.on_message(f"{PREFIX}/unit/air/simulation/u1/heartbeat", encode(hb), 103.0)
    done = run_jobs(core, rebooted, 103.1)
    [cmd] = on(done, "op0/tst/command")
    assert cmd["command"] == "rebind-tst-nodes" and list(cmd["execunits"]) == ["n1"]
    assert cmd["execunits"]["n1"] in ("/u0", "/u2")  # n0 succeeded: never moved nor redone


def test_a_unit_lost_during_a_repair_is_repaired_next() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0, ("u0", "u1", "u2", "u3"))
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0"), _task("n1", "/u1"),
                                _task("n2", "/u2")))
    for uid in ("n0", "n1", "n2"):
        feedback(core, uid, "running", 101.5)
    fleet(core, 104.0, ("u0", "u2", "u3"))
    planned = run_jobs(core, core.on_tick(105.0), 105.1)  # u1 lost
    # u2 falls silent too while the first repair waits for the engine.
    fleet(core, 106.0, ("u0", "u3"))
    assert core.on_tick(109.5).jobs == []  # one repair of a mission at a time
    done = engine_answers(core, planned, "ok", 109.6)
    assert statuses(done) == ["re-delegated"]
    assert len(done.jobs) == 1  # u2's task is planned next
    again = run_jobs(core, done, 109.7)
    [cmd] = on(again, "op0/tst/command")
    assert cmd["command"] == "rebind-tst-nodes" and "n2" in cmd["execunits"]
    assert all(u in ("/u0", "/u3") for u in cmd["execunits"].values())


def test_a_failed_tasks_replan_made_again_still_replaces_the_tree() -> None:
    # A failure replaces the tree (the engine already stopped its branch), also when a task
    # succeeded while it was planned and it is planned again without it.
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0"), _task("n1", "/u1")))
    feedback(core, "n0", "running", 101.5)
    failed = feedback(core, "n1", "failed", 102.0, reason="/u1 reported failed")
    feedback(core, "n0", "succeeded", 102.05)
    again = run_jobs(core, failed, 102.1)
    assert len(again.jobs) == 1 and on(again, "op0/tst/command") == []
    assert core.book.get("root-1").redelegating and not core.repair.replans["root-1"].rebind
