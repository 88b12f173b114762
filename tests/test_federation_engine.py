"""The reference engine hands a subtree named for a delegator to it (docs/protocol.md §15.3):
``start-tst`` on its ``tst/command``, its ``tst/feedback`` followed, node uuids kept (pure)."""

from __future__ import annotations

import json
from typing import Any

from delegation.engine.delegated import DELEGATED_TASK, fold_delegated
from delegation.messages import HeartBeat, TstFeedback, TstResponse, encode
from delegation.runtime.core import Effects
from delegation.tst.node import parse_tree, walk
from test_engine_core import FEEDBACK, ctl, engine, on, send, start_tst, task

B = "test/unit/ground/simulation/delegator-b"


def hear_delegator(c: Any, now: float = 0.0) -> Effects:
    hb = HeartBeat(agent_type="ground", agent_uuid="b", levels=["tst execution", "delegation"],
                   name="delegator-b", rate=1.0, stamp=1)
    return c.on_message(f"{B}/heartbeat", encode(hb), now)


def subtree() -> dict[str, Any]:
    """A conc the operator left to the delegator: its inside is not instantiated."""
    inner = ctl("conc", "sub", task("x", unit="*"), task("y", unit=""))
    inner["common_params"]["execunit"] = "/delegator-b"
    return inner


def test_fold_keeps_the_subtree_whole_and_leaves_other_nodes() -> None:
    tree = parse_tree(ctl("conc", "R", task("a"), subtree()))
    folded = fold_delegated(tree, {"delegator-b"})
    names = {n.node_uuid: (n.name, n.execunit) for _, n in walk(folded)}
    assert names == {"R": ("conc", "/op0"), "a": ("move-to", "/dji0"),
                     "sub": (DELEGATED_TASK, "/delegator-b")}
    sent = folded.children[1].params["tst"]
    assert "execunit" not in sent["common_params"]  # the delegator chooses inside
    assert [c["common_params"]["node-uuid"] for c in sent["children"]] == ["x", "y"]
    assert fold_delegated(tree, set()) is tree and fold_delegated(tree, {"nobody"}) is tree


def test_a_delegated_subtree_runs_on_the_delegator_and_its_feedback_is_followed() -> None:
    c = engine("dji0")
    hear_delegator(c)
    started = send(c, start_tst(ctl("conc", "R", task("a"), subtree())))
    assert on(started, "test/unit/ground/simulation/op0/tst/response")[0]["response"] == "started"
    [ask] = on(started, f"{B}/tst/command")
    assert ask["command"] == "start-tst" and ask["receiver"] == "delegator-b"
    assert ask["tst"]["common_params"] == {"node-uuid": "sub"}
    assert on(started, f"{B}/exec/command") == []  # never a start-task
    # Re-sent unanswered with the same com-uuid, like any start.
    again = c.on_tick(3.5)
    assert [m["com-uuid"] for m in on(again, f"{B}/tst/command")] == [ask["com-uuid"]]

    ok = TstResponse(response="started", response_to=ask["com-uuid"], root_uuid="sub")
    running = c.on_message(f"{B}/tst/response", encode(ok), 4.0)
    assert [(f["node-uuid"], f["status"]) for f in on(running, FEEDBACK)] == [("sub", "running")]
    # Inside: relayed unchanged; foreign nodes and impostors ignored.
    inner = c.on_message(f"{B}/tst/feedback",
                         encode(TstFeedback(node_uuid="x", status="running")), 5.0)
    assert [(f["node-uuid"], f["status"]) for f in on(inner, FEEDBACK)] == [("x", "running")]
    assert c.on_message(f"{B}/tst/feedback",
                        encode(TstFeedback(node_uuid="zzz", status="running")), 5.0).publish == []
    other = "test/unit/ground/simulation/mallory/tst/feedback"
    assert c.on_message(other, encode(TstFeedback(node_uuid="x", status="failed")),
                        5.0).publish == []
    done = c.on_message(f"{B}/tst/feedback", encode(TstFeedback(
        node_uuid="sub", status="succeeded", root_flag=True)), 9.0)
    assert [(f["node-uuid"], f["status"], f["root-flag"]) for f in on(done, FEEDBACK)] == [
        ("sub", "succeeded", False)]
    assert c.executor.status("sub").value == "succeeded"


def test_a_signal_to_the_subtree_becomes_signal_tst_tree_and_a_refusal_fails_it() -> None:
    c = engine("dji0")
    hear_delegator(c)
    started = send(c, start_tst(ctl("conc", "R", task("a"), subtree())))
    [ask] = on(started, f"{B}/tst/command")
    c.on_message(f"{B}/tst/response", encode(TstResponse(response="started",
                                                         response_to=ask["com-uuid"])), 2.0)
    abort = send(c, {"com-uuid": "s1", "command": "signal-tst-tree", "sender": "test",
                     "node-uuid": "R", "signal": "$abort"}, 3.0)
    [sig] = on(abort, f"{B}/tst/command")
    assert (sig["command"], sig["node-uuid"], sig["signal"]) == ("signal-tst-tree", "sub",
                                                                 "$abort")
    # A delegator that refuses the subtree fails the node, saying so.
    c2 = engine("dji0")
    hear_delegator(c2)
    [ask2] = on(send(c2, start_tst(ctl("conc", "R2", task("a2"), subtree()))), f"{B}/tst/command")
    no = TstResponse(response="failed", response_to=ask2["com-uuid"], fail_reason="not mine")
    failed = c2.on_message(f"{B}/tst/response", encode(no), 2.0)
    [fb] = [f for f in on(failed, FEEDBACK) if f["node-uuid"] == "sub"]
    assert fb["status"] == "failed" and "not mine" in fb["fail-reason"]


def test_tasks_inside_named_for_the_delegator_go_with_the_subtree_unnamed() -> None:
    inner = subtree()
    for child in inner["children"]:
        child["common_params"]["execunit"] = "/delegator-b"
    folded = fold_delegated(parse_tree(ctl("conc", "R", task("a"), inner)), {"delegator-b"})
    assert [n.name for _, n in walk(folded)] == ["conc", "move-to", DELEGATED_TASK]
    sent = folded.children[1].params["tst"]
    assert all("execunit" not in c["common_params"] for c in [sent, *sent["children"]])


def test_a_delegator_not_heard_lately_is_handed_nothing_the_engine_runs_the_node() -> None:
    c = engine("dji0", "dji1")
    hear_delegator(c, now=0.0)
    stale = ctl("conc", "sub", task("x"), task("y", unit="/dji1"))  # re-planned onto our units
    stale["common_params"]["execunit"] = "/delegator-b"
    started = send(c, start_tst(ctl("conc", "R", task("a", unit="/dji1"), stale)), 10.0)
    assert on(started, f"{B}/tst/command") == []
    units = {json.loads(o.payload)["execution-unit"] for o in started.publish
             if o.topic.endswith("/exec/command")}
    assert units == {"dji0", "dji1"}  # as the seed spells it (protocol.md §3)
