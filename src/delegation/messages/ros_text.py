"""What real ROS 2 publishers put in a ``std_msgs/String``, made into JSON text (pure).

SMARC's ROS 2 robots publish the seed's JSON, but not always as JSON: some ``str(dict)`` it
(single quotes, ``True``/``False``/``None``), some ``json.dumps`` a string that already was JSON
(JSON wrapped in quotes). SMARC's MQTT bridge reads all three with ``ast.literal_eval``; so do
we, here at the ROS edge, and then hand the same strict readers as on MQTT canonical JSON text
(DESIGN 3.12, docs/ros2.md). ``ast.literal_eval`` only builds literals (never calls anything),
and the text is bounded first, since parsing is not linear in every case.
"""

from __future__ import annotations

import ast
import json
import math
from typing import Any

from delegation.topics import MAX_PAYLOAD

__all__ = ["NOT_JSON", "json_text", "read_text"]

#: JSON wrapped in quotes is unwrapped at most this many times (``"\"{...}\""``).
_MAX_UNWRAP = 2


#: What `read_text` gives as the value of a text that holds no JSON value.
NOT_JSON: Any = object()


def json_text(text: str) -> str:
    """``text`` as JSON text when it is JSON, quoted JSON, or a Python literal of JSON values;
    otherwise ``text`` unchanged, so that the strict reader refuses it as it would on MQTT."""
    return read_text(text)[0]


def read_text(text: str) -> tuple[str, Any]:
    """`json_text` and the value the text holds (`NOT_JSON` when none), parsed once: a reader
    that needs the value (a heartbeat's name and type) does not parse it again."""
    # A character is at most 4 bytes: only a long text can be over (no copy for the rest).
    if len(text) > MAX_PAYLOAD // 4 and len(text.encode("utf-8", "replace")) > MAX_PAYLOAD:
        return text, NOT_JSON  # the reader refuses it unread, as on MQTT
    current = text
    for _ in range(_MAX_UNWRAP + 1):
        try:
            value = json.loads(current)
        except (ValueError, RecursionError):
            return _from_literal(text, current)
        if not isinstance(value, str):
            return current, value  # JSON (perhaps unwrapped): the strict reader decides the rest
        stripped = value.strip()
        if not stripped.startswith(("{", "[", '"')):
            return text, value  # a JSON string value, not wrapped JSON
        current = stripped
    return text, NOT_JSON


def _from_literal(text: str, current: str) -> tuple[str, Any]:
    """``current`` (``text`` perhaps unwrapped) read as a Python literal: its JSON text and value,
    or ``text`` unchanged and `NOT_JSON`."""
    literal = _literal(current)
    if literal is None:
        return text, NOT_JSON
    return literal


def _literal(text: str) -> tuple[str, Any] | None:
    """A Python literal (``{'a': True, 'b': None}``) as JSON text and value; None when it is
    none."""
    try:
        value = ast.literal_eval(text.strip())
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
        return None
    if not _json_like(value, 0):
        return None
    try:
        return json.dumps(value, separators=(",", ":"), allow_nan=False), value
    except (ValueError, TypeError, RecursionError):
        return None


def _json_like(value: Any, depth: int) -> bool:
    """Only what JSON has: dicts with string keys, lists (tuples), strings, numbers, booleans
    and None; no sets, bytes, complex numbers, NaN or infinities."""
    if depth > 64:
        return False
    if value is None or isinstance(value, bool | int | str):
        return True
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, list | tuple):
        return all(_json_like(v, depth + 1) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and _json_like(v, depth + 1) for k, v in value.items())
    return False
