"""Answers remembered per ``com-uuid``, so a re-sent command is answered again, never re-run.

The seed's protocol: unreliable links are handled by re-sending a command with the same com-uuid
until a response arrives. Every unit that answers commands (simulated units, the engine) keeps one
of these.
"""

from __future__ import annotations

import json
from collections import OrderedDict

#: How many answers a unit remembers (oldest forgotten first).
DEFAULT_HISTORY = 2000


def com_uuid_of(payload: bytes) -> str | None:
    """The ``com-uuid`` of a raw command, if it is JSON with a string one (no validation)."""
    try:
        raw = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    value = raw.get("com-uuid") if isinstance(raw, dict) else None
    return value if isinstance(value, str) and value else None


class AnswerCache:
    """A bounded map com-uuid -> the encoded answer that was sent."""

    def __init__(self, limit: int = DEFAULT_HISTORY) -> None:
        self.limit = limit
        self._answers: OrderedDict[str, bytes] = OrderedDict()

    def get(self, com_uuid: str | None) -> bytes | None:
        """The answer already given to ``com_uuid``, or None."""
        return self._answers.get(com_uuid) if com_uuid else None

    def put(self, com_uuid: str, answer: bytes) -> None:
        """Remember ``answer``; forget the oldest beyond the limit."""
        if not com_uuid:
            return
        self._answers[com_uuid] = answer
        self._answers.move_to_end(com_uuid)
        while len(self._answers) > self.limit:
            self._answers.popitem(last=False)

    def __len__(self) -> int:
        return len(self._answers)
