"""Mission status changes and the cancels they settle, alone (`delegation.service.lifecycle`,
`delegation.service.cancels`)."""

from __future__ import annotations

import json

from delegation.messages import MissionStatus
from delegation.runtime.commands import CommandLog
from delegation.service.cancels import Cancels
from delegation.service.commands import CommandDesk, Topics
from delegation.service.config import ServiceConfig
from delegation.service.lifecycle import Epoch, Lifecycle
from delegation.service.missions import Mission, MissionBook

BASE = "t/unit/ground/simulation/ds0"


def test_cancels_are_answered_by_the_end_or_pending_at_the_deadline() -> None:
    cancels = Cancels(engine="op0", timeout=5.0)
    cancels.wait("r1", ("delegation", "c1"), 10.0)
    cancels.wait("r2", ("delegation", "c2"), 12.0)
    assert cancels.due(14.9) == []
    [(key, pending)] = cancels.due(15.0)
    assert key == ("delegation", "c1") and pending.response == "pending"
    assert "not confirmed within 5 s" in pending.fail_reason and "r1" not in cancels.waiting
    [(_, failed)] = cancels.ended("r2", MissionStatus.SUCCEEDED, "")
    assert failed.response == "failed" and "ended succeeded before the abort" in \
        failed.fail_reason
    assert cancels.waiting == {} and cancels.ended("r2", MissionStatus.ABORTED, "") == []


def test_a_status_change_is_published_stamped_and_settles_its_cancels() -> None:
    book = MissionBook()
    book.add(Mission(root_uuid="r1", source="delegate", created=0.0, tst={}, plan={}, nodes={},
                     status=MissionStatus.RUNNING))
    desk = CommandDesk(ServiceConfig(), CommandLog(), Topics.under(BASE))
    desk.arrive("delegation", b'{"command": "cancel-mission", "com-uuid": "c1", '
                              b'"root-uuid": "r1"}', 1.0)
    life = Lifecycle(book, desk, Cancels("op0", 5.0), Epoch(1000.0))
    life.wait_cancel("r1", ("delegation", "c1"), 1.0)
    out = life.set_status("r1", MissionStatus.ABORTED, 2.0, "asked to")
    topics = [o.topic for o in out.publish]
    assert topics == [f"{BASE}/delegation/feedback", f"{BASE}/delegation/response"]
    assert json.loads(out.publish[0].payload)["status"] == "aborted"
    assert json.loads(out.publish[1].payload)["response"] == "ok"
    assert book.get("r1").ended_at == 1002.0  # epoch stamps
    assert life.set_status("r1", MissionStatus.ABORTED, 3.0).publish == []  # no change
    assert life.cancel_deadlines(100.0).publish == []
