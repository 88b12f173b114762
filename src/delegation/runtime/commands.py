"""Commands remembered per com-uuid, so a re-sent command is answered again and never run twice.

The seed's protocol: unreliable links are handled by re-sending a command with the same com-uuid
until a response arrives. Every unit that answers commands (the delegation service, the TST
engine, the simulated units) keeps one `CommandLog`. A command is first ``pending`` (being worked
on: planning, or waiting for the engine), then ``done`` with the exact messages that answered it.
Pure: no clock (``now`` is passed in), no threads. Persistence is the unit's: ``begin`` and
``finish`` note the key in ``dirty`` (drained and written before the answer is published), and a
command no longer in memory is looked up through an injected `CommandArchive`.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol

from delegation.runtime.core import Outgoing

log = logging.getLogger(__name__)

#: How many commands a unit remembers (oldest answered ones forgotten first): a re-send arrives
#: seconds later, not after ten thousand other commands.
DEFAULT_CAPACITY = 10_000

#: A command's key: (the face it arrived on, its com-uuid). One com-uuid may be used on two faces.
CommandKey = tuple[str, str]


#: The longest com-uuid kept (a longer one is refused, never stored); as ``MAX_IDENTIFIER``.
MAX_COM_UUID = 128
#: How much of an unparsable payload is searched for its com-uuid.
_SCAN_BYTES = 4096
_COM_UUID = re.compile(rb'"com-uuid"\s*:\s*"([^"\\]{1,%d})"' % MAX_COM_UUID)


def com_uuid_in(value: object) -> str | None:
    """The ``com-uuid`` of a decoded command: a non-empty string of at most ``MAX_COM_UUID``
    characters, else None."""
    if not isinstance(value, dict):
        return None
    com = value.get("com-uuid")
    return com if isinstance(com, str) and 0 < len(com) <= MAX_COM_UUID else None


def com_uuid_of(payload: bytes, max_bytes: int | None = None) -> str | None:
    """The ``com-uuid`` of a raw command, if it has a non-empty string one of at most
    ``MAX_COM_UUID`` characters (no other validation: a command too broken to decode is still
    answered by its com-uuid).

    A payload that is not JSON (truncated, invalid UTF-8 elsewhere, nested too deep) or longer
    than ``max_bytes`` is searched for ``"com-uuid": "..."`` in its first bytes only.
    """
    raw: object = None
    if max_bytes is None or len(payload) <= max_bytes:
        try:
            raw = json.loads(payload)
        except (ValueError, UnicodeDecodeError, RecursionError):
            raw = None
    if raw is not None:
        return com_uuid_in(raw)
    match = _COM_UUID.search(payload[:_SCAN_BYTES])
    if match is None:
        return None
    try:
        return match.group(1).decode("utf-8")
    except UnicodeDecodeError:
        return None


def value_digest(value: object) -> str:
    """`payload_digest` of a command already decoded (the one decode of the message): the digest
    of its canonical JSON, so key order and spacing do not make a re-send another command."""
    canonical = json.dumps(value, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


def payload_digest(payload: bytes, max_bytes: int | None = None) -> str:
    """What a command said, for telling a re-send from another command reusing its com-uuid:
    the digest of its canonical JSON (key order and spacing do not matter), or of its bytes
    (when it is not JSON, or longer than ``max_bytes``)."""
    if max_bytes is not None and len(payload) > max_bytes:
        return hashlib.sha256(payload).hexdigest()
    try:
        return value_digest(json.loads(payload))
    except (ValueError, UnicodeDecodeError, RecursionError, TypeError):
        return hashlib.sha256(payload).hexdigest()


class CommandState(StrEnum):
    PENDING = "pending"
    """Received and being worked on (planning, or waiting for the engine)."""
    DONE = "done"
    """Answered; the answer is kept to be sent again on a re-send."""


@dataclass(slots=True)
class CommandEntry:
    """One command seen on one face, by ``com-uuid``."""

    key: CommandKey
    received: float
    state: CommandState = CommandState.PENDING
    answer: list[Outgoing] = field(default_factory=list)
    resends: int = 0
    #: ``payload_digest`` of the command ("" when not recorded): a re-send must match it.
    digest: str = ""
    #: Who sent it and where its answer goes ("": anonymous, the shared response topic).
    caller: str = ""
    reply_topic: str = ""

    def same_command(self, digest: str) -> bool:
        """True when ``digest`` is this command's (or either is unknown)."""
        return not self.digest or not digest or digest == self.digest


