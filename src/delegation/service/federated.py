"""Planning with other delegators' offers (docs/protocol.md §15.2): which subtrees may be
offered, what an offer says, and the plan that lets offers compete with our own units.

Runs on the planner worker (like `delegation.service.jobs.run_job`): pure computation, no
messages. Only the children of a root ``conc`` are offered: they start together, so a delegated
child's offer (its makespan, measured from when the delegator starts it) combines with our own
part as ``max`` (makespan) and ``+`` (total time). A ``seq``'s children would tie the delegator's
schedule to ours (it may start only when we finish the previous child, from positions the offer
did not know): not offered yet.
"""

from __future__ import annotations

import logging
import math
import uuid as uuid_module
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from delegation.allocation import Assignment, Objective, Plan, plan_mission
from delegation.costs import task_geometry
from delegation.fleet import Delegator, UnitState
from delegation.geo import GeoPoint, distance_m
from delegation.tst.node import (
    ExecUnitKind,
    TstNode,
    classify_execunit,
    make_node,
    map_tree,
    to_dict,
    walk,
    where,
)
from delegation.tst.validate import DEFAULT_LIMITS, Limits, with_defaults

log = logging.getLogger(__name__)

#: Seconds of planner time each candidate combination gets (auction: milliseconds): the offers
#: are compared with the fast strategy, the chosen combination is planned with the one asked for.
COMPARE_TIME_LIMIT = 0.5


@dataclass(frozen=True, slots=True)
class Offer:
    """A delegator's answer to a plan-only ``delegate`` of one subtree: what its plan says.

    ``covers`` are the root's children the subtree holds: one child, or a bundle of several
    under a ``conc`` of ours (``bundle``, its node uuid, sent in the request)."""

    delegator: str
    covers: tuple[str, ...]
    makespan: float
    total_time: float
    total_distance: float
    #: The delegator's plan's assignments (JSON, hyphenated keys), for our plan's times.
    assignments: tuple[Mapping[str, Any], ...] = ()
    bundle: str = ""

    @classmethod
    def of(cls, delegator: str, subtree: TstNode, plan: Mapping[str, Any],
           covers: tuple[str, ...]) -> Offer | str:
        """The offer in a delegator's plan for ``subtree``, or why it is none (infeasible,
        unreadable, a task of the subtree missing from its assignments)."""
        if plan.get("feasible") is not True:
            return "its plan is infeasible"
        values = [plan.get(k) for k in ("makespan", "total-time", "total-distance")]
        numbers = [float(v) for v in values
                   if isinstance(v, int | float) and not isinstance(v, bool)]
        if len(numbers) != len(values):
            return "its plan has no makespan/total-time/total-distance"
        if not all(math.isfinite(x) and x >= 0.0 for x in numbers):
            return "its plan's times are not finite"
        raw = plan.get("assignments")
        tasks = {n.node_uuid for _, n in walk(subtree) if not n.is_control}
        assignments = tuple(_assignment(a) for a in raw if isinstance(a, Mapping)
                            and a.get("node-uuid") in tasks) if isinstance(raw, list) else ()
        if None in assignments:
            return "its plan has an assignment without finite times"
        if not tasks <= {a.get("node-uuid") for a in assignments if a is not None}:
            return "its plan does not assign every task of the subtree"
        makespan, total_time, total_distance = numbers
        bundle = (subtree.node_uuid or "") if covers != (subtree.node_uuid,) else ""
        return cls(delegator, covers, makespan, total_time, total_distance,
                   tuple(a for a in assignments if a is not None), bundle)


#: The numbers an offer's assignment must carry (a partner's plan is checked, not trusted).
_TIMES = ("start", "end", "travel-time", "work-time", "distance")


def _assignment(raw: Mapping[str, Any]) -> dict[str, Any] | None:
    """An offer's assignment with finite, non-negative numbers, or None."""
    out: dict[str, Any] = {"node-uuid": raw.get("node-uuid"), "name": str(raw.get("name", ""))}
    for key in _TIMES:
        value = raw.get(key, 0.0)
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value) or value < 0.0:
            return None
        out[key] = float(value)
    return out


