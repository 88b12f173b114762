"""The base of every wire model: hyphenated JSON keys, lenient reading, canonical writing.

WARA-PS JSON uses hyphenated keys (``com-uuid``); Python attributes are snake_case and the alias
generator maps one to the other. Readers ignore extra fields (real traffic carries many); writers
emit sorted keys and leave out ``None`` fields, as the seed's own examples do.
"""

from __future__ import annotations

import os
import uuid
from collections import deque
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

#: The longest identifier a message may carry (com-uuid, node-uuid, sender, ...): a 1 MB com-uuid
#: is refused, never kept in the command log.
MAX_IDENTIFIER = 128

#: Fields holding identifiers, bounded by ``MAX_IDENTIFIER``.
IDENTIFIER_FIELDS: frozenset[str] = frozenset(
    {
        "com_uuid", "response_to", "root_uuid", "node_uuid", "task_uuid", "agent_uuid", "sender",
        "receiver", "unit", "signal", "strategy", "objective", "command", "response_topic",
        "name",
    }
)  # fmt: skip


def hyphenate(name: str) -> str:
    """``com_uuid`` -> ``com-uuid``."""
    return name.replace("_", "-")


#: Fresh uuids for `new_com_uuid`, made from the OS's random bytes 256 at a time: ``uuid4``
#: asks the kernel for each, and the thread gives up the GIL for it (in a burst, a wait of up to a
#: switch interval per message relayed; 6 % of the service's samples). A deque: ``popleft`` hands
#: each out once to whichever thread asks (no lock; two threads refilling at once is harmless).
_POOL_UUIDS = 256
_pool: deque[str] = deque()


def _fill() -> None:
    raw = os.urandom(16 * _POOL_UUIDS)
    _pool.extend(str(uuid.UUID(bytes=raw[i:i + 16], version=4))
                 for i in range(0, len(raw), 16))


os.register_at_fork(after_in_child=_pool.clear)  # a child must never hand out its parent's


def new_com_uuid() -> str:
    """A fresh communication uuid (every message we send carries a new one): a random
    (version 4) uuid of the OS's random bytes."""
    while True:
        try:
            return _pool.popleft()
        except IndexError:
            _fill()


class WireModel(BaseModel):
    """A WARA-PS JSON message or part of one."""

    model_config = ConfigDict(
        alias_generator=hyphenate,
        populate_by_name=True,
        extra="ignore",
        validate_assignment=True,
        allow_inf_nan=False,
        ser_json_inf_nan="constants",  # NaN in a raw field reaches json.dumps, which refuses it
    )

    #: Wire keys left out when they hold ``""`` or ``[]`` (the seed omits e.g. ``fail-reason`` on
    #: ``pong`` and ``tasks-executing`` when nothing runs).
    _omit_empty: ClassVar[frozenset[str]] = frozenset()

    # Bound to the identifier fields only (``"*"`` ran it for every field of every message).
    @field_validator(*sorted(IDENTIFIER_FIELDS), mode="after", check_fields=False)
    @classmethod
    def _bounded_identifier(cls, value: Any, info: ValidationInfo) -> Any:
        """Identifiers are short; checked before a decoded message is kept anywhere."""
        if isinstance(value, str) and len(value) > MAX_IDENTIFIER:
            raise ValueError(f"is {len(value)} characters long; at most {MAX_IDENTIFIER}")
        return value

    def omit_when_empty(self) -> frozenset[str]:
        """Keys to drop from the wire form when empty; subclasses refine this."""
        return self._omit_empty

    def to_wire(self) -> dict[str, Any]:
        """The canonical JSON object: hyphenated keys, no ``None`` fields."""
        data = self.model_dump(mode="json", by_alias=True, exclude_none=True)
        for key in self.omit_when_empty():
            if key in data and data[key] in ("", []):
                del data[key]
        return data


class Command(WireModel):
    """What every command carries besides its ``command`` name: a ``com-uuid`` (fresh unless
    given) that its answer names, and who sent it."""

    com_uuid: str = Field(default_factory=new_com_uuid)
    sender: str = ""


class Answer(WireModel):
    """What every response carries: its own ``com-uuid``, the command it answers, the answer,
    and why when it failed (left out where a subclass's ``omit_when_empty`` says so)."""

    com_uuid: str = Field(default_factory=new_com_uuid)
    fail_reason: str = ""
    response: str
    response_to: str