class CommandArchive(Protocol):
    """Where answered commands that left memory are read back (a store; the unit's)."""

    def load_command(self, key: CommandKey) -> CommandEntry | None:
        """The stored entry for ``key``, or None."""
        ...


class CommandLog:
    """Commands by (face, com-uuid): ``seen`` on arrival, ``begin`` a new one, ``finish`` with the
    answer. Bounded by ``capacity``; a command still pending is never forgotten. With an
    ``archive``, a key not in memory is looked up there before it counts as new."""

    def __init__(
        self, capacity: int = DEFAULT_CAPACITY, archive: CommandArchive | None = None
    ) -> None:
        self.capacity = capacity
        self.archive = archive
        self._entries: OrderedDict[CommandKey, CommandEntry] = OrderedDict()
        #: Keys begun or finished since the unit last drained them (to persist; kept only with
        #: an archive, so a log nobody drains does not grow).
        self.dirty: set[CommandKey] = set()

    def drain_dirty(self) -> list[CommandEntry]:
        """The entries changed since the last call, and forget the notes."""
        changed = [self._entries[k] for k in self.dirty if k in self._entries]
        self.dirty.clear()
        return changed

    def restore(self, entry: CommandEntry) -> None:
        """Put back an entry read from a store (not dirty: it is stored already)."""
        self._entries[entry.key] = entry
        self._trim()

    def __len__(self) -> int:
        return len(self._entries)

    def seen(self, key: CommandKey) -> CommandEntry | None:
        """The entry of a command already received (counting this re-send), or None if new."""
        entry = self._entries.get(key)
        if entry is None and self.archive is not None:
            entry = self.archive.load_command(key)
            if entry is not None:
                self.restore(entry)
        if entry is not None:
            entry.resends += 1
        return entry

    def answer_again(self, key: CommandKey) -> list[Outgoing] | None:
        """What a re-send of an answered command gets: its first answer's very bytes (counted as
        a re-send); None when ``key`` is new or still pending (the engine and a simulated unit
        then run it, the service looks further, `CommandDesk`)."""
        entry = self.seen(key)
        if entry is None or entry.state is not CommandState.DONE:
            return None
        log.debug("re-sent command %s (%s) answered again", key[1], key[0])
        return entry.answer

    def get(self, key: CommandKey) -> CommandEntry | None:
        """The entry of a command, without counting a re-send."""
        return self._entries.get(key)

    def begin(self, key: CommandKey, now: float, digest: str = "") -> CommandEntry:
        """Record a new command as pending (``digest``: its ``payload_digest``)."""
        entry = CommandEntry(key, now, digest=digest)
        self._entries[key] = entry
        if self.archive is not None:
            self.dirty.add(key)
        self._trim()
        return entry

    def forget(self, key: CommandKey) -> CommandEntry | None:
        """Drop a command begun in this step and not kept (turned away before it was accepted:
        a re-send is then a new command); its entry, if there was one."""
        self.dirty.discard(key)
        return self._entries.pop(key, None)

    def finish(self, key: CommandKey, answer: Sequence[Outgoing]) -> bool:
        """Record the answer; False if the command was already answered (nothing to send)."""
        entry = self._entries.get(key)
        if entry is None:
            entry = self.begin(key, 0.0)
        if entry.state is CommandState.DONE:
            return False
        entry.state = CommandState.DONE
        entry.answer = list(answer)
        if self.archive is not None:
            self.dirty.add(key)
        return True

    def _kept(self, key: CommandKey) -> bool:
        return self._entries[key].state is CommandState.PENDING or key in self.dirty

    def _trim(self) -> None:
        while len(self._entries) > self.capacity:
            oldest_key = next(iter(self._entries))
            if self._kept(oldest_key):
                # Never forget a command still being worked on, nor an answer not yet stored (a
                # store outage): move it to the back.
                self._entries.move_to_end(oldest_key)
                if all(self._kept(k) for k in self._entries):
                    return
                continue
            del self._entries[oldest_key]