def offerable_children(root: TstNode) -> list[tuple[str, TstNode]]:
    """(path, child) of the children that may be offered (docs/protocol.md §15.2): those of a
    root ``conc`` with at least two children, whose subtree names no unit (no fixed ``execunit``)
    and shares no alias with the rest of the tree."""
    if root.name != "conc" or len(root.children) < 2:
        return []
    aliases: dict[str, set[int]] = {}
    fixed: set[int] = set()
    for i, child in enumerate(root.children):
        for _, node in walk(child):
            kind, name = classify_execunit(node.execunit)
            if kind is ExecUnitKind.FIXED:
                fixed.add(i)
            elif kind is ExecUnitKind.ALIAS:
                aliases.setdefault(name, set()).add(i)
    shared = {i for users in aliases.values() if len(users) > 1 for i in users}
    return [(where(f"root/children[{i}]", c), c) for i, c in enumerate(root.children)
            if i not in fixed and i not in shared and c.node_uuid]


def takers(child: TstNode, delegators: Sequence[Delegator]) -> list[Delegator]:
    """The delegators whose fleet lists every task of ``child``."""
    names = {n.name for _, n in walk(child) if not n.is_control}
    return [d for d in delegators if d.alive and d.can_take(names)]


def anchor(child: TstNode) -> GeoPoint | None:
    """Where a subtree begins: the first point of its first task that has one."""
    for _, node in walk(child):
        if node.is_control:
            continue
        try:
            g = task_geometry(node)
        except (KeyError, TypeError, ValueError):
            continue
        points = [*g.points, *(a[0] for a in g.areas if a)]
        if points:
            return points[0]
    return None


def _nearest(where_: GeoPoint, points: Sequence[GeoPoint]) -> float:
    return min((distance_m(where_, p) for p in points), default=math.inf)


def nearer_takers(child: TstNode, delegators: Sequence[Delegator], own: Sequence[UnitState],
                  positions: Mapping[str, GeoPoint]) -> list[tuple[float, Delegator]]:
    """(distance, delegator) for the delegators that could take ``child`` and have a unit
    nearer to where it begins than any of our units that could (every unit's position is on
    the broker), nearest first; a delegator whose units' positions are unknown is counted as
    near (infinitely far, after the others), a child without a place goes to every taker."""
    names = {n.name for _, n in walk(child) if not n.is_control}
    where_ = anchor(child)
    found = []
    ours = _nearest(where_, [u.position for u in own if names <= u.tasks]) if where_ else 0.0
    for d in takers(child, delegators):
        known = [positions[u] for u in d.units_managed if u in positions]
        if where_ is None or not known:
            found.append((math.inf, d))
            continue
        dist = _nearest(where_, known)
        if dist < ours:
            found.append((dist, d))
    return sorted(found, key=lambda t: (t[0], t[1].name))


@dataclass(frozen=True, slots=True)
class Ask:
    """A subtree to ask one delegator an offer for (``covers``: the root's children it holds)."""

    delegator: Delegator
    path: str
    subtree: TstNode
    covers: tuple[str, ...]


def offer_asks(root: TstNode, delegators: Sequence[Delegator], own: Sequence[UnitState],
               positions: Mapping[str, GeoPoint], new_uuid: Callable[[], str]) -> list[Ask]:
    """What to ask whom (docs/protocol.md §15.2): each offerable child to the delegators with a
    unit nearer to it than ours (`nearer_takers`), and to each delegator the bundle of the
    children it is the nearest for, under a new ``conc`` (when two or more)."""
    asks: list[Ask] = []
    site: dict[str, list[tuple[str, TstNode]]] = {}
    by_name = {d.name: d for d in delegators}
    for path, child in offerable_children(root):
        near = nearer_takers(child, delegators, own, positions)
        asks.extend(Ask(d, path, child, (child.node_uuid or "",)) for _, d in near)
        if near and math.isfinite(near[0][0]):
            site.setdefault(near[0][1].name, []).append((path, child))
    for name, kids in sorted(site.items()):
        if len(kids) >= 2:
            conc = make_node("conc", [k for _, k in kids], node_uuid=new_uuid())
            asks.append(Ask(by_name[name], ", ".join(p for p, _ in kids), conc,
                            tuple(k.node_uuid or "" for _, k in kids)))
    return asks


def without_units(root: TstNode, units: Collection[str]) -> TstNode:
    """The tree with every ``execunit`` that names one of ``units`` cleared, control nodes too:
    a lost delegator's subtree (its ``seq``/``conc`` named for it) is free again, for our own
    units or another delegator's offer (docs/protocol.md §15.4)."""
    if not units:
        return root

    def clear(node: TstNode, children: tuple[TstNode, ...]) -> TstNode:
        node = node.with_children(children)
        if isinstance(node.execunit, str):
            kind, name = classify_execunit(node.execunit)
            if kind is ExecUnitKind.FIXED and name in units:
                return node.with_common_values({"execunit": ""})
        return node

    return map_tree(root, clear)


