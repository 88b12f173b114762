"""The service's side of its conversation with the TST engine (pure: ``now`` is passed in).

The service sends the engine three kinds of command for a caller: a ``start-tst`` with the
instantiated tree, a forwarded signal, and the ``$abort`` of a cancelled mission; and for itself
``query-tst`` (docs/protocol.md §12.5): catching up on a tree after a restart or an outage
(``query``), or finding out whether a ``start-tst`` whose answer never came started the tree after
all (``confirm``). Each waits here, by the engine command's com-uuid, until the engine answers or
its timeout passes. What the answer (or the silence) means for the caller comes back as an
`EngineAnswer`; the core publishes it and moves the mission on, since the mission book and the
command log are the core's.

The com-uuid of a ``start-tst`` is derived from the command it serves (`start_command_uuid`):
the unfinished part of a tree sent again to a restarted engine carries the same com-uuid, so the
engine derives the same start-task ids and units answer again what they already run.
"""

from __future__ import annotations

import logging
import uuid
from collections import Counter, OrderedDict
from dataclasses import dataclass
from typing import Any, Literal

from delegation.errors import InputError, InputProblem, MessageError
from delegation.fleet import FleetRegistry
from delegation.messages import (
    DelegationResponse,
    MissionStatus,
    StartTst,
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

RequestKind = Literal["start", "signal", "cancel", "rebind", "query", "confirm"]
#: Requests during which a mission counts as starting (`EngineLink.starting`).
STARTING = frozenset({"start", "confirm"})

#: How many trees' engine topics are remembered (feedback for older ones is ignored).
MAX_TREES = 10_000
#: The `CommandKey` face of the service's own engine commands (re-delegation, catching up):
#: never answered to anyone.
INTERNAL = "internal"
#: The uuid5 namespace of ``start-tst`` com-uuids (`start_command_uuid`).
START_NAMESPACE = uuid.UUID("0b6f5c1e-3d47-4c8e-a0f4-6a3c2e9d7b15")


def start_command_uuid(service: str, key: CommandKey, mission: str) -> str:
    """The com-uuid of the ``start-tst`` that serves the command ``key`` (a caller's command, or
    the service's own ``(internal, <root>#start)`` of a re-delegated tree) for the mission
    ``mission`` of the service named ``service``: the same for every sending of that tree, so that
    a restarted engine given it again derives the same start-task ids (docs/protocol.md §12.5);
    another service, command or mission never gets it (the engine would take it for a re-send)."""
    return str(uuid.uuid5(START_NAMESPACE, f"{service}/{key[0]}/{key[1]}/{mission}"))


def tree_root(tst: dict[str, Any]) -> str:
    """The root node uuid of a tree as JSON (either spelling of ``common_params``)."""
    common = tst.get("common_params") or tst.get("common-params") or {}
    uid = common.get("node-uuid") if isinstance(common, dict) else None
    return uid if isinstance(uid, str) else ""


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
    #: The root uuid of the tree a ``start-tst`` sent (or a ``query-tst`` asks about).
    tree: str = ""

    @property
    def caller_com_uuid(self) -> str:
        """The com-uuid of the caller's command, which the engine's answer completes."""
        return self.key[1]


@dataclass(frozen=True, slots=True)
class EngineAnswer:
    """What the engine's answer (or its silence) means: the caller's answer, and the mission's
    new status (set before the answer goes out) if it changes."""

    request: EngineRequest
    #: The caller's answer (None: nobody to answer yet, see ``confirm``, or a query).
    answer: WireModel | None
    mission_status: MissionStatus | None = None
    fail_reason: str = ""
    #: The engine's own answer (a ``query-tst``'s ``nodes``); None when it did not answer.
    response: TstResponse | None = None
    #: A ``start-tst`` went unanswered: ask the engine whether it runs the tree (``confirm``).
    confirm: bool = False
    #: The tree may run on the engine although the mission failed: ``$abort`` it.
    abort: bool = False
    #: The engine started the tree holding failed tasks for a rebind (``hold-failed``, §12.7).
    holds: bool = False


class EngineLink:
    """Commands to the engine, waiting for their answers (``pending``, by engine com-uuid)."""

    def __init__(self, config: ServiceConfig, fleet: FleetRegistry) -> None:
        self.config = config
        self.fleet = fleet
        self.pending: dict[str, EngineRequest] = {}
        #: Root uuid -> how many ``start``/``confirm`` requests of it are pending: `starting` is
        #: asked for every open mission per plan (a scan of ``pending`` each was quadratic).
        self._starting: Counter[str] = Counter()
        #: Counts changes of `starting` (see `MissionBook.revision`).
        self.revision = 0
        #: Missions whose `starting` changed since `FleetView` last read them (it empties it).
        self.touched: set[str] = set()
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
        """True while a ``start-tst`` of this mission waits for the engine (or, unanswered, the
        engine is asked whether it runs the tree)."""
        return self._starting[root_uuid] > 0

    def _await(self, com: str, request: EngineRequest) -> None:
        """Wait for the answer to ``com`` (a re-used com-uuid replaces its older request)."""
        self._forget(com)
        self.pending[com] = request
        if request.kind in STARTING:
            self._starting[request.root_uuid] += 1
            self.revision += 1
            self.touched.add(request.root_uuid)

    def _forget(self, com: str) -> EngineRequest | None:
        """Stop waiting for the answer to ``com``; the request, if one waited."""
        request = self.pending.pop(com, None)
        if request is not None and request.kind in STARTING:
            self.revision += 1
            self.touched.add(request.root_uuid)
            self._starting[request.root_uuid] -= 1
            if self._starting[request.root_uuid] <= 0:
                del self._starting[request.root_uuid]
        return request

    def send(
        self,
        kind: RequestKind,
        key: CommandKey,
        face: Face,
        model: WireModel,
        now: float,
        root_uuid: str = "",
        plan: dict[str, Any] | None = None,
        tree: str = "",
        com: str = "",
    ) -> Outgoing:
        """The command to publish; its answer is awaited. ``InputError`` if no engine is live.

        A ``start-tst`` gets the com-uuid `start_command_uuid` derives from ``key`` (or ``com``:
        the unfinished part of a tree re-sent under its first com-uuid)."""
        base = self.base(now)
        if base is None:
            raise InputError(InputProblem("engine", "", self.problem(now) or "no engine"))
        if isinstance(model, StartTst):
            com = com or start_command_uuid(self.config.name, key, root_uuid)
            model = model.model_copy(update={"com_uuid": com})
            tree = tree or tree_root(model.tst)
        com = getattr(model, "com_uuid", "") or new_com_uuid()
        wait = (self.config.catch_up_timeout if kind == "query" else self.config.engine_timeout)
        self._await(com, EngineRequest(kind, key, face, now + wait, root_uuid, plan, base, tree))
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
            self._forget(message.response_to)
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
            self._forget(com)
            if req.kind == "query":  # asked again by the catch-up, or given up there
                expired.append(EngineAnswer(req, None))
            elif req.kind == "start" and req.tree:  # ask rather than assume it did not start
                expired.append(EngineAnswer(req, None, confirm=True))
            elif req.kind == "confirm":
                why = (f"{reason}, nor said whether it runs the tree {req.tree}: "
                       "$abort sent to it in case it does")
                expired.append(EngineAnswer(req, failure(req.face, req.caller_com_uuid, why),
                                            MissionStatus.FAILED, why, abort=True))
            else:
                status = MissionStatus.FAILED if req.kind == "start" else None
                expired.append(EngineAnswer(req, failure(req.face, req.caller_com_uuid, reason),
                                            status, reason))
        return expired

    def _answer(self, req: EngineRequest, resp: TstResponse) -> EngineAnswer:
        engine, caller = self.config.engine, req.caller_com_uuid
        if req.kind == "query":
            return EngineAnswer(req, None, response=resp)
        if req.kind == "confirm":
            return self._confirmed(req, resp)
        if req.kind == "start":
            if resp.response == "started":
                return EngineAnswer(req, self._started(req), MissionStatus.STARTED,
                                    holds=bool(resp.hold_failed))
            reason = f"engine {engine} refused the tree: {resp.fail_reason or resp.response}"
            return EngineAnswer(req, failure(req.face, caller, reason), MissionStatus.FAILED,
                                reason)
        if req.kind == "cancel":
            if resp.response == "ok":
                return EngineAnswer(req, DelegationResponse(response="ok", response_to=caller))
            reason = f"engine {engine} did not abort: {resp.fail_reason or resp.response}"
            return EngineAnswer(req, failure(req.face, caller, reason))
        return self._passed_on(req, resp)

    def _started(self, req: EngineRequest) -> WireModel:
        """The caller's answer to a mission started."""
        if req.face == "tst":
            return TstResponse(response="started", response_to=req.caller_com_uuid,
                               root_uuid=req.root_uuid)
        return DelegationResponse(response="started", response_to=req.caller_com_uuid,
                                  plan=req.plan)

    def _confirmed(self, req: EngineRequest, resp: TstResponse) -> EngineAnswer:
        """The engine's answer to ``query-tst`` about a tree whose ``start-tst`` went unanswered:
        it runs the tree (the mission started, its statuses are applied), it does not know it
        (not started: the mission fails), or it cannot say (the mission fails, ``$abort``)."""
        engine, caller = self.config.engine, req.caller_com_uuid
        silent = f"engine {engine} did not answer start-tst within {self.config.engine_timeout:g} s"
        if resp.response == "ok":
            return EngineAnswer(req, self._started(req), MissionStatus.STARTED, response=resp)
        if resp.response == "unknown":
            why = f"{silent}, and does not know the tree: it was not started"
            return EngineAnswer(req, failure(req.face, caller, why), MissionStatus.FAILED, why)
        why = (f"{silent}, nor said whether it runs the tree ({resp.fail_reason or resp.response})"
               ": $abort sent to it in case it does")
        return EngineAnswer(req, failure(req.face, caller, why), MissionStatus.FAILED, why,
                            abort=True)

    def _passed_on(self, req: EngineRequest, resp: TstResponse) -> EngineAnswer:
        """A forwarded signal: the engine's answer passed on."""
        engine, caller = self.config.engine, req.caller_com_uuid
        if resp.response == "failed":
            return EngineAnswer(req, failure(req.face, caller, f"engine {engine}: "
                                                               f"{resp.fail_reason}"))
        return EngineAnswer(req, TstResponse(response=resp.response, response_to=caller))

