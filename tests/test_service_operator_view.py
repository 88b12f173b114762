"""The operator's own tree during execution (docs/protocol.md §8): control nodes derived."""

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


def test_kept_control_nodes_are_the_engines_and_count_for_their_parents() -> None:
    # The sent tree kept s1 (and the root r): their feedback is relayed, not derived.
    leaf = {"name": "look-at-position", "params": {}}
    tree = parse_tree({"name": "conc", "common_params": {"node-uuid": "r"}, "children": [
        {"name": "seq", "common_params": {"node-uuid": "s1"}, "children": [
            {**leaf, "common_params": {"node-uuid": "a"}}]}]})
    view = OperatorView.of(tree, sent=tree)
    assert view.relayed("r") and view.relayed("s1") and view.relayed("a")
    assert view.changes("a", {"a": "running"}) == []  # nothing derived: all kept
    regrouped = OperatorView.of(tree, sent=parse_tree({**leaf, "common_params": {
        "node-uuid": "a"}}))
    assert not regrouped.relayed("s1")
    assert regrouped.changes("a", {"a": "aborted"}) == [("s1", "aborted"), ("r", "aborted")]
