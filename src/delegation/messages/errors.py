"""Turning bad bytes and pydantic's errors into ``MessageError`` problems that name the field."""

from __future__ import annotations

import json
import math
from typing import Any

from pydantic import ValidationError

from delegation.errors import InputProblem, MessageError, short_repr

#: JSON nested deeper than this is refused. A tree at the parser's depth limit (64 levels) nests
#: about 135 levels of JSON; pydantic refuses to serialise beyond about 250.
MAX_JSON_DEPTH = 200


def json_depth(value: Any) -> int:
    """How deeply containers nest in decoded JSON (a scalar is 0), without recursion."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            item = list(item.values())
        if isinstance(item, list):
            depth += 1
            deepest = max(deepest, depth)
            stack.extend((child, depth) for child in item if isinstance(child, dict | list))
    return deepest


class _NotFinite(ValueError):
    """A ``NaN``/``Infinity`` literal or a number beyond a float's range."""


class _Marker:
    """Stands in for a non-finite number while looking for the field that holds it."""

    __slots__ = ("text",)

    def __init__(self, text: str) -> None:
        self.text = text


def _reject_constant(name: str) -> Any:
    raise _NotFinite(f"{name} is not valid JSON")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _NotFinite(f"number {text[:20]} is out of range")
    return value


def _marked_float(text: str) -> Any:
    value = float(text)
    return value if math.isfinite(value) else _Marker(f"number {text[:20]} is out of range")


#: One decoder for every message: ``json.loads`` with hooks builds a new one per call (~1 us
#: of the ~4 us a small periodic message costs).
_DECODER = json.JSONDecoder(parse_constant=_reject_constant, parse_float=_finite_float)


def _non_finite_field(text: str) -> tuple[str, str] | None:
    """(field, reason) of the first non-finite number in ``text``, found by parsing again with
    markers (iteratively: no recursion on deep JSON)."""
    try:
        value = json.loads(
            text,
            parse_constant=lambda name: _Marker(f"{name} is not a finite number"),
            parse_float=_marked_float,
        )
    except (ValueError, RecursionError):
        return None
    stack: list[tuple[tuple[int | str, ...], Any]] = [((), value)]
    while stack:
        loc, item = stack.pop()
        if isinstance(item, _Marker):
            return loc_text(loc), item.text
        if isinstance(item, dict):
            stack.extend(((*loc, k), v) for k, v in reversed(list(item.items())))
        elif isinstance(item, list):
            stack.extend(((*loc, i), v) for i, v in reversed(list(enumerate(item))))
    return None


def json_value(
    payload: bytes | str, where: str = "message", max_depth: int | None = MAX_JSON_DEPTH
) -> Any:
    """Decode JSON text or raise ``MessageError``.

    Bad UTF-8, ``NaN``/``Infinity``, numbers beyond a float's range (``1e999``) and, unless
    ``max_depth`` is None, nesting deeper than ``max_depth`` are refused, so that every decoded
    message can be written back.
    """
    try:
        text = payload.decode("utf-8") if isinstance(payload, bytes | bytearray) else payload
        if text.startswith("\ufeff"):  # as json.loads says it
            raise json.JSONDecodeError("Unexpected UTF-8 BOM (decode using utf-8-sig)", text, 0)
        value = _DECODER.decode(text)
    except UnicodeDecodeError as exc:
        raise MessageError(
            InputProblem(where, "", f"not UTF-8 text: {exc.reason} at byte {exc.start}")
        ) from None
    except json.JSONDecodeError as exc:
        raise MessageError(
            InputProblem(
                where, "", f"invalid JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})")
        ) from None
    except RecursionError:
        raise MessageError(InputProblem(where, "", "invalid JSON: nested too deeply")) from None
    except _NotFinite as exc:  # NaN/Infinity/1e999: name the field that holds it
        found = _non_finite_field(text)
        field, reason = found if found is not None else ("", str(exc))
        raise MessageError(InputProblem(where, field, f"invalid JSON: {reason}")) from None
    except ValueError as exc:  # integers too long to convert
        raise MessageError(InputProblem(where, "", f"invalid JSON: {exc}")) from None
    # Nesting needs an opening bracket per level: text with few of them is not walked.
    if max_depth is not None and text.count("[") + text.count("{") > max_depth \
            and json_depth(value) > max_depth:
        raise MessageError(InputProblem(where, "", f"JSON nested deeper than {max_depth} levels"))
    return value


def loc_text(loc: tuple[int | str, ...]) -> str:
    """``("task", "params", 2)`` -> ``task.params[2]``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def validation_problems(exc: ValidationError, where: str) -> list[InputProblem]:
    """One problem per pydantic error, naming the field by its wire (hyphenated) name."""
    problems: list[InputProblem] = []
    for err in exc.errors(include_url=False):
        # Drop pydantic's internal loc parts (union member names, validator tags).
        loc = tuple(
            p for p in err["loc"] if isinstance(p, int) or not str(p).startswith("function-")
        )
        field = loc_text(loc)
        if err["type"] == "missing":
            message = "missing"
        elif err["type"] == "extra_forbidden":
            message = "unknown field"
        else:
            message = f"{err['msg']}, got {short_repr(err.get('input'))}"
        problems.append(InputProblem(where, field, message))
    return problems
