"""One exception family for the project, and the `InputProblem` value every validator reports.

Expected failures inside the planner are values (see ``allocation``); exceptions are for input that
cannot be understood at all, and each carries the problems found so callers can name node and field.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


def short_repr(value: Any) -> str:
    """``repr`` cut to a readable length, for quoting a bad value in a problem's message."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def json_kind(value: Any) -> str:
    """What a decoded JSON value is, for messages: ``an object``, ``a list``, ``null`` ..."""
    if value is None:
        return "null"
    return {
        dict: "an object",
        list: "a list",
        str: "a string",
        bool: "a boolean",
        int: "a number",
        float: "a number",
    }.get(type(value), type(value).__name__)


@dataclass(frozen=True, slots=True)
class InputProblem:
    """One thing wrong with an input: where (node path or uuid), which field, and what."""

    where: str
    field: str
    message: str

    def __str__(self) -> str:
        if self.field:
            return f"{self.where}: {self.field}: {self.message}"
        return f"{self.where}: {self.message}"


class DelegationError(Exception):
    """Base of every exception this package raises on purpose."""


class InputError(DelegationError):
    """Input (JSON, a tree, a command, a scenario) that cannot be accepted, with every problem."""

    def __init__(self, problems: list[InputProblem] | InputProblem | str) -> None:
        if isinstance(problems, str):
            problems = [InputProblem("input", "", problems)]
        elif isinstance(problems, InputProblem):
            problems = [problems]
        self.problems: list[InputProblem] = list(problems)
        super().__init__("; ".join(str(p) for p in self.problems))

    @property
    def fail_reason(self) -> str:
        """The text that goes into a response's ``fail-reason``."""
        return str(self)


class MessageError(InputError):
    """A message (bytes from a topic, or a command file) that is not valid JSON or not a known
    message of the WARA-PS APIs; ``problems`` say which field is wrong."""
