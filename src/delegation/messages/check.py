"""Check a document a user hands us: a TST, or any WARA-PS message (``delegation validate``).

Returns every problem found rather than raising, so the CLI can print one line per problem. A
command carrying a tree (``start-tst``, ``delegate``, ``get-bids``) has its tree checked too, and a
``start-task`` its task against the catalogue.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from delegation.errors import InputError, InputProblem
from delegation.messages.base import WireModel
from delegation.messages.codec import parse_message
from delegation.messages.direct import StartTask
from delegation.messages.errors import json_value
from delegation.tst.catalogue import CATALOGUE
from delegation.tst.node import TstNode, leaves, walk
from delegation.tst.validate import param_problems, parse_and_validate

#: Commands whose ``tst`` field is a tree to validate.
TREE_COMMANDS: frozenset[str] = frozenset({"start-tst", "delegate", "get-bids"})


@dataclass(slots=True)
class CheckResult:
    """What a document is (``kind``), a one-line summary when valid, and its problems."""

    kind: str
    problems: list[InputProblem] = field(default_factory=list)
    summary: str = ""
    message: WireModel | None = None
    tree: TstNode | None = None

    @property
    def ok(self) -> bool:
        return not self.problems


def _tree_summary(tree: TstNode) -> str:
    nodes = sum(1 for _ in walk(tree))
    tasks = len(leaves(tree))
    return f"{nodes} node{'s' if nodes != 1 else ''}, {tasks} task{'s' if tasks != 1 else ''}"


def _check_tree(data: Any, result: CheckResult) -> None:
    try:
        result.tree = parse_and_validate(data)
    except InputError as exc:
        result.problems.extend(exc.problems)


def _check_task(message: StartTask, result: CheckResult) -> None:
    spec = CATALOGUE.get(message.task.name)
    if spec is None:
        result.problems.append(
            InputProblem("start-task", "task.name", f"unknown task {message.task.name!r}")
        )
        return
    result.problems.extend(
        InputProblem(
            "start-task", f"task.{f}", m) for f, m in param_problems(spec, message.task.params)
    )


def _looks_like_message(data: dict[str, Any]) -> bool:
    return any(k in data for k in ("command", "response", "status", "type", "com-uuid"))


def check_data(data: Any) -> CheckResult:
    """Check decoded JSON: a command or other message if it looks like one, else a TST."""
    if not isinstance(data, dict) or not _looks_like_message(data):
        result = CheckResult(kind="tst")
        _check_tree(data, result)
        if result.tree is not None:
            result.summary = f"TST, {_tree_summary(result.tree)}"
        return result

    name = data.get("command")
    result = CheckResult(kind=f"{name} command" if isinstance(name, str) else "message")
    try:
        result.message = parse_message(data)
    except InputError as exc:
        result.problems.extend(exc.problems)
    # Check the tree even when the command's other fields are wrong: report everything.
    if isinstance(name, str) and name in TREE_COMMANDS and isinstance(data.get("tst"), dict):
        _check_tree(data["tst"], result)
    if isinstance(result.message, StartTask):
        _check_task(result.message, result)
    if not result.problems:
        if result.message is not None and not isinstance(name, str):
            result.kind = f"{type(result.message).__name__} message"
        result.summary = result.kind
        if result.tree is not None:
            result.summary += f" with a TST of {_tree_summary(result.tree)}"
    return result


def check_bytes(payload: bytes, source: str = "input") -> CheckResult:
    """Check raw bytes (a file's content): invalid JSON is a problem like any other."""
    try:
        # No nesting limit here: the tree parser names the node where a tree gets too deep.
        data = json_value(payload, source, max_depth=None)
    except InputError as exc:
        return CheckResult(kind="json", problems=list(exc.problems))
    return check_data(data)