@dataclass(frozen=True, slots=True)
class Handover:
    """Subtrees of lost delegators that go whole to other delegators within the running tree
    (docs/protocol.md §15.4): what the engine is told (``rebind-tst-nodes`` of each subtree's
    root: it holds the subtree as one node), what the mission's tree records (every node of
    those subtrees named for the lost delegator), and the ``re-delegated`` rows."""

    engine: dict[str, str]
    book: dict[str, str]
    tasks: list[dict[str, str]]


def _fixed(node: TstNode) -> str:
    if not isinstance(node.execunit, str):
        return ""
    kind, name = classify_execunit(node.execunit)
    return name if kind is ExecUnitKind.FIXED else ""


def delegated_roots(root: TstNode, units: Collection[str]) -> dict[str, tuple[str, TstNode]]:
    """uuid -> (path, node) of the topmost nodes below ``root`` named for one of ``units``: the
    subtrees an engine hands to a delegator whole (`delegation.engine.delegated`)."""
    found: dict[str, tuple[str, TstNode]] = {}
    for path, node in walk(root):
        if node is root or any(path.startswith(p + "/") for p, _ in found.values()):
            continue
        if _fixed(node) in units and node.node_uuid:
            found[node.node_uuid] = (path, node)
    return found


def _lost_subtrees(current: TstNode, planned: TstNode, origin: Mapping[str, str],
                   freed: Collection[str], lost: Collection[str]) -> tuple[
                       dict[str, tuple[str, TstNode]], dict[str, set[str]], dict[str, TstNode]
                   ] | None:
    """What `handover` and `take_back` both start from: the subtrees the lost delegators were
    handed (root uuid -> path and node), the task uuids inside each, and the planned nodes by
    the uuid they stand for; None when there are none or the plan frees a task outside them."""
    roots = delegated_roots(current, lost)
    inside = {r: {n.node_uuid or "" for _, n in walk(node) if not n.is_control}
              for r, (_, node) in roots.items()}
    covered: set[str] = set().union(*inside.values())
    if not roots or not {origin.get(f, "") for f in freed} <= covered:
        return None
    by_old = {origin[n.node_uuid]: n for _, n in walk(planned)
              if n.node_uuid and n.node_uuid in origin}
    return roots, inside, by_old


def handover(current: TstNode, planned: TstNode, origin: Mapping[str, str],
             freed: Collection[str], lost: Collection[str], delegators: Collection[str],
             status: Mapping[str, str]) -> Handover | None:
    """The `Handover` when a re-delegation's plan (``planned``, made of the remaining tree whose
    uuids ``origin`` maps to ``current``'s) gives every subtree a lost delegator was handed,
    whole (none of its tasks ended), to one live delegator, and frees nothing else; else None
    (the tree is replaced: our own units take the rest)."""
    found = _lost_subtrees(current, planned, origin, freed, lost)
    if found is None:
        return None
    roots, inside, by_old = found
    engine: dict[str, str] = {}
    book: dict[str, str] = {}
    tasks: list[dict[str, str]] = []
    for r, (path, node) in roots.items():
        new = by_old.get(r)
        taker = _fixed(new) if new is not None else ""
        if new is None or taker in lost or taker not in delegators \
                or status.get(r) in _ENDED or any(status.get(t) in _ENDED for t in inside[r]):
            return None
        if {origin.get(n.node_uuid or "") for _, n in walk(new) if not n.is_control} != inside[r]:
            return None  # not whole: the delegator would run the subtree from its start
        engine[r] = f"/{taker}"
        for sub, n in walk(node, path):
            if n.node_uuid and (n is node or _fixed(n) in lost):
                book[n.node_uuid] = f"/{taker}"
            if not n.is_control and n.node_uuid:
                tasks.append({"node-uuid": n.node_uuid, "replaces": n.node_uuid,
                              "name": n.name, "path": where(sub, n), "unit": f"/{taker}"})
    return Handover(engine, book, tasks)


#: Node statuses after which a subtree is not handed to anyone again.
_ENDED = frozenset({"succeeded", "failed", "aborted"})


