"""The service's side of its conversation with the TST engine (pure: ``now`` is passed in).

The service sends the engine three kinds of command for a caller: a ``start-tst`` with the
instantiated tree, a forwarded signal, and the ``$abort`` of a cancelled mission. Each waits here,
by the engine command's com-uuid, until the engine answers or ``engine_timeout`` passes. What the
answer (or the silence) means for the caller comes back as an `EngineAnswer`; the core publishes
it and moves the mission on, since the mission book and the command log are the core's.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Literal

from delegation.errors import InputError, InputProblem, MessageError
from delegation.fleet import FleetRegistry
from delegation.messages import (
    DelegationResponse,
    MissionStatus,
    TstFeedback,
    TstResponse,
    WireModel,
    decode,
    new_com_uuid,
)
from delegation.runtime.commands import CommandKey
from delegation.runtime.core import Outgoing
from delegation.service.config import ServiceConfig
from delegation.service.faces import Face, failure

log = logging.getLogger(__name__)

RequestKind = Literal["start", "signal", "cancel", "rebind"]

#: How many trees' engine topics are remembered (feedback for older ones is ignored).
MAX_TREES = 10_000


@dataclass(frozen=True, slots=True)
class EngineRequest:
    """A command the service sent to the engine and whose answer a caller is waiting for."""

    kind: RequestKind
    key: CommandKey
    face: Face
    deadline: float
    root_uuid: str = ""
    plan: dict[str, Any] | None = None
    #: The engine base topic the command went to: only an answer from there counts.
    base: str = ""

    @property
    def caller_com_uuid(self) -> str:
        """The com-uuid of the caller's command, which the engine's answer completes."""
        return self.key[1]


@dataclass(frozen=True, slots=True)
class EngineAnswer:
    """What the engine's answer (or its silence) means: the caller's answer, and the mission's
    new status (set before the answer goes out) if it changes."""

    request: EngineRequest
    answer: WireModel
    mission_status: MissionStatus | None = None
    fail_reason: str = ""


class EngineLink:
    """Commands to the engine, waiting for their answers (``pending``, by engine com-uuid)."""

    def __init__(self, config: ServiceConfig, fleet: FleetRegistry) -> None:
        self.config = config
        self.fleet = fleet
        self.pending: dict[str, EngineRequest] = {}
        #: Root uuid -> the engine base topic its tree was sent to (bounded, oldest forgotten).
        self.sent_to: OrderedDict[str, str] = OrderedDict()

    def subscriptions(self) -> list[str]:
        """The engine's answers and feedback, wherever its heartbeat says it lives."""
        p, e = self.config.prefix, self.config.engine
        return [f"{p}/unit/+/+/{e}/tst/response", f"{p}/unit/+/+/{e}/tst/feedback"]

    def base(self, now: float) -> str | None:
        """The engine's base topic (from its heartbeat) while the heartbeat is fresh, else None."""
        if not self.fleet.is_alive(self.config.engine, now):
            return None
        return self.fleet.base_topic(self.config.engine)

    def problem(self, now: float) -> str | None:
        """Why nothing can be sent to the engine now, or None."""
        if self.base(now) is None:
            return (
                f"no TST engine {self.config.engine!r} is live on the broker "
                f"(no recent heartbeat under {self.config.prefix}/unit/+/+/{self.config.engine})"
            )
        return None

    def starting(self, root_uuid: str) -> bool:
        """True while a ``start-tst`` of this mission waits for the engine."""
        return any(r.kind == "start" and r.root_uuid == root_uuid for r in self.pending.values())

    def send(
        self,
        kind: RequestKind,
        key: CommandKey,
        face: Face,
        model: WireModel,
        now: float,
        root_uuid: str = "",
        plan: dict[str, Any] | None = None,
    ) -> Outgoing:
        """The command to publish; its answer is awaited. ``InputError`` if no engine is live."""
        base = self.base(now)
        if base is None:
            raise InputError(InputProblem("engine", "", self.problem(now) or "no engine"))
        com = getattr(model, "com_uuid", "") or new_com_uuid()
        self.pending[com] = EngineRequest(kind, key, face, now + self.config.engine_timeout,
                                          root_uuid, plan, base)
        if kind == "start" and root_uuid:
            self.sent_to[root_uuid] = base
            self.sent_to.move_to_end(root_uuid)
            while len(self.sent_to) > MAX_TREES:
                self.sent_to.popitem(last=False)
        return Outgoing.of(f"{base}/tst/command", model)

    def sent_from(self, root_uuid: str, topic: str, bound: str | None = None) -> bool:
        """True when ``topic`` lies under the engine base the tree ``root_uuid`` was sent to
        (feedback from any other engine topic is an impostor's). A tree sent before a restart
        has no record here: then the engine's base as the fleet registry bound it (``bound``)
        is the one to trust."""
        base = self.sent_to.get(root_uuid) or bound
        return base is not None and topic.startswith(base + "/")

    def receive(self, topic: str, payload: bytes) -> TstFeedback | EngineAnswer | None:
        """One message from the engine: feedback (for the mission book), the answer to a waiting
        command, or None (unreadable, or an answer to someone else)."""
        try:
            message = decode(topic, payload)
        except MessageError as exc:
            log.warning("unreadable message from the engine on %s: %s", topic, exc)
            return None
        if isinstance(message, TstFeedback):
            return message
        if isinstance(message, TstResponse):
            req = self.pending.get(message.response_to)
            if req is None:
                return None
            if req.base and not topic.startswith(req.base + "/"):
                log.warning("ignoring an answer on %s: the command went to %s", topic, req.base)
                return None
            del self.pending[message.response_to]
            return self._answer(req, message)
        return None

    def expire(self, now: float) -> list[EngineAnswer]:
        """Commands the engine did not answer in time, each answered ``failed`` (once)."""
        reason = (f"engine {self.config.engine} did not answer within "
                  f"{self.config.engine_timeout:g} s")
        expired: list[EngineAnswer] = []
        for com, req in list(self.pending.items()):
            if now < req.deadline:
                continue
            del self.pending[com]
            status = MissionStatus.FAILED if req.kind == "start" else None
            expired.append(EngineAnswer(req, failure(req.face, req.caller_com_uuid, reason),
                                        status, reason))
        return expired

    def _answer(self, req: EngineRequest, resp: TstResponse) -> EngineAnswer:
        engine, caller = self.config.engine, req.caller_com_uuid
        if req.kind == "start":
            if resp.response == "started":
                answer: WireModel
                if req.face == "tst":
                    answer = TstResponse(response="started", response_to=caller,
                                         root_uuid=req.root_uuid)
                else:
                    answer = DelegationResponse(response="started", response_to=caller,
                                                plan=req.plan)
                return EngineAnswer(req, answer, MissionStatus.STARTED)
            reason = f"engine {engine} refused the tree: {resp.fail_reason or resp.response}"
            return EngineAnswer(req, failure(req.face, caller, reason), MissionStatus.FAILED,
                                reason)
        if req.kind == "cancel":
            if resp.response == "ok":
                return EngineAnswer(req, DelegationResponse(response="ok", response_to=caller))
            reason = f"engine {engine} did not abort: {resp.fail_reason or resp.response}"
            return EngineAnswer(req, failure(req.face, caller, reason))
        # a forwarded signal: pass the engine's answer on
        if resp.response == "failed":
            return EngineAnswer(req, failure(req.face, caller, f"engine {engine}: "
                                                               f"{resp.fail_reason}"))
        return EngineAnswer(req, TstResponse(response=resp.response, response_to=caller))

