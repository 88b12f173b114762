"""How the delegation service names itself, finds its engine and plans by default."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from delegation.runtime.core import Identity
from delegation.topics import DEFAULT_PREFIX, MAX_PAYLOAD, unit_base_topic
from delegation.tst.validate import Limits

_REPAIRS = ("rebind", "restart")
_REPAIR_SWEEPS = ("remainder", "whole")
_COMMITMENTS = ("wait", "exclude", "share")


@dataclass(frozen=True, slots=True)
class ServiceConfig:
    """How the service names itself, finds its engine and plans by default."""

    name: str = "delegator0"
    prefix: str = DEFAULT_PREFIX
    agent_type: str = "ground"
    role: str = "simulation"
    engine: str = "op0"
    strategy: str = "auction"
    objective: str = "makespan"
    time_limit: float = 2.0
    #: The longest ``time-limit`` a ``delegate`` may ask for (plans run one at a time).
    max_time_limit: float = 60.0
    #: Seconds to wait for the engine's answer before a command is answered ``failed``.
    engine_timeout: float = 15.0
    #: Seconds the service waits for a lost engine to come back before its missions fail (a
    #: restarted engine is given the unfinished part of each tree again, docs/protocol.md §11).
    engine_return_timeout: float = 30.0
    #: Seconds a ``query-tst`` (catching up after a restart or an outage) waits for its answer
    #: before it is asked again, at most ``catch_up_attempts`` times.
    catch_up_timeout: float = 2.0
    catch_up_attempts: int = 10
    #: Seconds a ``cancel-mission`` waits for the engine to confirm the abort before it is
    #: answered ``pending`` (the engine's own abort timeout is 15 s).
    cancel_timeout: float = 20.0
    #: Heartbeat / info rate (Hz).
    rate: float = 1.0
    #: Fleet profiles for what heartbeats do not carry (speeds, endurance, ...); see ``fleet``.
    profiles: dict[str, dict[str, Any]] | None = None
    #: A unit (or the engine) is lost after at most this many seconds without a heartbeat,
    #: whatever rate it advertises (3 periods, at least 5 s).
    max_heartbeat_timeout: float = 15.0
    #: ... and never before this many seconds (jitter on a loaded broker); lower it to hold
    #: "3 heartbeat periods" for units faster than 0.6 Hz.
    min_heartbeat_timeout: float = 5.0
    #: After the service's own reconnect, peers get this long on top of their timeout to be
    #: heard again (MQTT clients here reconnect with a back-off of up to 8 s).
    reconnect_grace: float = 10.0
    #: For this many seconds after the service starts listening, a command that plans waits
    #: (rather than being refused or planned for the part of the fleet heard so far) until the
    #: engine has been heard: peers' heartbeats come once a second and are not retained.
    listen_first: float = 3.0
    #: ... and, within ``listen_first``, until it has listened this long: one round of its
    #: peers' heartbeats (once a second) and some jitter. Hearing the engine says nothing of the
    #: units, whose beats of the same second may come after it (the deployment doc's ``submit``
    #: right after ``serve`` started was planned for none of its three units, 16-31 ms early).
    #: ``delegation serve`` listens 1.2 s (``--listen-round``); 0 here, where a caller feeds the
    #: core its peers itself (the pure tests, on their own clocks, hear the engine last).
    listen_round: float = 0.0
    #: Planning jobs handed to the planner and not finished yet (waiting or being planned)
    #: beyond which a command that plans is refused, "busy", and not kept: a re-send once the
    #: planner has caught up is planned (issue 22; re-delegations are never refused). 1000:
    #: the 500-mission burst of benchmarks/burst.py is planned whole (200 turned 296 away).
    planner_queue: int = 1000
    #: Units whose battery (state of charge, 0..1) is below this are not planned for.
    min_battery: float = 0.2
    #: How often one task may be re-delegated (lost unit, unit answered ``failed``).
    max_retries: int = 2
    #: How a lost unit's tasks move (docs/protocol.md §11): ``rebind`` moves them within the
    #: running tree (`rebind-tst-nodes`, our engine's), healthy units' tasks untouched;
    #: ``restart`` replaces the tree (``$abort`` + ``start-tst``), as for an engine without it
    #: (a refused or unanswered rebind falls back to it anyway).
    repair: str = "rebind"
    #: A lost unit's part of a search, moved by ``rebind``: ``remainder`` subtracts what its
    #: reported positions had swept and shares the rest among the live units; ``whole`` flies
    #: the part again whole (the comparison of benchmarks/faults.py).
    repair_sweep: str = "remainder"
    #: Seconds our engine holds a failed task (or one its unit aborted unasked) for a rebind,
    #: its branch going on (``start-tst`` ``hold-failed``, docs/protocol.md §12.7), so that the
    #: task alone moves; past it the branch fails. Above planning's time; 0: the tree is
    #: replaced instead (as for an engine without the option).
    hold_failed: float = 30.0
    #: Units busy in another running mission of this service: ``wait`` plans them from when and
    #: where they become free (by that mission's plan), ``exclude`` leaves them out, ``share``
    #: ignores commitments (the engine queues the tasks). Said in the plan's notes.
    commitments: str = "wait"
    #: Who may query, cancel and signal every mission (others: only their own), by the name a
    #: command carries (its per-client command topic, ``sender``, or ``response-topic``).
    operators: frozenset[str] = frozenset()
    #: The largest command or status message read (bytes); a larger one is refused unread.
    max_payload: int = MAX_PAYLOAD
    #: The highest explicit speed (m/s) a task may ask for.
    max_speed: float = 100.0
    #: The units this service manages (``serve --fleet``; said in its ``delegation_info``).
    #: Empty: every unit it sees that no other delegator says it manages (docs/protocol.md §15.1).
    fleet: frozenset[str] = frozenset()
    #: Seconds the service waits for other delegators' offers before it plans (docs/protocol.md
    #: §15); a delegator that has not answered by then is left out, said in the plan's notes.
    bid_window: float = 1.0
    #: Ask other delegators for offers at all (off: plan with the own fleet only).
    federate: bool = True
    #: Other delegators (and their engines) whose offer requests and subtrees this service
    #: accepts (``serve --partner``); an ``operators`` name is trusted too. A command from any
    #: other delegator or TST engine that plans is refused (docs/protocol.md §15.4).
    partners: frozenset[str] = frozenset()

    def __post_init__(self) -> None:
        """A setting with no meaning is refused by name (it would silently act as the default)."""
        for field, value, allowed in (("repair", self.repair, _REPAIRS),
                                      ("repair_sweep", self.repair_sweep, _REPAIR_SWEEPS),
                                      ("commitments", self.commitments, _COMMITMENTS)):
            if value not in allowed:
                raise ValueError(f"ServiceConfig.{field}: {value!r} is not one of "
                                 f"{', '.join(allowed)}")
        if not self.hold_failed >= 0.0:  # (NaN too)
            raise ValueError(f"ServiceConfig.hold_failed: {self.hold_failed!r} s is not >= 0")

    @property
    def limits(self) -> Limits:
        """The physical ranges trees are validated with."""
        return Limits(max_speed=self.max_speed)

    @property
    def base_topic(self) -> str:
        return unit_base_topic(self.name, self.agent_type, self.role, self.prefix)

    def identity(self, agent_uuid: str) -> Identity:
        """The service as a unit on the broker (for its heartbeat)."""
        return Identity(
            name=self.name,
            agent_type=self.agent_type,
            agent_uuid=agent_uuid,
            role=self.role,
            prefix=self.prefix,
            rate=self.rate,
        )
