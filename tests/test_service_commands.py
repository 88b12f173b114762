"""The command desk alone (`delegation.service.commands`): one decode, re-sends recognised before
the command is parsed, every command answered once on its caller's topic."""

from __future__ import annotations

import json
from typing import Any

import pytest

from delegation.messages import DelegationPing, DelegationResponse
from delegation.runtime.commands import CommandLog, payload_digest, value_digest
from delegation.service import commands as desk_module
from delegation.service.commands import CommandDesk, Topics
from delegation.service.config import ServiceConfig
from delegation.service.missions import Mission

BASE = "waraps/service/virtual/delegation/ds0"


@pytest.fixture
def desk() -> CommandDesk:
    return CommandDesk(ServiceConfig(operators=frozenset({"ops"}), max_payload=2000), CommandLog(),
                       Topics.under(BASE))


def _bytes(command: dict[str, Any]) -> bytes:
    return json.dumps(command).encode()


def test_a_new_command_is_parsed_and_begun_with_its_caller(desk: CommandDesk) -> None:
    got = desk.arrive("delegation", _bytes({"command": "ping", "com-uuid": "c1"}), 5.0, "alice")
    assert got.effects is None and isinstance(got.command, DelegationPing)
    assert got.key == ("delegation", "c1")
    assert desk.caller(got.key) == "alice" and desk.received(got.key, 0.0) == 5.0
    out = desk.respond("delegation", got.key, DelegationResponse(response="pong",
                                                                 response_to="c1"))
    assert [o.topic for o in out.publish] == [f"{BASE}/delegation/response/alice"]
    again = desk.respond("delegation", got.key, DelegationResponse(response="pong",
                                                                   response_to="c1"))
    assert again.publish == []  # answered once


def test_a_resend_is_answered_from_the_log_without_parsing(
    desk: CommandDesk, monkeypatch: pytest.MonkeyPatch
) -> None:
    first = desk.arrive("delegation", _bytes({"command": "ping", "com-uuid": "c1", "x": 1}), 1.0)
    answer = desk.respond("delegation", first.key, DelegationResponse(response="pong",
                                                                      response_to="c1"))

    def boom(*_: object) -> None:
        raise AssertionError("a re-send must not be parsed")

    monkeypatch.setattr(desk_module, "parse_command", boom)
    # Key order and spacing do not make it another command.
    resent = desk.arrive("delegation", b'{"x":1, "com-uuid":"c1","command":"ping"}', 4.0)
    assert resent.effects is not None and resent.effects.publish == answer.publish
    assert desk.commands.get(("delegation", "c1")).resends == 1  # type: ignore[union-attr]


def test_a_resend_while_pending_gets_nothing(desk: CommandDesk) -> None:
    desk.arrive("tst", _bytes({"command": "ping", "com-uuid": "c1"}), 1.0)
    again = desk.arrive("tst", _bytes({"command": "ping", "com-uuid": "c1"}), 2.0)
    assert again.effects is not None and again.effects.publish == [] and again.command is None


def test_a_reused_com_uuid_is_refused_on_the_callers_topic(desk: CommandDesk) -> None:
    desk.arrive("delegation", _bytes({"command": "ping", "com-uuid": "c1"}), 1.0)
    other = desk.arrive("delegation", _bytes({"command": "list-agents", "com-uuid": "c1"}), 2.0,
                        "bob")
    assert other.effects is not None
    [out] = other.effects.publish
    assert out.topic == f"{BASE}/delegation/response/bob"
    assert "'c1' reused for a different command" in json.loads(out.payload)["fail-reason"]


@pytest.mark.parametrize(("payload", "com"), [
    (b'{"command": "ping", "com-uuid": "c1", "x": NaN}', "c1"),  # strict JSON refuses it
    (b'{"command": "nope", "com-uuid": "c1"}', "c1"),
    (b'\xff{"com-uuid": "c1"', "c1"),  # not JSON: the com-uuid is searched for
    (b"[1, 2]", ""),
])
def test_bad_commands_are_answered_failed_by_their_com_uuid(
    desk: CommandDesk, payload: bytes, com: str
) -> None:
    got = desk.arrive("tst", payload, 1.0)
    assert got.effects is not None and got.command is None
    [out] = got.effects.publish
    body = json.loads(out.payload)
    assert body["response"] == "failed" and body["response-to"] == com
    assert (desk.commands.get(("tst", com)) is not None) == bool(com)


def test_an_oversized_command_is_refused_unparsed(desk: CommandDesk) -> None:
    payload = _bytes({"com-uuid": "big", "command": "ping", "pad": "x" * 3000})
    d = desk.decode("tst", payload)
    assert d.error is not None and d.data is None and d.com_uuid == "big"
    assert "more than the 2000 allowed" in d.error.fail_reason
    assert d.digest == payload_digest(payload, 2000)


def test_the_one_decode_gives_the_same_digest_as_the_bytes(desk: CommandDesk) -> None:
    payload = b'{"command": "ping",  "com-uuid": "c9"}'
    d = desk.decode("delegation", payload)
    assert d.error is None and d.com_uuid == "c9"
    assert d.digest == payload_digest(payload) == value_digest(json.loads(payload))


def test_authorise_names_the_owner(desk: CommandDesk) -> None:
    mission = Mission(root_uuid="r1", source="delegate", created=0.0, tst={}, plan={}, nodes={},
                      owner="alice")
    for caller, allowed in (("alice", True), ("ops", True), ("bob", False)):
        key = desk.arrive("delegation", _bytes({"command": "ping", "com-uuid": caller}), 1.0,
                          caller).key
        if allowed:
            assert desk.authorise("query-mission", mission, key) is mission
        else:
            with pytest.raises(Exception, match="belongs to 'alice'"):
                desk.authorise("query-mission", mission, key)
