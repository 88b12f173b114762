"""A failed task moves alone (issue 22 item 3, docs/protocol.md §11 and §12.7), in the service
core: the service starts trees with ``hold-failed``; an engine that says it holds them keeps a
failed task's branch going, so the service plans that task again without its unit and moves it by
``rebind-tst-nodes``; nothing is aborted or started again, the unit's other tasks stay on it. An
engine that does not say so (the public op0) gets the old remedy: the tree replaced.

Fed with explicit times, planning jobs run with the real planner, no broker."""

from __future__ import annotations

from delegation.messages import TstResponse, encode
from delegation.runtime.core import Effects
from delegation.service import ServiceConfig, ServiceCore
from delegation.tst.node import parse_tree, walk
from test_service_core import BASE, ENGINE, PREFIX, engine_answers, on, run_jobs, start_tst
from test_service_redelegation import _task, _tree, feedback, fleet, statuses


def started(core: ServiceCore, tree: dict[str, object], hold: bool) -> dict[str, object]:
    planned = run_jobs(core, core.on_message(f"{BASE}/tst/command", start_tst(tree), 101.0),
                       101.0)
    [sent] = on(planned, "op0/tst/command")
    assert sent["command"] == "start-tst" and sent["hold-failed"] == 30.0
    resp = TstResponse(response="started", response_to=sent["com-uuid"],
                       root_uuid=sent["tst"]["common_params"]["node-uuid"],
                       hold_failed=30.0 if hold else None)
    core.on_message(f"{ENGINE}/tst/response", encode(resp), 101.0)
    return sent


def failed_n1(core: ServiceCore, hold: bool) -> Effects:
    fleet(core, 100.0)
    started(core, _tree("conc", "root-1", _task("n0", "/u0"),
                        _tree("seq", "s", _task("n1", "/u1"), _task("n2", "/u1"))), hold)
    feedback(core, "n0", "running", 101.5)
    feedback(core, "n1", "running", 101.5)
    fleet(core, 102.0)
    failed = feedback(core, "n1", "failed", 102.5, reason="/u1 reported failed")
    return run_jobs(core, failed, 102.6)


def test_a_held_failed_task_moves_alone_and_the_rest_runs_on() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    planned = failed_n1(core, hold=True)
    [cmd] = on(planned, "op0/tst/command")  # no $abort, no start-tst: one rebind
    assert cmd["command"] == "rebind-tst-nodes" and list(cmd["execunits"]) == ["n1"]
    unit = cmd["execunits"]["n1"]
    assert unit in ("/u0", "/u2")  # not the unit that failed it
    assert not core.book.get("root-1").redelegating
    done = engine_answers(core, planned, "ok", 102.7)
    [moved] = on(done, "delegation/feedback")
    assert moved["status"] == "re-delegated" and "failed on /u1" in moved["fail-reason"]
    assert [(t["node-uuid"], t["unit"]) for t in moved["tasks"]] == [("n1", unit)]
    mission = core.book.get("root-1")
    sent = {n.node_uuid: n.execunit for _, n in walk(parse_tree(mission.current_tst))}
    assert {k: sent[k] for k in ("n0", "n1", "n2")} == {"n0": "/u0", "n1": unit, "n2": "/u1"}
    assert "n1" not in mission.node_status  # it runs again: its held failure was not its end
    for uid, status in (("n1", "running"), ("n1", "succeeded"), ("n2", "succeeded"),
                        ("n0", "succeeded")):
        feedback(core, uid, status, 110.0)
    assert mission.node_status["n1"] == "succeeded"
    assert statuses(feedback(core, "root-1", "succeeded", 111.0, root=True)) == ["succeeded"]


def test_an_engine_that_does_not_hold_gets_the_tree_replaced() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    planned = failed_n1(core, hold=False)
    assert [c["command"] for c in on(planned, "op0/tst/command")] == ["signal-tst-tree",
                                                                     "start-tst"]


def test_a_rebind_refused_for_a_held_task_replaces_the_tree() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    planned = failed_n1(core, hold=True)
    refused = engine_answers(core, planned, "failed", 102.7,
                             fail_reason="execunits.n1: already ended (failed)")
    assert core.book.get("root-1").redelegating and len(refused.jobs) == 1
    done = run_jobs(core, refused, 102.8)
    assert [c["command"] for c in on(done, "op0/tst/command")] == ["signal-tst-tree",
                                                                   "start-tst"]


