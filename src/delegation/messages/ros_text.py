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

__all__ = ["json_text"]

#: JSON wrapped in quotes is unwrapped at most this many times (``"\"{...}\""``).
_MAX_UNWRAP = 2


def json_text(text: str) -> str:
    """``text`` as JSON text when it is JSON, quoted JSON, or a Python literal of JSON values;
    otherwise ``text`` unchanged, so that the strict reader refuses it as it would on MQTT."""
    if len(text.encode("utf-8", errors="replace")) > MAX_PAYLOAD:
        return text  # the reader refuses it unread, as on MQTT
    current = text
    for _ in range(_MAX_UNWRAP + 1):
        try:
            value = json.loads(current)
        except (ValueError, RecursionError):
            literal = _from_literal(current)
            return text if literal is None else literal
        if not isinstance(value, str):
            return current  # JSON (perhaps unwrapped): the strict reader decides the rest
        stripped = value.strip()
        if not stripped.startswith(("{", "[", '"')):
            return text  # a JSON string value, not wrapped JSON
        current = stripped
    return text


def _from_literal(text: str) -> str | None:
    """A Python literal (``{'a': True, 'b': None}``) as JSON text; None when it is none."""
    try:
        value = ast.literal_eval(text.strip())
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
        return None
    if not _json_like(value, 0):
        return None
    try:
        return json.dumps(value, separators=(",", ":"), allow_nan=False)
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
