"""The offer round (docs/protocol.md §15.2): before a plan, other delegators are asked for offers
on the subtrees they could take, and the planning job waits for them at most ``bid_window`` s.

Pure (``now`` is passed in): a round is opened with the job it holds, and moves on with the
answers that arrive (`OfferDesk.receive`) and with ticks (`OfferDesk.expire`); each returns the
jobs whose round is over, carrying the offers and notes on those who refused or stayed silent.
Nothing blocks: the service goes on answering pings, feedback and other commands meanwhile.

An offer request is a plan-only ``delegate`` (``preview: true``) of one subtree, sent on the
delegator's per-client command topic (``<its base>/delegation/command/<our name>``), so that its
answer comes back on ``<its base>/delegation/response/<our name>`` to us alone. A command whose
caller is itself a delegator is planned with the own fleet only: offers are not asked for the
subtree someone else is asking us about, nor for a subtree another delegator's engine hands us
(its caller is a unit on the ``tst execution`` level): no rounds within rounds, no loops between
partners.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field, replace

from delegation.errors import MessageError
from delegation.fleet import Delegator, FleetRegistry
from delegation.messages import Delegate, DelegationResponse, new_com_uuid
from delegation.messages.codec import validate_model
from delegation.messages.errors import json_value
from delegation.runtime.core import Effects, Outgoing
from delegation.service.config import ServiceConfig
from delegation.service.federated import Offer, offer_asks
from delegation.service.jobs import Job
from delegation.topics import parse_unit_topic
from delegation.tst.node import TstNode, to_dict

log = logging.getLogger(__name__)

#: The share of the bid window a delegator may spend planning its offer (the rest is the trip).
PLANNING_SHARE = 0.5


@dataclass(frozen=True, slots=True)
class OfferRequest:
    """One subtree asked of one delegator (by the request's com-uuid): one child of the root,
    or a bundle of them under a new ``conc`` (``covers``: the children's uuids)."""

    com_uuid: str
    delegator: str
    base: str
    path: str
    subtree: TstNode
    covers: tuple[str, ...]


@dataclass(slots=True)
class OfferRound:
    """The offers one planning job waits for."""

    job: Job
    opened: float
    deadline: float
    waiting: dict[str, OfferRequest]
    offers: list[Offer] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


class OfferDesk:
    """Opens offer rounds for planning jobs and closes them on answers or at their deadline."""

    def __init__(self, config: ServiceConfig, fleet: FleetRegistry) -> None:
        self.config = config
        self.fleet = fleet
        self.rounds: dict[int, OfferRound] = {}
        self._by_com: dict[str, int] = {}
        #: Seconds each closed round held its job (for the figures: offer-round p50).
        self.durations: deque[float] = deque(maxlen=10_000)

    def subscriptions(self) -> list[str]:
        """Answers to our offer requests, from any delegator."""
        return [f"{self.config.prefix}/unit/+/+/+/delegation/response/{self.config.name}"]

    def is_answer(self, topic: str) -> bool:
        """True for a topic `subscriptions` covers."""
        rest = f"delegation/response/{self.config.name}"
        if not topic.endswith(rest):  # asked of every message: most are not (read cheaply)
            return False
        parsed = parse_unit_topic(topic)
        return parsed is not None and parsed.rest == rest

    def _askable(self, now: float) -> list[Delegator]:
        """The live delegators this service would ask for offers now (none when it does not
        federate)."""
        c = self.config
        if not c.federate or c.bid_window <= 0:
            return []
        return [d for d in self.fleet.delegators(now) if d.name != c.name]

    def may_ask(self, now: float) -> bool:
        """Whether `open` could ask anyone now (a plan's job may then be held for offers)."""
        return bool(self._askable(now))

    def open(self, job: Job, caller: str, now: float, *, redelegation: bool = False
             ) -> Effects | None:
        """Ask the live delegators for offers on the job's offerable subtrees and hold the job;
        None when there is nothing to ask (the job goes to the planner at once). A re-delegation
        asks only when ``redelegation`` says so (a lost delegator's part, §15.4)."""
        c = self.config
        if job.kind != "plan" or (job.redelegate and not redelegation):
            return None
        delegators = self._askable(now)
        if not delegators:  # nobody to ask: no geometry (it cost more than the plan, issue 19)
            return None
        if caller and (caller in {d.name for d in delegators}
                       or "tst execution" in self.fleet.levels(caller)):
            return None  # another delegator (or its engine) gives us a part: our fleet does it
        requests = self._requests(job, delegators, now)
        if not requests:
            return None
        effects = Effects()
        limit = max(0.05, min(job.options.time_limit, c.bid_window * PLANNING_SHARE))
        for r in requests:
            ask = Delegate(com_uuid=r.com_uuid, sender=c.name, tst=to_dict(r.subtree),
                           preview=True,
                           strategy=job.options.strategy, objective=job.options.objective,
                           time_limit=limit)
            effects.publish.append(Outgoing.of(f"{r.base}/delegation/command/{c.name}", ask))
            self._by_com[r.com_uuid] = job.id
        self.rounds[job.id] = OfferRound(job, now, now + c.bid_window,
                                         {r.com_uuid: r for r in requests})
        log.info("mission %s: asked %d offer(s) of %s (at most %.1f s)", job.tree.node_uuid,
                 len(requests), ", ".join(sorted({r.delegator for r in requests})), c.bid_window)
        return effects

    def _requests(self, job: Job, delegators: list[Delegator], now: float
                  ) -> list[OfferRequest]:
        """What to ask whom (`offer_asks`), each with a fresh com-uuid."""
        positions = {u.name: u.position for u in self.fleet.snapshot(now)}
        asks = offer_asks(job.tree.root, delegators, job.units, positions, new_com_uuid)
        return [OfferRequest(new_com_uuid(), a.delegator.name, a.delegator.base_topic, a.path,
                             a.subtree, a.covers) for a in asks]

    def receive(self, topic: str, payload: bytes, now: float) -> list[Job]:
        """A delegator's answer: an offer or a refusal; the jobs whose round is now complete."""
        try:
            answer = validate_model(DelegationResponse, json_value(payload, "delegation/response"),
                                    "delegation/response")
        except MessageError as exc:
            log.warning("unreadable offer on %s: %s", topic, exc)
            return []
        job_id = self._by_com.get(answer.response_to)
        found = self.rounds.get(job_id) if job_id is not None else None
        request = found.waiting.get(answer.response_to) if found else None
        if found is None or request is None or not topic.startswith(request.base + "/"):
            return []  # late (the round is over), or not from whom we asked
        del found.waiting[answer.response_to], self._by_com[answer.response_to]
        offer = (Offer.of(request.delegator, request.subtree, answer.plan, request.covers)
                 if answer.response == "ok" and answer.plan is not None
                 else answer.fail_reason or answer.response)
        if isinstance(offer, Offer):
            found.offers.append(offer)
        else:
            found.notes.append(f"{request.delegator} made no offer for {request.path}: "
                               f"{str(offer)[:200]}")
        return self._close(found, now) if not found.waiting else []

    def expire(self, now: float) -> list[Job]:
        """Rounds whose bid window passed: the silent delegators are left out, said so."""
        done: list[Job] = []
        for r in [r for r in self.rounds.values() if now >= r.deadline]:
            for request in r.waiting.values():
                self._by_com.pop(request.com_uuid, None)
                r.notes.append(f"{request.delegator} did not answer within "
                               f"{self.config.bid_window:g} s: left out of {request.path}")
            done.extend(self._close(r, now))
        return done

    def _close(self, r: OfferRound, now: float) -> list[Job]:
        del self.rounds[r.job.id]
        self.durations.append(now - r.opened)
        log.info("mission %s: %d offer(s) in %.2f s", r.job.tree.node_uuid, len(r.offers),
                 now - r.opened)
        return [replace(r.job, offers=tuple(r.offers), notes=(*r.job.notes, *r.notes))]
