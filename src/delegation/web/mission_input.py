"""A mission as the page sends it: JSON or YAML text, or an object (pure).

Reads exactly what ``delegation submit`` reads: a TST, a scenario (its ``mission``) or a
start-tst/delegate command (its ``tst``). The tree is validated here so that bad input is a 400
naming the node and field before anything reaches the service.
"""

from __future__ import annotations

import json
from typing import Any

import yaml

from delegation.errors import InputError, InputProblem
from delegation.safe_yaml import load_yaml
from delegation.topics import MAX_PAYLOAD
from delegation.tst.node import parse_tree, to_dict, with_uuids
from delegation.tst.validate import parse_and_validate

#: Characters of mission text accepted: what fits in one command to the service.
MAX_TEXT = MAX_PAYLOAD


def _document(text: str) -> Any:
    if len(text) > MAX_TEXT:
        raise InputError(InputProblem("mission", "", f"longer than {MAX_TEXT} characters"))
    try:
        return json.loads(text)
    except RecursionError:
        raise InputError(InputProblem("mission", "", "nested too deeply")) from None
    except ValueError:
        pass
    try:
        return load_yaml(text)
    except yaml.YAMLError as exc:
        line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(InputProblem("mission", "", f"neither JSON nor YAML: {line}")) from None


def mission_tree(value: Any) -> dict[str, Any]:
    """The validated TST (JSON form) in mission text or an object; `InputError` otherwise."""
    data = _document(value) if isinstance(value, str) else value
    if not isinstance(data, dict):
        raise InputError(InputProblem(
            "mission", "", "must be a JSON/YAML object (a TST, a scenario "
            "or a start-tst/delegate command)"))
    if "mission" in data and "agents" in data:
        data = data["mission"]
    elif "tst" in data and "command" in data:
        data = data["tst"]
    if not isinstance(data, dict) or "name" not in data:
        raise InputError(InputProblem(
            "mission", "", "no TST found (expected a tree, a scenario or a "
            "start-tst/delegate command)"))
    parse_and_validate(data)
    return data


def with_node_uuids(tree: dict[str, Any]) -> dict[str, Any]:
    """The tree with a uuid on every node (the caller's kept), so the page knows the operator's
    tree by uuid before the service answers."""
    return to_dict(with_uuids(parse_tree(tree)))
