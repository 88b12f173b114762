"""The operator's own tree during execution (DESIGN 3.4 revised): control nodes derived."""

from __future__ import annotations

from delegation.service.operator_view import OperatorView
from delegation.tst import parse_tree


def _tree() -> OperatorView:
    # conc(s1 = seq(a, b), c): the sent tree may regroup s1 and c; the operator sees these.
    leaf = {"name": "look-at-position", "params": {}}
    return OperatorView.of(parse_tree({"name": "conc", "common_params": {"node-uuid": "r"},
        "children": [
            {"name": "seq", "common_params": {"node-uuid": "s1"}, "children": [
                {**leaf, "common_params": {"node-uuid": "a"}},
                {**leaf, "common_params": {"node-uuid": "b"}}]},
            {**leaf, "common_params": {"node-uuid": "c"}}]}))


def test_control_nodes_follow_their_children_as_the_engine_computes_them() -> None:
    view, status = _tree(), {}
    status["a"] = "running"
    assert view.changes("a", status) == [("s1", "running"), ("r", "running")]
    status["a"] = "succeeded"
    assert view.changes("a", status) == []  # s1 and r still running
    status["b"] = "succeeded"
    assert view.changes("b", status) == [("s1", "succeeded")]
    status["c"] = "failed"
    assert view.changes("c", status) == [("r", "failed")]
    assert "s1" in view and "sent-only" not in view


def test_an_aborted_child_aborts_its_parents() -> None:
    view = _tree()
    assert view.changes("b", {"a": "succeeded", "b": "aborted"}) == [
        ("s1", "aborted"), ("r", "aborted")]


def test_a_kept_control_node_ends_as_the_engine_says_once() -> None:
    # An aborted tree whose leaves never reported: the engine's word on the root is shown, once,
    # and a later derived status does not contradict it.
    view = _tree()
    assert view.final_from_engine("r", "aborted")
    assert not view.final_from_engine("r", "aborted")
    assert not view.final_from_engine("a", "aborted")  # leaves are relayed, not this
    assert not view.final_from_engine("r", "running")
    assert view.changes("c", {"c": "succeeded"}) == []
