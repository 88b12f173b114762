"""Mission book-keeping (pure state, no broker)."""

from __future__ import annotations

import pytest

from delegation.errors import InputError
from delegation.messages import MissionStatus
from delegation.service.missions import Mission, MissionBook, node_infos
from delegation.tst.node import make_node


def _tree() -> tuple:
    a = make_node("move-to", execunit="/dji0", node_uuid="a")
    b = make_node("move-to", execunit="/dji1", node_uuid="b")
    root = make_node("conc", [a, b], execunit="/op0", node_uuid="root")
    return root, a, b


def _mission(root) -> Mission:
    return Mission(root_uuid="root", source="tst", created=0.0, tst=root.to_dict(),
                   plan={"assignments": []}, nodes=node_infos(root))


def test_node_infos_index_every_node_with_path_and_unit() -> None:
    root, _, _ = _tree()
    infos = node_infos(root)
    assert set(infos) == {"root", "a", "b"}
    assert infos["b"].path == "root/children[1]"
    assert infos["b"].execunit == "/dji1"
    assert infos["b"].is_task and not infos["root"].is_task


def test_lifecycle_from_root_feedback_and_node_times() -> None:
    root, _, _ = _tree()
    book = MissionBook()
    book.add(_mission(root))
    assert book.of_node("a") is book.find("root")

    ev = book.set_status("root", MissionStatus.STARTED, 1.0)
    assert ev is not None and ev.status is MissionStatus.STARTED
    _, events = book.observe_feedback("root", "running", True, "", 2.0)
    assert [e.status for e in events] == [MissionStatus.RUNNING]
    book.observe_feedback("a", "running", False, "", 3.0)
    book.observe_feedback("a", "succeeded", False, "", 5.0)
    mission, events = book.observe_feedback("root", "succeeded", True, "", 6.0)
    assert mission is not None
    assert [e.status for e in events] == [MissionStatus.SUCCEEDED]
    assert mission.status is MissionStatus.SUCCEEDED and mission.ended_at == 6.0
    data = mission.to_json()
    node_a = next(n for n in data["nodes"] if n["node-uuid"] == "a")
    assert node_a["status"] == "succeeded"
    assert node_a["started"] == 2.0 and node_a["ended"] == 4.0  # seconds since start (t=1)


def test_status_never_moves_back_and_final_is_final() -> None:
    root, _, _ = _tree()
    book = MissionBook()
    book.add(_mission(root))
    book.observe_feedback("root", "running", True, "", 1.0)
    assert book.find("root").status is MissionStatus.RUNNING  # type: ignore[union-attr]
    # A late "started" (the engine's response after its first feedback) changes nothing.
    assert book.set_status("root", MissionStatus.STARTED, 2.0) is None
    assert book.set_status("root", MissionStatus.ABORTED, 3.0) is not None
    assert book.set_status("root", MissionStatus.SUCCEEDED, 4.0) is None
    _, events = book.observe_feedback("root", "succeeded", True, "", 5.0)
    assert events == []


def test_root_failure_without_reason_names_the_failed_tasks() -> None:
    root, _, _ = _tree()
    book = MissionBook()
    book.add(_mission(root))
    book.observe_feedback("b", "failed", False, "", 1.0)
    _, events = book.observe_feedback("root", "failed", True, "", 2.0)
    assert events[-1].status is MissionStatus.FAILED
    assert "root/children[1]" in events[-1].fail_reason and "/dji1" in events[-1].fail_reason


def test_conflicts_name_reused_uuids_of_live_missions_only() -> None:
    root, _, _ = _tree()
    book = MissionBook()
    book.add(_mission(root))
    problems = book.conflicts(root)
    assert {p.where for p in problems} == {"root", "root/children[0]", "root/children[1]"}
    book.set_status("root", MissionStatus.SUCCEEDED, 1.0)
    assert book.conflicts(root) == []


def test_unknown_mission_is_an_input_error_naming_it() -> None:
    with pytest.raises(InputError, match="unknown mission 'nope'"):
        MissionBook().get("nope")


def test_changed_since_names_the_missions_changed_after_a_revision_last_changed_last() -> None:
    book = MissionBook()
    roots = []
    for i in range(3):
        node = make_node("move-to", node_uuid=f"m{i}", execunit="/u1")
        m = Mission(root_uuid=f"m{i}", source="tst", created=0.0, tst=node.to_dict(),
                    plan={"assignments": []}, nodes=node_infos(node))
        book.add(m)
        roots.append(m.root_uuid)
    start = book.revision
    assert book.changed_since(start) == []
    book.touch(roots[0])
    book.touch(roots[2])
    book.touch(roots[0])
    assert book.changed_since(start) == [roots[2], roots[0]]
    assert book.changed_since(0) == [roots[1], roots[2], roots[0]]
    assert book.changed_since(book.revision) == []
