"""The one idempotency store (`CommandLog`) every unit uses: answered once, re-sends answered
again, bounded; and `com_uuid_of`, which reads a command's com-uuid from raw bytes."""

from __future__ import annotations

from delegation.runtime.commands import CommandLog, CommandState, com_uuid_of
from delegation.runtime.core import Outgoing


def test_com_uuid_of_reads_only_a_string_com_uuid() -> None:
    assert com_uuid_of(b'{"com-uuid": "abc", "command": "ping"}') == "abc"
    assert com_uuid_of(b'{"com-uuid": 5}') is None
    assert com_uuid_of(b'{"com-uuid": ""}') is None
    assert com_uuid_of(b"[1, 2]") is None
    assert com_uuid_of(b"not json") is None
    assert com_uuid_of(b"\xff\xfe") is None


def test_command_log_answers_once_and_remembers() -> None:
    log = CommandLog()
    key = ("tst", "c1")
    assert log.seen(key) is None
    log.begin(key, 0.0)
    entry = log.seen(key)
    assert entry is not None and entry.state is CommandState.PENDING and entry.resends == 1
    assert log.finish(key, [Outgoing("t", b"answer")])
    assert not log.finish(key, [Outgoing("t", b"other")])  # answered once
    again = log.seen(key)
    assert again is not None and again.answer == [Outgoing("t", b"answer")]


def test_answer_again_only_for_an_answered_command() -> None:
    """A new or still-pending command gets None (the unit runs it); an answered one its first
    answer, counted as a re-send."""
    log = CommandLog()
    key = ("exec", "c1")
    assert log.answer_again(key) is None
    log.begin(key, 0.0)
    assert log.answer_again(key) is None
    log.finish(key, [Outgoing("t", b"answer")])
    assert log.answer_again(key) == [Outgoing("t", b"answer")]
    entry = log.get(key)
    assert entry is not None and entry.resends == 2


def test_command_log_is_bounded_but_keeps_pending() -> None:
    log = CommandLog(capacity=3)
    log.begin(("tst", "pending"), 0.0)
    for i in range(5):
        log.begin(("tst", f"c{i}"), float(i))
        log.finish(("tst", f"c{i}"), [])
    assert len(log) == 3
    assert log.seen(("tst", "pending")) is not None
    assert log.seen(("tst", "c0")) is None
