"""`Inbox`: items stamped when they arrive, the frontier ticks are judged at, and the bound
(superseded periodic messages dropped, nothing else)."""

from __future__ import annotations

import threading

from delegation.runtime.inbox import Inbox, periodic
from delegation.runtime.mqtt import Message


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_items_keep_their_arrival_time_and_the_frontier_is_the_oldest_waiting() -> None:
    clock = Clock()
    inbox = Inbox(clock)
    assert inbox.frontier() == 100.0  # nothing waits: the clock
    inbox.put(Message("p/unit/air/simulation/dji0/heartbeat", b"1"))
    clock.t = 101.0
    inbox.put("job done")
    clock.t = 130.0  # 29 s of work later, nothing taken yet
    assert inbox.frontier() == 100.0
    first = inbox.get(0)
    assert first is not None and first.arrived == 100.0
    assert inbox.frontier() == 101.0
    second = inbox.get_nowait()
    assert second is not None and (second.item, second.arrived) == ("job done", 101.0)
    assert inbox.frontier() == 130.0
    assert inbox.get(0.01) is None and inbox.get_nowait() is None


def test_when_full_a_newer_periodic_message_replaces_the_queued_one_on_its_topic() -> None:
    clock = Clock()
    inbox = Inbox(clock, limit=3, name="t")
    beat = "p/unit/air/simulation/dji0/heartbeat"
    command = "p/unit/ground/simulation/svc/delegation/command"
    inbox.put(Message(beat, b"old"))
    inbox.put(Message(command, b"c1"))
    clock.t = 101.0
    inbox.put(Message("p/unit/air/simulation/dji0/sensor/position", b"p1"))
    # Full: the newer heartbeat supersedes the queued one (dropped and counted).
    clock.t = 102.0
    inbox.put(Message(beat, b"new"))
    assert (inbox.dropped, inbox.overflow, len(inbox)) == (1, 0, 3)
    # Commands are never dropped: kept past the limit and counted.
    inbox.put(Message(command, b"c2"))
    # A periodic message on a topic with nothing queued is kept too (one per topic at most).
    inbox.put(Message("p/unit/air/simulation/dji1/heartbeat", b"other"))
    assert (inbox.dropped, inbox.overflow, len(inbox)) == (1, 2, 5)
    taken = []
    while (entry := inbox.get_nowait()) is not None:
        assert isinstance(entry.item, Message)
        taken.append((entry.item.payload, entry.arrived))
    assert taken == [(b"c1", 100.0), (b"p1", 101.0), (b"new", 102.0), (b"c2", 102.0),
                     (b"other", 102.0)]


def test_below_the_limit_nothing_is_dropped() -> None:
    inbox = Inbox(Clock(), limit=100)
    for i in range(50):
        inbox.put(Message("p/unit/air/simulation/dji0/heartbeat", str(i).encode()))
    assert len(inbox) == 50 and inbox.dropped == 0


def test_a_taken_message_is_no_longer_superseded() -> None:
    inbox = Inbox(Clock(), limit=1)
    beat = "p/unit/air/simulation/dji0/heartbeat"
    inbox.put(Message(beat, b"1"))
    assert inbox.get_nowait() is not None
    inbox.put(Message(beat, b"2"))
    inbox.put(Message(beat, b"3"))  # full (1 waiting): "2" is superseded
    entry = inbox.get_nowait()
    assert entry is not None and isinstance(entry.item, Message) and entry.item.payload == b"3"
    assert inbox.dropped == 1 and inbox.get_nowait() is None


def test_periodic_topics() -> None:
    assert periodic("p/unit/air/simulation/dji0/heartbeat")
    assert periodic("p/unit/air/simulation/dji0/sensor/position")
    assert periodic("p/unit/ground/simulation/op0/tst_execution_info")
    for topic in ("p/unit/air/simulation/dji0/exec/feedback",
                  "p/unit/ground/simulation/op0/tst/response",
                  "p/unit/ground/simulation/svc/delegation/command"):
        assert not periodic(topic)


def test_a_waiting_taker_wakes_when_an_item_comes() -> None:
    inbox = Inbox()
    got: list[object] = []
    taker = threading.Thread(target=lambda: got.append(inbox.get(5.0)))
    taker.start()
    inbox.put("x")
    taker.join(5.0)
    assert not taker.is_alive()
    assert got and got[0] is not None
