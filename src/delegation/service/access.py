"""Who is asking, where the answer goes, and who may touch a mission (docs/security.md; pure).

A caller is named, most trusted first, by the per-client command topic it published on
(``<base>/delegation/command/<client>``: with the shipped mosquitto ACL, ``<client>`` is the
broker-authenticated username), else by the command's ``sender``, else by the client level of its
``response-topic``; a command with none of these is anonymous. A mission belongs to whoever
created it; only its owner and the configured operators may query, cancel or signal it. A mission
created anonymously stays open to everyone (as before owners existed).

Answers go to the caller's own response topic when it has one (``response-topic``, which must be
``<base>/<api>/response/<client>``, or the per-client topic's counterpart), else to the shared
``<base>/<api>/response``.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any

from delegation.errors import InputError, InputProblem

#: A client level: one topic level of plain characters (no wildcards, no ``/``).
CLIENT_NAME = re.compile(r"[A-Za-z0-9_.-]{1,64}")


@dataclass(frozen=True, slots=True)
class Caller:
    """The name a command is accounted to ("" for anonymous) and where its answer goes ("" for
    the face's shared response topic)."""

    name: str = ""
    reply_topic: str = ""


def client_of(topic: str, command_topic: str) -> str | None:
    """``alice`` for ``<command_topic>/alice``; None for any other topic."""
    if not topic.startswith(command_topic + "/"):
        return None
    client = topic[len(command_topic) + 1 :]
    return client if CLIENT_NAME.fullmatch(client) else None


def caller_of(
    command: str, data: Mapping[str, Any] | None, client: str | None, response_base: str
) -> Caller:
    """The caller of a command (decoded JSON ``data``, or None when unreadable) that arrived on a
    per-client topic of ``client`` (or the shared one); ``InputError`` naming ``response-topic``
    when it is not ``<response_base>/<client>``."""
    own_topic = f"{response_base}/{client}" if client else ""
    raw = data.get("response-topic") if data is not None else None
    reply = own_topic
    named = ""
    if raw is not None:
        match = None
        if isinstance(raw, str) and raw.startswith(response_base + "/"):
            match = CLIENT_NAME.fullmatch(raw[len(response_base) + 1 :])
        if match is None:
            raise InputError(
                InputProblem(
                    command,
                    "response-topic",
                    f"must be {response_base}/<client> (one level of letters, "
                    f"digits, '_', '.', '-'), not {str(raw)[:80]!r}",
                )
            )
        if own_topic and raw != own_topic:
            raise InputError(
                InputProblem(
                    command, "response-topic", f"{client!r} may only be answered on {own_topic}"
                )
            )
        reply, named = raw, match.group(0)
    sender = data.get("sender") if data is not None else None
    if client:
        name = client
    elif isinstance(sender, str) and sender:
        name = sender
    else:
        name = named
    return Caller(name=name, reply_topic=reply)


def may_manage(owner: str, caller: str, operators: Collection[str]) -> bool:
    """True when ``caller`` may query, cancel or signal a mission of ``owner``."""
    return not owner or caller == owner or caller in operators


def refusal(command: str, root_uuid: str, owner: str, caller: str) -> InputError:
    """The answer to a caller touching someone else's mission."""
    who = repr(caller) if caller else "an anonymous caller"
    return InputError(
        InputProblem(
            command,
            "sender",
            f"mission {root_uuid} belongs to {owner!r}; {who} is neither its "
            "owner nor an operator of this service",
        )
    )
