"""The service's two command faces and how each one answers ``failed``.

The TST face (``tst/command``) is a drop-in delegator and answers with `TstResponse`; the
Delegation API (``delegation/command``) answers with `DelegationResponse`. Both the core and the
engine link build failures, so the one rule lives here.
"""

from __future__ import annotations

from typing import Literal

from delegation.messages import DelegationResponse, TstResponse, WireModel

Face = Literal["tst", "delegation"]


def failure(face: Face, com_uuid: str, reason: str) -> WireModel:
    """The ``failed`` answer to the command ``com_uuid`` on ``face``."""
    if face == "tst":
        return TstResponse(response="failed", response_to=com_uuid, fail_reason=reason)
    return DelegationResponse(response="failed", response_to=com_uuid, fail_reason=reason)
