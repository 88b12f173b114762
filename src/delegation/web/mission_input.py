"""A mission as the page sends it: JSON or YAML text, or an object (pure).

Reads exactly what ``delegation submit`` reads, through the same `tree_in`: a TST, a scenario
(its ``mission``) or a start-tst/delegate command (its ``tst``). The tree is validated here so that
bad input is a 400 naming the node and field before anything reaches the service.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
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
    tree = tree_in(data, "mission")
    parse_and_validate(tree)
    return tree


def tree_in(document: Mapping[str, Any], where: str) -> dict[str, Any]:
    """The TST a mission document holds: a scenario's ``mission``, a start-tst/delegate
    command's ``tst``, or the document itself; `InputError` at ``where`` when it holds none.
    Not validated (the callers do, once)."""
    data: Any = document
    if "mission" in document and "agents" in document:
        data = document["mission"]
    elif "tst" in document and "command" in document:
        data = document["tst"]
    if not isinstance(data, dict) or "name" not in data:
        raise InputError(InputProblem(
            where, "", "no TST found (expected a tree, a scenario or a start-tst/delegate "
            "command)"))
    return data


def with_node_uuids(tree: dict[str, Any]) -> dict[str, Any]:
    """The tree with a uuid on every node (the caller's kept), so the page knows the operator's
    tree by uuid before the service answers."""
    return to_dict(with_uuids(parse_tree(tree)))