@dataclass(frozen=True, slots=True)
class TakeBack:
    """Subtrees of lost delegators that the plan gives to our own units, each run in its
    place within the running tree (``rebind-tst-nodes`` ``subtrees``: the engine holds the
    subtree as one node, under its root's uuid): the subtrees (root uuid -> the planned part,
    its root's uuid kept, the rest new), the new nodes' origins (new uuid -> the node it
    stands for) and the ``re-delegated`` rows."""

    subtrees: dict[str, dict[str, Any]]
    origin: dict[str, str]
    tasks: list[dict[str, str]]


def take_back(current: TstNode, planned: TstNode, origin: Mapping[str, str],
              freed: Collection[str], lost: Collection[str], delegators: Collection[str],
              status: Mapping[str, str]) -> TakeBack | None:
    """The `TakeBack` when a re-delegation's plan (``planned``, made of the remaining tree whose
    uuids ``origin`` maps to ``current``'s) runs what is left of every subtree a lost delegator
    was handed on our own units only (no task on a delegator), as planned from that subtree
    (the same tasks, nothing regrouped or shared into new parts), and frees nothing else; else
    None (the tree is replaced)."""
    found = _lost_subtrees(current, planned, origin, freed, lost)
    if found is None:
        return None
    roots, inside, by_old = found
    others = set(delegators) | set(lost)
    subtrees: dict[str, dict[str, Any]] = {}
    origins: dict[str, str] = {}
    tasks: list[dict[str, str]] = []
    for r, (path, _) in roots.items():
        left = {t for t in inside[r] if status.get(t) not in ("succeeded", "revoked")}
        if status.get(r) in _ENDED or not left:
            continue  # nothing of it to run again
        new = by_old.get(r)
        if new is None:
            return None
        nodes = list(walk(new, path))
        if any(_fixed(n) in others for _, n in nodes) \
                or any(not n.is_control and not _fixed(n) for _, n in nodes):
            return None  # a part for a delegator (ours would start its tasks) or unassigned
        if {origin.get(n.node_uuid or "") for _, n in nodes if not n.is_control} != left:
            return None  # regrouped or shared into new parts: not the subtree's own tasks
        subtrees[r] = to_dict(new.with_common_values({"node-uuid": r}))
        for sub, n in nodes:
            uid = n.node_uuid or ""
            if n is not new and uid in origin:
                origins[uid] = origin[uid]
            if not n.is_control:
                tasks.append({"node-uuid": uid if n is not new else r,
                              "replaces": origin[uid], "name": n.name,
                              "path": where(sub, n), "unit": f"/{_fixed(n)}"})
    return TakeBack(subtrees, origins, tasks) if subtrees else None


def kept_delegations(root: TstNode, own: Collection[str], engine: str) -> list[Offer]:
    """The children of a root ``conc`` named wholly for one unit that is neither ours nor the
    engine (every node's ``execunit`` is that ``/delegator``): a re-delegation keeps them with
    their delegator, since our planner cannot plan for a unit it does not have."""
    if root.name != "conc":
        return []
    kept = []
    for child in root.children:
        names = set()
        for _, node in walk(child):
            kind, name = classify_execunit(node.execunit) if isinstance(
                node.execunit, str) else (ExecUnitKind.FREE, "")
            names.add(name if kind is ExecUnitKind.FIXED else "")
        if len(names) == 1 and child.node_uuid:
            (name,) = names
            if name and name not in own and name != engine:
                kept.append(Offer(name, (child.node_uuid,), 0.0, 0.0, 0.0))
    return kept


@dataclass(frozen=True, slots=True)
class _Score:
    unassigned: int
    primary: float
    secondary: float

    def key(self) -> tuple[int, float, float]:
        return (self.unassigned, self.primary, self.secondary)


