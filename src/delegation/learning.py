"""What the service learns about its fleet while it flies, and what it warns about (pure).

`SpeedLearner` keeps, per unit and speed class, an exponential average of the ground speed the
unit reports on ``sensor/speed`` while it runs a task of that class (known from the instantiated
tree and the engine's feedback). A plan uses the learnt figure where there is one, the fleet
profile (``--profiles``) before that, and the agent type's defaults last; `speed_notes` says which
(a plan made with defaults is said to be one, in the plan's notes and the service log).

Why ``sensor/speed`` and not positions: positions arrive on the service's wall clock, and a
simulated fleet runs faster than the wall (``--speedup``); the unit's own speed reading is in the
mission's units whatever the time factor.

`input_warnings` flags operator input that is valid but most likely not meant: an ``execunit``
without the ``/`` that names a live unit (it is an alias, so any unit may get the task), and tasks
so far from every unit that the coordinates are probably wrong (latitude and longitude swapped).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

from delegation.errors import InputError
from delegation.fleet import SPEED_KEYS, UnitState
from delegation.geo import GeoPoint, great_circle_matrix_m
from delegation.tst.node import TstNode, walk, where

#: A task this far (m) from every unit is flagged as implausible geometry.
FAR_M = 500_000.0

#: Where a unit's speeds came from, in the order they are preferred.
LEARNT, PROFILE, DEFAULT = "learnt", "profile", "default"


def speed_class(node: TstNode) -> str | None:
    """The speed class a task node runs at (``standard`` when not given); None for a control
    node or an explicit m/s value (which is not a class to learn)."""
    if node.is_control:
        return None
    value = node.params.get("speed")
    if value is None:
        return "standard"
    return value if isinstance(value, str) and value in SPEED_KEYS else None


@dataclass(slots=True)
class _Estimate:
    value: float
    samples: int
    at: float


@dataclass(slots=True)
class SpeedLearner:
    """Per unit and speed class: an exponential average of the reported ground speed.

    Fed with ``task_started``/``task_ended`` (from the engine's node feedback) and
    ``observe_speed`` (the unit's ``sensor/speed``), each with ``now``. Readings below
    ``min_speed`` (holding position, turning on the spot) are not samples; an estimate is used
    once it has ``min_samples``.
    """

    alpha: float = 0.3
    min_samples: int = 2
    min_speed: float = 0.2
    _running: dict[str, tuple[str, str]] = field(default_factory=dict)  # unit -> (node, class)
    _estimates: dict[str, dict[str, _Estimate]] = field(default_factory=dict)

    def task_started(self, unit: str, node_uuid: str, cls: str, now: float) -> None:
        self._running[unit] = (node_uuid, cls)

    def task_ended(self, unit: str, node_uuid: str, now: float) -> None:
        if self._running.get(unit, ("", ""))[0] == node_uuid:
            del self._running[unit]

    def observe_speed(self, unit: str, value: float, now: float) -> str | None:
        """One speed reading (m/s); returns the class when its estimate just became usable."""
        running = self._running.get(unit)
        if running is None or not value >= self.min_speed or value != value:
            return None
        cls = running[1]
        per_unit = self._estimates.setdefault(unit, {})
        est = per_unit.get(cls)
        if est is None:
            per_unit[cls] = est = _Estimate(float(value), 0, now)
        else:
            est.value += self.alpha * (float(value) - est.value)
            est.at = now
        est.samples += 1
        return cls if est.samples == self.min_samples else None

    def learnt(self, unit: str) -> dict[str, float]:
        """The usable estimates of a unit, per class (m/s)."""
        return {c: e.value for c, e in self._estimates.get(unit, {}).items()
                if e.samples >= self.min_samples}

    def speeds(self, unit: str, prior: Mapping[str, float]) -> dict[str, float]:
        """``prior`` (profile or defaults) with the learnt classes in; classes not learnt yet are
        scaled by the mean learnt/prior ratio (a unit 20 % faster at ``fast`` is assumed 20 %
        faster at ``standard`` too, as `delegation.fleet.complete_speeds` does)."""
        learnt = self.learnt(unit)
        if not learnt:
            return dict(prior)
        ratios = [v / prior[c] for c, v in learnt.items() if prior.get(c)]
        scale = sum(ratios) / len(ratios) if ratios else 1.0
        return {c: learnt.get(c, prior[c] * scale) for c in SPEED_KEYS}

    def apply(self, units: Iterable[UnitState]) -> tuple[UnitState, ...]:
        """The units with what was learnt about their speeds."""
        return tuple(replace(u, speeds=self.speeds(u.name, u.speeds)) if self.learnt(u.name)
                     else u for u in units)

    def source(self, unit: str, has_profile: bool) -> str:
        """``learnt``, ``profile`` or ``default``: where a unit's planning speeds come from."""
        if self.learnt(unit):
            return LEARNT
        return PROFILE if has_profile else DEFAULT


def speed_notes(units: Sequence[UnitState], sources: Mapping[str, str],
                used: Iterable[str]) -> list[str]:
    """A note per unit the plan uses whose speeds are not its own (defaults) or were learnt."""
    by_name = {u.name: u for u in units}
    notes = []
    for name in sorted(set(used)):
        unit, source = by_name.get(name), sources.get(name)
        if unit is None or source == PROFILE:
            continue
        figures = ", ".join(f"{c} {unit.speeds[c]:.1f}" for c in SPEED_KEYS)
        if source == DEFAULT:
            notes.append(f"unit /{name}: speeds are the {unit.agent_type} defaults ({figures} "
                         "m/s): no profile and nothing learnt yet, so plan times may be off")
        elif source == LEARNT:
            notes.append(f"unit /{name}: speeds learnt from its flights ({figures} m/s)")
    return notes


def input_warnings(tree: TstNode, units: Sequence[UnitState],
                   known: Iterable[str] = ()) -> list[str]:
    """Valid but suspicious input: bare unit names used as aliases, tasks far from every unit.

    The distances of every task's points come from one matrix (a matrix per task cost most of
    the check: ~0.4 ms a 20-task mission on the service's thread)."""
    from delegation.costs import task_geometry

    names = {u.name for u in units} | set(known)
    # In the tree's order: a warning, or a task's rows of the distance matrix to judge later.
    found: list[str | tuple[str, TstNode, int, int]] = []
    points: list[GeoPoint] = []
    for path, node in walk(tree):
        unit = node.execunit
        if isinstance(unit, str) and unit.strip() and unit not in ("*",) \
                and not unit.startswith("/") and unit in names:
            found.append(
                f"{where(path, node)}: execunit {unit!r} is an alias (any capable unit, the same "
                f"for every node with that alias), not the unit /{unit}; write '/{unit}' to ask "
                "for that unit")
        if node.is_control or not units:
            continue
        try:
            geometry = task_geometry(node)
        except (KeyError, ValueError, TypeError, InputError):
            continue
        mine = [*geometry.points, *(p for a in geometry.areas for p in a)]
        if mine:
            found.append((path, node, len(points), len(points) + len(mine)))
            points.extend(mine)
    distances = great_circle_matrix_m(points, [u.position for u in units]) if points else None
    warnings = []
    for item in found:
        if isinstance(item, str):
            warnings.append(item)
            continue
        path, node, first, last = item
        assert distances is not None
        nearest = float(distances[first:last].min())
        if nearest > FAR_M:
            warnings.append(
                f"{where(path, node)}: {nearest / 1000:,.0f} km from the nearest unit; "
                "latitude and longitude swapped, or the wrong site?")
    return warnings
