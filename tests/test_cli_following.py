"""How the CLI reads a started mission's id from the service's plan (`cli.following.mission_id`),
whichever spelling of the common params the operator's tree used."""

from __future__ import annotations

from typing import Any

import pytest

from delegation.cli.following import mission_id
from delegation.errors import DelegationError

CASES: list[tuple[dict[str, Any], str | None]] = [
    ({"tst": {"name": "seq", "common_params": {"node-uuid": "r1"}}}, "r1"),
    ({"tst": {"name": "seq", "common-params": {"node-uuid": "r2"}}}, "r2"),  # the seed's 11.1
    ({"tst": {"name": "seq", "common-params": {"execunit": "*"}}}, None),
    ({"tst": {"name": "seq"}}, None),
    ({}, None),
]


@pytest.mark.parametrize(("plan", "expected"), CASES)
def test_mission_id_under_either_spelling(plan: dict[str, Any], expected: str | None) -> None:
    if expected is None:
        with pytest.raises(DelegationError, match="names no root node-uuid"):
            mission_id(plan)
    else:
        assert mission_id(plan) == expected
