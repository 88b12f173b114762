"""Reading and answering the service's commands (pure): one decode, idempotency, authorisation.

A command's bytes are decoded once: the JSON value gives the com-uuid, the digest that tells a
re-send from another command reusing its com-uuid, the caller and the typed command. A re-send
is recognised before the command model is parsed (and long before its tree is validated): a known
com-uuid with the same digest gets the stored answer, or nothing while the first copy is still
being worked on. Every command is answered once, on its caller's response topic, and the answer
is kept in the `CommandLog` for later re-sends.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from typing import Any

from delegation.errors import InputError, InputProblem, MessageError
from delegation.messages import WireModel, parse_command
from delegation.messages.errors import json_value
from delegation.runtime.commands import (
    CommandEntry,
    CommandKey,
    CommandLog,
    CommandState,
    com_uuid_in,
    com_uuid_of,
    payload_digest,
    value_digest,
)
from delegation.runtime.core import Effects, Outgoing
from delegation.service.access import Caller, caller_of, may_manage, refusal
from delegation.service.config import ServiceConfig
from delegation.service.faces import Face, failure
from delegation.service.missions import Mission, MissionBook

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Topics:
    """The service's command, response and feedback topics under its base topic."""

    tst_command: str
    delegation_command: str
    tst_response: str
    tst_feedback: str
    delegation_response: str
    delegation_feedback: str

    @classmethod
    def under(cls, base: str) -> Topics:
        return cls(f"{base}/tst/command", f"{base}/delegation/command", f"{base}/tst/response",
                   f"{base}/tst/feedback", f"{base}/delegation/response",
                   f"{base}/delegation/feedback")

    def response(self, face: Face) -> str:
        """The shared response topic of ``face``."""
        return self.tst_response if face == "tst" else self.delegation_response


@dataclass(frozen=True, slots=True)
class Decoded:
    """A command's bytes decoded once: the JSON ``data`` (when ``error`` is None), its
    com-uuid, digest, and the caller it is accounted to until the command says otherwise."""

    data: Any
    error: MessageError | None
    com_uuid: str | None
    digest: str
    caller: Caller


@dataclass(frozen=True, slots=True)
class Arrival:
    """A command read: ``effects`` when it is answered already (a re-send, a refusal, a bad
    command), else the typed ``command`` to act on under ``key`` (begun in the log)."""

    effects: Effects | None = None
    command: WireModel | None = None
    key: CommandKey = ("", "")


