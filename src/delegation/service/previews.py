"""Each caller's recent plan previews, so that a start naming one starts that very plan (pure).

A preview (``delegate`` with ``preview: true``) is answered and never stored as a mission; the
operator compares previews and picks one. Planning again at start could give another plan
(``optimal`` within a time limit, units that moved), so the service keeps the plans it previewed,
in memory (a preview is not a mission: a restart forgets them), bounded in count and age. Before
a kept plan is started it is checked against the fleet as it is now; `stale_reason` says why it
no longer holds, and the start then plans again and says so (docs/protocol.md).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from delegation.allocation import Plan
from delegation.fleet import UnitState
from delegation.geo import distance_m
from delegation.service.jobs import Job
from delegation.tst.node import without_node_uuids

#: Previews kept per caller (the page previews up to three strategies at a time).
PER_CALLER = 8
#: Previews kept in all (the oldest go first).
TOTAL = 256
#: Seconds a preview may be started after it was answered.
MAX_AGE = 600.0
#: Metres a unit may have moved since the preview before its times no longer hold.
MOVED_M = 25.0
#: Seconds a unit may have become busier (free later) since the preview.
LATER_S = 1.0


@dataclass(frozen=True, slots=True)
class Preview:
    """One answered preview: the job it answered (tree with uuids, fleet snapshot, options), its
    plan, the plan's JSON as answered and when."""

    preview_id: str
    caller: str
    job: Job
    plan: Plan
    plan_json: dict[str, Any]
    made: float
    #: The validated tree without node uuids (a start must name the same mission).
    tree: dict[str, Any]


class Previews:
    """Answered previews by (caller, preview id), oldest first; bounded (`PER_CALLER`, `TOTAL`,
    `MAX_AGE`)."""

    def __init__(self, per_caller: int = PER_CALLER, total: int = TOTAL,
                 max_age: float = MAX_AGE) -> None:
        self.per_caller, self.total, self.max_age = per_caller, total, max_age
        self._kept: OrderedDict[tuple[str, str], Preview] = OrderedDict()

    def __len__(self) -> int:
        return len(self._kept)

    def keep(self, preview: Preview) -> None:
        self._kept[(preview.caller, preview.preview_id)] = preview
        mine = [k for k in self._kept if k[0] == preview.caller]
        for key in mine[: max(0, len(mine) - self.per_caller)]:
            del self._kept[key]
        while len(self._kept) > self.total:
            self._kept.popitem(last=False)

    def take(self, caller: str, preview_id: str, now: float) -> tuple[Preview | None, str]:
        """The caller's preview (removed: a plan is started once), or None and why not."""
        self._expire(now)
        found = self._kept.pop((caller, preview_id), None)
        if found is None:
            return None, (f"preview {preview_id} is not known (older than {self.max_age:.0f} s, "
                          "started already, another caller's, or the service restarted)")
        return found, ""

    def _expire(self, now: float) -> None:
        old = [k for k, p in self._kept.items() if now - p.made > self.max_age]
        for key in old:
            del self._kept[key]


def stale_reason(preview: Preview, tree: dict[str, Any], units: Iterable[UnitState]) -> str:
    """Why the previewed plan cannot be started as it was shown ("" when it can): another
    mission (``tree``: the start's validated tree), or a unit it uses that is gone, no longer
    offers its task, got busier or moved since the preview."""
    if without_node_uuids(tree) != preview.tree:
        return "the mission is not the one previewed"
    if preview.job.offers:
        return "it used other delegators' offers, which are asked for again"
    now_by = {u.name: u for u in units}
    then_by = {u.name: u for u in preview.job.units}
    used: dict[str, set[str]] = {}
    for a in preview.plan.assignments:
        used.setdefault(a.execunit.strip("/"), set()).add(a.name)
    for name in sorted(used):
        unit, then = now_by.get(name), then_by.get(name)
        if then is None:
            continue  # not one of ours (the engine's own tasks)
        if unit is None or not unit.alive:
            return f"{name} is no longer available (lost, battery low or busy elsewhere)"
        missing = sorted(used[name] - unit.tasks)
        if missing:
            return f"{name} no longer offers {', '.join(missing)}"
        if unit.available_at > then.available_at + LATER_S:
            return f"{name} got busy in another mission"
        moved = distance_m(unit.position, then.position)
        if moved > MOVED_M:
            return f"{name} moved {moved:.0f} m since the preview"
    return ""