def test_every_held_task_of_a_unit_moves_in_one_rebind() -> None:
    # A rebooted unit: the engine fails each task it had accepted, one feedback each; each
    # replan supersedes the last, and the last moves them all.
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started(core, _tree("conc", "root-1", _task("n0", "/u0"), _task("n1", "/u1"),
                        _task("n2", "/u1")), hold=True)
    for uid in ("n0", "n1", "n2"):
        feedback(core, uid, "running", 101.5)
    fleet(core, 102.0)
    why = "/u1 rebooted (a new agent-uuid in its heartbeat): the task it ran is gone"
    first = feedback(core, "n1", "failed", 102.5, reason=why)
    second = feedback(core, "n2", "failed", 102.5, reason=why)
    planned = run_jobs(core, Effects(jobs=[*first.jobs, *second.jobs]), 102.6)
    [cmd] = on(planned, "op0/tst/command")
    assert cmd["command"] == "rebind-tst-nodes" and sorted(cmd["execunits"]) == ["n1", "n2"]
    assert set(cmd["execunits"].values()) <= {"/u0", "/u2"}


def test_a_hold_that_runs_out_before_the_move_is_planned_replaces_the_tree() -> None:
    """The engine's hold (30 s) ran out while the held task's move was still being planned (a
    planner queue behind a long plan): its branch failed as without the hold (§12.7). The
    mission does not end with it: the repair goes on as a replacement of the tree."""
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started(core, _tree("conc", "root-1", _task("n0", "/u0"),
                        _tree("seq", "s", _task("n1", "/u1"), _task("n2", "/u1"))), hold=True)
    feedback(core, "n0", "running", 101.5)
    feedback(core, "n1", "running", 101.5)
    fleet(core, 102.0)
    failed = feedback(core, "n1", "failed", 102.5, reason="/u1 reported failed")
    assert len(failed.jobs) == 1  # the move is being planned (not done yet)
    fleet(core, 132.0)
    lapsed = Effects()
    why = "root/children[1]/children[0] (move-to) failed: /u1 reported failed"
    lapsed.extend(feedback(core, "s", "failed", 132.6, reason=why))
    lapsed.extend(feedback(core, "n0", "aborted", 132.7, reason="/u0 reported aborted"))
    lapsed.extend(feedback(core, "root-1", "failed", 132.8, root=True,
                           reason=f"root/children[1] (seq) failed: {why}"))
    assert statuses(lapsed) == []  # the mission goes on
    assert len(lapsed.jobs) == 1  # planned again whole (n0's abort is the engine's: no job)
    relayed = {(f["node-uuid"], f["status"]) for f in on(lapsed, f"{BASE}/tst/feedback")}
    assert ("s", "failed") not in relayed and ("root-1", "failed") not in relayed
    mission = core.book.get("root-1")
    assert mission.redelegating and not mission.ended
    assert on(run_jobs(core, failed, 133.0), "op0/tst/command") == []  # superseded: dropped
    done = run_jobs(core, lapsed, 133.1)
    assert [c["command"] for c in on(done, "op0/tst/command")] == ["signal-tst-tree",
                                                                   "start-tst"]
    [moved] = on(done, "delegation/feedback")
    assert moved["status"] == "re-delegated"
    new = parse_tree(on(done, "op0/tst/command")[1]["tst"])
    units = {t.name + str(i): t.execunit for i, (_, t) in enumerate(walk(new)) if not t.is_control}
    # n0 again (the branch's failure stopped it), n1 and n2 off the failing unit, as when a
    # rebind is refused.
    assert len(units) == 3 and "/u1" not in units.values()


def test_a_hold_that_runs_out_while_the_move_is_sent_replaces_the_tree() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    planned = failed_n1(core, hold=True)  # the rebind is out, not answered yet
    [cmd] = on(planned, "op0/tst/command")
    assert cmd["command"] == "rebind-tst-nodes"
    fleet(core, 132.0)
    lapsed = feedback(core, "s", "failed", 132.6, reason="root/children[1]/children[0] failed")
    assert core.book.get("root-1").redelegating and len(lapsed.jobs) == 1
    late = TstResponse(response="failed", response_to=cmd["com-uuid"],
                       fail_reason="execunits.n1: already ended (failed)")
    refused = core.on_message(f"{ENGINE}/tst/response", encode(late), 132.7)
    assert refused.jobs == [] and on(refused, "op0/tst/command") == []  # already in hand
    done = run_jobs(core, lapsed, 133.0)
    assert [c["command"] for c in on(done, "op0/tst/command")] == ["signal-tst-tree",
                                                                   "start-tst"]
