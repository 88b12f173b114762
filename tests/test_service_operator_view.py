"""The operator's own tree during execution (docs/protocol.md §8): control nodes derived."""

from __future__ import annotations

import pytest

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


def test_an_aborted_child_aborts_its_parents_once_their_other_branches_ended() -> None:
    view = _tree()
    # s1 = seq(a, b) has ended; r = conc(s1, c) lets c run on (docs/protocol.md §12.3).
    assert view.changes("b", {"a": "succeeded", "b": "aborted"}) == [("s1", "aborted"),
                                                                     ("r", "running")]
    assert view.changes("c", {"a": "succeeded", "b": "aborted", "c": "succeeded"}) == [
        ("r", "aborted")]


def _one(kids: int = 3) -> OperatorView:
    leaf = {"name": "look-at-position", "params": {}}
    return OperatorView.of(parse_tree({"name": "conc", "common_params": {"node-uuid": "p"},
        "children": [{**leaf, "common_params": {"node-uuid": f"k{i}"}}
                     for i in range(kids)]}))


#: (children's statuses, the control node's derived status): issue 20 item 4, §12.3.
DERIVED = [
    (("succeeded", "succeeded", "succeeded"), "succeeded"),
    (("succeeded", "revoked", "succeeded"), "succeeded"),  # a skipped child is not a failure
    (("revoked", "revoked", "succeeded"), "succeeded"),
    (("revoked", "revoked", "revoked"), "revoked"),  # all skipped: the node did nothing
    (("aborted", "revoked", "succeeded"), "aborted"),
    (("aborted", "failed", "succeeded"), "failed"),  # a later failure makes it failed
    (("aborted", "running", "not-active"), "running"),  # ends once the others have ended
    (("failed", "running", "not-active"), "running"),
    (("revoked", "not-active", "not-active"), "not-active"),  # skipping is not starting
    (("revoked", "active", "not-active"), "running"),
    (("not-active", "not-active", "not-active"), "not-active"),
]


@pytest.mark.parametrize(("kids", "derived"), DERIVED, ids=[",".join(k) for k, _ in DERIVED])
def test_a_control_node_is_derived_from_its_children_as_the_engine_ends_it(kids, derived) -> None:
    view = _one()
    assert view.derive("p", {f"k{i}": s for i, s in enumerate(kids)}) == derived


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


def test_what_was_shown_may_change_again_after_a_re_delegation() -> None:
    view = _tree()
    assert view.changes("b", {"a": "succeeded", "b": "failed"}) == [("s1", "failed"),
                                                                    ("r", "running")]
    assert view.changes("b", {"a": "succeeded", "b": "running"}) == []  # final stays
    view.reset()  # the tree was replaced: b runs again elsewhere (and r is said again)
    assert view.changes("b", {"a": "succeeded", "b": "running"}) == [("s1", "running"),
                                                                     ("r", "running")]