class FederatedPlanner:
    """Chooses which offered children go to which delegator (greedily, one child at a time, the
    one that improves the objective most; each delegator takes at most one child) and builds the
    plan: our part planned as usual, each delegated child whole with the delegator as its
    ``execunit``."""

    def __init__(self, root: TstNode, units: Sequence[UnitState], offers: Sequence[Offer], *,
                 strategy: str, objective: str, time_limit: float, engine_unit: str,
                 limits: Limits = DEFAULT_LIMITS, kept: Sequence[Offer] = (),
                 split: bool = True) -> None:
        self.root = root
        self.units = tuple(units)
        children = {c.node_uuid for c in root.children}
        self.offers = [o for o in offers if o.covers and set(o.covers) <= children]
        #: Subtrees that stay with their delegator whatever the rest costs (`kept_delegations`).
        self.kept = [o for o in kept if o.covers and set(o.covers) <= children]
        self.strategy, self.objective = strategy, Objective(objective)
        self.time_limit, self.engine_unit, self.limits = time_limit, engine_unit, limits
        #: Whether our own plans may share a search among units (``split: false`` says no).
        self.split = split
        #: Our own plan of what is left, by the children given away (None: nothing left).
        self._own: dict[frozenset[str], Plan | None] = {}
        self.evaluations = 0

    def own_tree(self, chosen: Sequence[Offer]) -> TstNode | None:
        """The root without the delegated children (None when nothing is left for us)."""
        gone = {k for o in chosen for k in o.covers}
        kept = [c for c in self.root.children if c.node_uuid not in gone]
        return self.root.with_children(kept) if kept else None

    def _own_plan(self, chosen: Sequence[Offer]) -> Plan | None:
        """Our fast plan of what ``chosen`` leaves us (the same for whoever takes the rest)."""
        gone = frozenset(k for o in chosen for k in o.covers)
        if gone not in self._own:
            own_tree = self.own_tree(chosen)
            self.evaluations += own_tree is not None
            self._own[gone] = None if own_tree is None else plan_mission(
                own_tree, self.units, strategy="auction", objective=self.objective,
                time_limit=min(self.time_limit, COMPARE_TIME_LIMIT),
                engine_unit=self.engine_unit, limits=self.limits, split=self.split)
        return self._own[gone]

    def score(self, chosen: Sequence[Offer]) -> _Score:
        """(tasks nobody takes, objective, the other measure) of giving ``chosen`` away."""
        own = self._own_plan(chosen)
        makespan = max([own.makespan if own else 0.0, *(o.makespan for o in chosen)])
        total = (own.total_time if own else 0.0) + sum(o.total_time for o in chosen)
        primary, secondary = (makespan, total) if self.objective is Objective.MAKESPAN \
            else (total, makespan)
        return _Score(len(own.unassigned) if own else 0, primary, secondary)

    def _bound(self, chosen: Sequence[Offer]) -> float:
        """A lower bound on the objective of giving ``chosen`` away, whatever our part costs:
        a trial that cannot beat the best so far is not planned."""
        if self.objective is Objective.MAKESPAN:
            return max((o.makespan for o in chosen), default=0.0)
        return sum(o.total_time for o in chosen)

    def choose(self) -> list[Offer]:
        """The offers taken (empty when our own fleet does better): every partner's bundle at
        once when that beats our fleet alone (the two-site case, in one evaluation), then
        greedily the one offer that improves the objective most, while one does."""
        chosen: list[Offer] = list(self.kept)
        best = self.score(chosen)
        bundles: dict[str, Offer] = {}
        for o in self.offers:
            if o.bundle:
                bundles.setdefault(o.delegator, o)
        if bundles:
            together = [*chosen, *bundles.values()]
            score = self.score(together)
            if score.key() < best.key():
                chosen, best = together, score
        while True:
            # A kept part does not count: a lost partner's subtree may go to a delegator that
            # runs another part of the mission (its engine hands it the two one after the other).
            used = {o.delegator for o in chosen if o not in self.kept}
            taken = {k for o in chosen for k in o.covers}
            candidates = [o for o in self.offers
                          if o.delegator not in used and not taken & set(o.covers)]
            trials = [(self.score([*chosen, o]), o) for o in candidates
                      if best.unassigned or self._bound([*chosen, o]) < best.primary]
            better = [t for t in trials if t[0].key() < best.key()]
            if not better:
                return chosen
            best, offer = min(better, key=lambda t: t[0].key())
            chosen.append(offer)

    def plan(self) -> Plan:
        """The plan: our own plan for what is kept, the offers for what is delegated."""
        chosen = self.choose()
        baseline = self.score(self.kept)
        own_tree = self.own_tree(chosen)
        own = None if own_tree is None else plan_mission(
            own_tree, self.units, strategy=self.strategy, objective=self.objective,
            time_limit=self.time_limit, engine_unit=self.engine_unit, limits=self.limits,
            split=self.split)
        if not chosen and own is not None:
            own.notes.extend(self._notes(chosen, baseline))
            return own
        return self._assemble(own, chosen, baseline)

    def _delegated(self, source: TstNode, offer: Offer) -> TstNode:
        """The subtree the delegator gets: the child, or our ``conc`` around the bundle, named
        for it, and so is every task inside that the caller left free (the delegator chooses its
        unit; a lost delegator's tasks are then found and re-delegated like a lost unit's)."""
        unit = f"/{offer.delegator}"

        def mark(node: TstNode, children: tuple[TstNode, ...]) -> TstNode:
            node = node.with_children(children)
            if node.is_control or classify_execunit(node.execunit)[0] is not ExecUnitKind.FREE:
                return node
            return node.with_common_values({"execunit": unit})

        kids = [map_tree(c, mark) for c in source.children if c.node_uuid in offer.covers]
        if not offer.bundle:
            return kids[0].with_common_values({"execunit": unit})
        return make_node("conc", kids, execunit=unit, node_uuid=offer.bundle)

    def _assemble(self, own: Plan | None, chosen: Sequence[Offer], baseline: _Score) -> Plan:
        source = with_defaults(self.root)
        delegated = [self._delegated(source, o) for o in chosen]
        if own is None:
            kids: list[TstNode] = []
        elif own.tst.name == "conc" and own.tst.node_uuid == self.root.node_uuid:
            kids = list(own.tst.children)
        else:  # regrouped: our part becomes one child under the caller's root
            kids = [own.tst.with_common_values({"node-uuid": str(uuid_module.uuid4())})
                    if own.tst.node_uuid == self.root.node_uuid else own.tst]
        tst = source.with_children([]).with_common_values(
            {"execunit": f"/{self.engine_unit}"}).with_children([*kids, *delegated])
        theirs = [Assignment(str(a.get("node-uuid")), str(a.get("name", "")), f"/{o.delegator}",
                             float(a.get("start", 0.0)), float(a.get("end", 0.0)),
                             float(a.get("travel-time", 0.0)), float(a.get("work-time", 0.0)),
                             float(a.get("distance", 0.0)))
                  for o in chosen for a in o.assignments]
        makespan = max([own.makespan if own else 0.0, *(o.makespan for o in chosen)])
        precedence = None if own is None or own.precedence_makespan is None else max(
            [own.precedence_makespan, *(o.makespan for o in chosen)])
        return Plan(
            strategy=self.strategy, objective=self.objective.value,
            feasible=own is None or own.feasible, makespan=makespan,
            total_time=(own.total_time if own else 0.0) + sum(o.total_time for o in chosen),
            total_distance=((own.total_distance if own else 0.0)
                            + sum(o.total_distance for o in chosen)),
            solve_time=own.solve_time if own else 0.0, bound=None, gap=None,
            assignments=sorted([*(own.assignments if own else []), *theirs],
                               key=lambda a: (a.start, a.execunit)),
            unassigned=list(own.unassigned) if own else [],
            tst=tst, routes=dict(own.routes) if own else {},
            notes=[*(own.notes if own else []), *self._notes(chosen, baseline)],
            source=source, precedence_makespan=precedence,
        )

    def _notes(self, chosen: Sequence[Offer], baseline: _Score) -> list[str]:
        """Which subtree went where and why, and the offers not taken."""
        paths = {c.node_uuid: where(f"root/children[{i}]", c)
                 for i, c in enumerate(self.root.children)}
        what = "makespan" if self.objective is Objective.MAKESPAN else "total time"
        own_alone = (f"{baseline.primary:.0f} s" if not baseline.unassigned
                     else f"{baseline.unassigned} task(s) nobody here can take")
        overall = self.score(chosen).primary

        def subtree(o: Offer) -> str:
            return ", ".join(paths[k] for k in o.covers)

        notes = [f"kept: {subtree(o)} stays with {o.delegator} (its part is sent to it again; "
                 "its times are not known here)" for o in self.kept]
        notes += [f"offer taken: {subtree(o)} goes to {o.delegator} (its {what} "
                  f"{o.makespan if what == 'makespan' else o.total_time:.0f} s; "
                  f"{overall:.0f} s in all, own fleet alone: {own_alone})"
                  for o in chosen if o not in self.kept]
        notes += [f"offer not taken: {o.delegator} for {subtree(o)} (makespan "
                  f"{o.makespan:.0f} s)" for o in self.offers if o not in chosen]
        return notes