class CommandDesk:
    """The command log's front: decode, recognise re-sends, begin, answer once."""

    def __init__(self, config: ServiceConfig, commands: CommandLog, topics: Topics) -> None:
        self.config = config
        self.commands = commands
        self.topics = topics

    def decode(self, face: Face, payload: bytes, client: str | None = None) -> Decoded:
        """Size first (nothing of an oversized payload is parsed or kept; its com-uuid is
        searched for in its first bytes), then the one JSON decode."""
        where, limit = f"{face}/command", self.config.max_payload
        base = self.topics.response(face)
        caller = Caller(client or "", f"{base}/{client}" if client else "")
        if len(payload) > limit:
            error = MessageError(InputProblem(where, "", f"{len(payload)} bytes is more than "
                                                         f"the {limit} allowed"))
            return Decoded(None, error, com_uuid_of(payload, max_bytes=limit),
                           hashlib.sha256(payload).hexdigest(), caller)
        try:
            data = json_value(payload, where)
        except MessageError as exc:  # still answered by its com-uuid, if one can be read
            return Decoded(None, exc, com_uuid_of(payload), payload_digest(payload, limit),
                           caller)
        return Decoded(data, None, com_uuid_in(data), value_digest(data), caller)

    def arrive(self, face: Face, payload: bytes, now: float, client: str | None = None
               ) -> Arrival:
        """A command's bytes: a re-send is answered from the log before anything is parsed; a
        new command is parsed, begun in the log (with its caller) and returned to act on."""
        d = self.decode(face, payload, client)
        if d.com_uuid is not None:
            known = self._known((face, d.com_uuid), d, client)
            if known is not None:
                return Arrival(known)
        cmd, error, caller = self._parse(face, d, client)
        com_uuid = getattr(cmd, "com_uuid", None) if cmd is not None else d.com_uuid
        key: CommandKey | None = (face, com_uuid) if com_uuid else None
        if key is not None:
            if com_uuid != d.com_uuid:  # named ``com_uuid`` (by attribute): looked up only now
                known = self._known(key, d, client)
                if known is not None:
                    return Arrival(known)
            entry = self.commands.begin(key, now, d.digest)
            entry.caller, entry.reply_topic = caller.name, caller.reply_topic
        if cmd is None or key is None:
            reason = error.fail_reason if error is not None else f"{face}/command: unreadable"
            log.info("bad command on %s/command: %s", face, reason)
            return Arrival(self.fail(face, key, com_uuid or "", reason, caller.reply_topic))
        return Arrival(command=cmd, key=key)

    def _caller_of(self, face: Face, d: Decoded, client: str | None) -> Caller:
        """The caller a decoded command names (the default one when it names a bad one)."""
        if d.error is not None or not isinstance(d.data, dict):
            return d.caller
        try:
            return caller_of(f"{face}/command", d.data, client, self.topics.response(face))
        except InputError:
            return d.caller

    def _parse(self, face: Face, d: Decoded, client: str | None
               ) -> tuple[WireModel | None, MessageError | InputError | None, Caller]:
        """(the typed command or None, why not, its caller)."""
        if d.error is not None:
            return None, d.error, d.caller
        cmd: WireModel | None = None
        error: MessageError | InputError | None = None
        try:
            cmd = parse_command(d.data, face)
        except MessageError as exc:
            error = exc
        try:
            caller = caller_of(f"{face}/command", d.data if isinstance(d.data, dict) else None,
                               client, self.topics.response(face))
        except InputError as exc:
            return None, exc, d.caller
        return cmd, error, caller

    def _known(self, key: CommandKey, d: Decoded, client: str | None) -> Effects | None:
        """The answer to a command seen before (None when it is new): its stored answer again,
        nothing while it is worked on, or a refusal when its com-uuid now names another
        command."""
        entry = self.commands.seen(key)
        if entry is None:
            return None
        if not entry.same_command(d.digest):
            log.info("com-uuid %s reused for a different command", key[1])
            face: Face = "tst" if key[0] == "tst" else "delegation"
            caller = self._caller_of(face, d, client)
            reason = f"{face}/command: com-uuid: {key[1]!r} reused for a different command"
            return self.respond(face, None, failure(face, key[1], reason), caller.reply_topic)
        return self.resend(entry)

    @staticmethod
    def resend(entry: CommandEntry) -> Effects:
        """A command seen before: its stored answer again, or nothing while it is being worked
        on (the answer goes out once ready and serves every copy)."""
        if entry.state is CommandState.PENDING:
            log.info("re-sent command %s is still being worked on", entry.key[1])
            return Effects()
        log.info("re-sent command %s: answering again", entry.key[1])
        return Effects.of(entry.answer)

    def respond(
        self, face: Face, key: CommandKey | None, response: WireModel, reply_topic: str = ""
    ) -> Effects:
        """Publish the answer to a command once, on its caller's response topic; remember it for
        re-sends."""
        entry = self.commands.get(key) if key is not None else None
        topic = (entry.reply_topic if entry is not None else reply_topic) or \
            self.topics.response(face)
        out = Outgoing.of(topic, response)
        if key is not None and not self.commands.finish(key, [out]):
            return Effects()
        return Effects(publish=[out])

    def fail(self, face: Face, key: CommandKey | None, com_uuid: str, reason: str,
             reply_topic: str = "") -> Effects:
        """Answer ``failed`` with ``reason``."""
        log.info("command %s on %s refused: %s", com_uuid or "?", face, reason)
        return self.respond(face, key, failure(face, com_uuid, reason), reply_topic)

    def turn_away(self, face: Face, key: CommandKey, reason: str) -> Effects:
        """Answer ``failed`` with ``reason`` and forget the command (not accepted, not stored):
        the same command re-sent later is taken as new."""
        entry = self.commands.forget(key)
        log.info("command %s on %s turned away: %s", key[1], face, reason)
        return self.respond(face, None, failure(face, key[1], reason),
                            entry.reply_topic if entry is not None else "")

    def caller(self, key: CommandKey) -> str:
        """Who sent the command ``key`` ("" for anonymous)."""
        entry = self.commands.get(key)
        return entry.caller if entry is not None else ""

    def received(self, key: CommandKey, default: float) -> float:
        """When the command ``key`` arrived (``default`` when the log does not know)."""
        entry = self.commands.get(key)
        return entry.received if entry is not None else default

    def missions_page(self, book: MissionBook, key: CommandKey, offset: int, limit: int
                      ) -> tuple[list[dict[str, Any]], int]:
        """(a page of the missions the caller of ``key`` may see, how many there are): an
        operator sees every one, anyone else their own and the anonymous ones."""
        caller = self.caller(key)
        if caller in self.config.operators:
            return book.page(offset, limit)
        every, _ = book.page(0, 1 << 30)
        mine = [s for s in every if may_manage(str(s.get("owner") or ""), caller, ())]
        return mine[offset:offset + limit], len(mine)

    def authorise(self, command: str, mission: Mission, key: CommandKey) -> Mission:
        """The mission, if the caller may touch it; else ``InputError`` saying whose it is."""
        caller = self.caller(key)
        if not may_manage(mission.owner, caller, self.config.operators):
            log.warning("refused %s of mission %s (owner %r) to %r", command, mission.root_uuid,
                        mission.owner, caller)
            raise refusal(command, mission.root_uuid, mission.owner, caller)
        return mission
