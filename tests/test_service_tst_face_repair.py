"""The operator's TST face after a re-delegation replaced the tree (issue 20 item 2,
docs/protocol.md §4 and §11), in the service core without a broker: signals with the operator's
node uuids reach the tree running now, the operator hears the new tree under their own uuids (the
root's final status included) and nothing of the aborted old tree, and a signal to one of the
operator's control nodes that the sent tree regrouped away reaches the tasks under it."""

from __future__ import annotations

import json
from typing import Any

from delegation.runtime.core import Effects
from delegation.service import ServiceConfig, ServiceCore
from test_service_core import BASE, PREFIX, engine_answers, on, run_jobs
from test_service_redelegation import _task, _tree, feedback, fleet, started_mission


def signal(core: ServiceCore, command: str, uid: str, sig: str, now: float,
           com: str = "s-1") -> Effects:
    cmd = {"com-uuid": com, "command": command, "node-uuid": uid, "signal": sig,
           "sender": "test"}
    return core.on_message(f"{BASE}/tst/command", json.dumps(cmd).encode(), now)


def replaced(core: ServiceCore) -> tuple[str, dict[str, Any]]:
    """conc(n0 on u0, n1 on u1), both running; n1 fails on u1: the tree is replaced. The new
    root's uuid and the ``re-delegated`` feedback."""
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0"), _task("n1", "/u1")))
    feedback(core, "n0", "running", 101.5)
    feedback(core, "n1", "running", 101.5)
    failed = feedback(core, "n1", "failed", 102.0, reason="/u1 reported failed")
    assert len(failed.jobs) == 1
    # What the failure spreads up in the old tree is not the operator's news.
    assert on(feedback(core, "root-1", "failed", 102.0, root=True), "tst/feedback") == []
    done = run_jobs(core, failed, 102.1)
    [moved] = on(done, "delegation/feedback")
    engine_answers(core, Effects(publish=[o for o in done.publish if b"start-tst" in o.payload]),
                   "started", 102.2)
    return core.book.get("root-1").current_root, moved


def test_signals_with_the_operators_uuids_reach_the_new_tree() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    new_root, moved = replaced(core)
    assert new_root != "root-1"
    new_n1 = moved["tasks"][0]["node-uuid"]
    out = signal(core, "signal-tst-node", "n1", "$pause", 103.0)
    [cmd] = on(out, "op0/tst/command")
    assert cmd["command"] == "signal-tst-node" and cmd["node-uuid"] == new_n1  # as is, mapped
    out = signal(core, "signal-tst-tree", "root-1", "$abort", 103.1, com="s-2")
    [cmd] = on(out, "op0/tst/command")
    assert cmd["command"] == "signal-tst-tree" and cmd["node-uuid"] == new_root
    answered = engine_answers(core, out, "ok", 103.2)
    assert [(a["response-to"], a["response"]) for a in on(answered, "tst/response")] == [
        ("s-2", "ok")]


def test_the_operator_hears_the_new_tree_under_their_own_uuids_to_its_end() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    new_root, moved = replaced(core)
    new_n1 = moved["tasks"][0]["node-uuid"]
    new_n0 = next(u for u in core.book.get("root-1").current_nodes
                  if u not in (new_root, new_n1))
    # The old tree's abort: nothing relayed.
    for uid in ("n0", "root-1"):
        assert on(feedback(core, uid, "aborted", 102.5, root=uid == "root-1"),
                  "tst/feedback") == []
    heard = []
    for uid, status in ((new_n1, "running"), (new_n0, "running"), (new_n0, "succeeded"),
                        (new_n1, "succeeded")):
        heard += [(f["node-uuid"], f["status"]) for f in on(feedback(core, uid, status, 104.0),
                                                              "tst/feedback")]
    end = on(feedback(core, new_root, "succeeded", 110.0, root=True), "tst/feedback")
    assert heard == [("n1", "running"), ("n0", "running"), ("n0", "succeeded"),
                     ("n1", "succeeded")]
    assert [(f["node-uuid"], f["root-flag"], f["status"]) for f in end] == [
        ("root-1", True, "succeeded")]
    mission = core.book.get("root-1").to_json()
    assert {n["node-uuid"]: n["status"] for n in mission["nodes"]} == {
        "root-1": "succeeded", "n0": "succeeded", "n1": "succeeded"}
    assert mission["status"] == "succeeded"


def test_a_signal_to_an_operators_node_that_ended_before_the_replacement_is_refused() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started_mission(core, _tree("seq", "root-1", _task("n0", "/u0"), _task("n1", "/u1")))
    feedback(core, "n0", "succeeded", 101.5)
    failed = feedback(core, "n1", "failed", 102.0)
    done = run_jobs(core, failed, 102.1)
    engine_answers(core, Effects(publish=[o for o in done.publish if b"start-tst" in o.payload]),
                   "started", 102.2)
    out = signal(core, "signal-tst-node", "n0", "$pause", 103.0)
    [answer] = on(out, "tst/response")
    assert answer["response"] == "failed" and "not part of the tree running now" in \
        answer["fail-reason"]


def _far(uid: str, unit: str, lat: float) -> dict[str, Any]:
    task = _task(uid, unit)
    task["params"]["waypoint"] = {"latitude": lat, "longitude": 16.68, "altitude": 20.0}
    return task


def regrouped_mission(core: ServiceCore) -> None:
    """conc(S1 = conc(a, x), S2 = conc(b, c)), a then b on u0 (a long), x then c on u1 (c long):
    the sent tree is conc(seq(a, b), seq(x, c)), in which neither S1 nor S2 has a node."""
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1",
                                _tree("conc", "S1", _far("a", "/u0", 57.78),
                                      _far("x", "/u1", 57.7612)),
                                _tree("conc", "S2", _far("b", "/u0", 57.7801),
                                      _far("c", "/u1", 57.78))))
    view = core.book.get("root-1").operator
    assert view is not None and not view.relayed("S2"), "the planner kept S2: pick another tree"


def test_a_signal_to_a_regrouped_control_node_reaches_the_tasks_under_it() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    regrouped_mission(core)
    feedback(core, "a", "running", 101.5)
    feedback(core, "x", "succeeded", 101.5)
    feedback(core, "c", "running", 101.6)
    # signal-tst-tree: every task under S2 that has not ended, each answered, answered once.
    out = signal(core, "signal-tst-tree", "S2", "$abort", 102.0)
    sent = on(out, "op0/tst/command")
    assert sorted((c["command"], c["node-uuid"], c["signal"]) for c in sent) == [
        ("signal-tst-node", "b", "$abort"), ("signal-tst-node", "c", "$abort")]
    first = engine_answers(core, Effects(publish=out.publish[:1]), "ok", 102.1)
    assert on(first, "tst/response") == []  # one answer is not the whole
    second = engine_answers(core, Effects(publish=out.publish[1:]), "failed", 102.1,
                            fail_reason="no executing node")
    [answer] = on(second, "tst/response")
    assert answer["response-to"] == "s-1" and answer["response"] == "failed"
    assert "no executing node" in answer["fail-reason"]
    # signal-tst-node $pause (the node alone): only what has not started under it.
    out = signal(core, "signal-tst-node", "S2", "$pause", 103.0, com="s-2")
    assert [(c["node-uuid"], c["signal"]) for c in on(out, "op0/tst/command")] == [
        ("b", "$pause")]
