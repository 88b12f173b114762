"""Run strategies x objectives on scenarios and keep one record per run.

Every plan is checked with the planner's own ``check_invariants``; a violation is kept in the
record (``problems``), never hidden. A scenario that cannot be read or planned is reported with
its file name, and the others still run. The library returns values; the CLI prints them.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from delegation.allocation.strategies import Objective
from delegation.bench.isolate import call_isolated
from delegation.errors import DelegationError, InputError, Problem

if TYPE_CHECKING:
    from delegation.allocation import Plan
    from delegation.fleet import UnitState
    from delegation.scenario import Scenario
    from delegation.tst import TstNode

log = logging.getLogger(__name__)

#: File suffixes a scenario folder is searched for.
SCENARIO_SUFFIXES: tuple[str, ...] = (".yaml", ".yml", ".json")

#: The strategy every other one is compared with.
BASELINE = "nearest"


@dataclass(frozen=True)
class LoadedScenario:
    """A scenario with where it came from (a file path, or ``generated:<name>``)."""

    source: str
    scenario: Scenario


@dataclass(frozen=True, slots=True)
class ScenarioFailure:
    """A scenario that could not be read or planned, named by its file."""

    source: str
    message: str

    def __str__(self) -> str:
        if self.message.startswith(self.source):  # the loader already named the file
            return self.message
        return f"{self.source}: {self.message}"


@dataclass
class RunRecord:
    """One strategy x objective run on one scenario: the numbers the table, CSV and JSON show.

    ``objective_value`` is the plan's makespan or total time, as the objective asks;
    ``ratio_to_nearest`` divides it by ``nearest``'s on the same scenario, objective and repeat,
    and is None where ``nearest`` did not run or the two plans leave different numbers of tasks
    unassigned (their objectives then measure different work).
    """

    scenario: str
    source: str
    strategy: str
    objective: str
    #: 1..N (``--repeat N``)
    repeat: int
    units: int
    tasks: int
    feasible: bool
    makespan: float
    total_time: float
    total_distance: float
    objective_value: float
    solve_time: float
    wall_time: float
    assigned: int
    unassigned: int
    bound: float | None = None
    gap: float | None = None
    ratio_to_nearest: float | None = None
    #: invariant violations found by ``check_invariants`` (empty: the plan is sound)
    problems: list[str] = field(default_factory=list)
    #: what the strategy reported doing (e.g. optimal keeping the auction's plan when too large)
    notes: list[str] = field(default_factory=list)
    #: the strategy whose plan this is when the strategy fell back to it (``optimal`` keeping
    #: the auction's), else None
    fallback: str | None = None
    #: the plan's precedence-graph makespan and what the sent tree adds to it (s)
    precedence_makespan: float | None = None
    instantiation_loss: float | None = None
    #: a lower bound on any plan's makespan (``allocation.bounds``), s
    lower_bound: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


#: Record fields in the order the CSV and JSON carry them.
RECORD_FIELDS: tuple[str, ...] = tuple(RunRecord.__dataclass_fields__)


@dataclass
class BenchResult:
    """What a bench run produced: records, the plans of the first repeat, and the failures."""

    records: list[RunRecord] = field(default_factory=list)
    failures: list[ScenarioFailure] = field(default_factory=list)
    #: (source, strategy, objective) -> the plan of repeat 0, for plots.
    plans: dict[tuple[str, str, str], Plan] = field(default_factory=dict)
    #: source -> (scenario, units) as planned, for plots.
    scenarios: dict[str, tuple[Scenario, list[UnitState]]] = field(default_factory=dict)

    @property
    def violations(self) -> list[RunRecord]:
        """Runs whose plan failed the planner's invariant checks."""
        return [r for r in self.records if r.problems]


#: progress(done, total, label) is called after each run.
ProgressFn = Callable[[int, int, str], None]


# --------------------------------------------------------------------------- loading


def scenario_files(paths: Iterable[str | Path]) -> tuple[list[Path], list[ScenarioFailure]]:
    """The scenario files named by ``paths`` (files, or folders searched recursively)."""
    files: list[Path] = []
    failures: list[ScenarioFailure] = []
    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            found = sorted(
                p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in SCENARIO_SUFFIXES
            )
            if not found:
                failures.append(
                    ScenarioFailure(str(path), "no scenario files (*.yaml, *.yml, *.json)")
                )
            files.extend(found)
        elif path.is_file():
            files.append(path)
        else:
            failures.append(ScenarioFailure(str(path), "no such file or folder"))
    return files, failures


def load_scenarios(
    paths: Iterable[str | Path],
) -> tuple[list[LoadedScenario], list[ScenarioFailure]]:
    """Load every scenario file; a bad one becomes a failure naming the file, not an exception."""
    from delegation.scenario import load_scenario

    files, failures = scenario_files(paths)
    loaded: list[LoadedScenario] = []
    for path in files:
        try:
            loaded.append(LoadedScenario(str(path), load_scenario(path)))
        except DelegationError as exc:
            failures.append(ScenarioFailure(str(path), str(exc)))
        except (OSError, ValueError) as exc:  # unreadable file, undecodable text
            failures.append(ScenarioFailure(str(path), f"cannot read: {exc}"))
    return loaded, failures


def scenarios_from_dicts(data: Iterable[dict[str, Any]]) -> list[LoadedScenario]:
    """Wrap generated scenario dicts (they are valid by construction)."""
    from delegation.scenario import scenario_from_dict

    out = []
    for item in data:
        source = f"generated:{item.get('name', '?')}"
        out.append(LoadedScenario(source, scenario_from_dict(item, source=source)))
    return out


# --------------------------------------------------------------------------- running


def check_choice(kind: str, chosen: Sequence[str], known: Collection[str]) -> list[str]:
    """``chosen`` without duplicates, or InputError naming what is unknown."""
    unknown = [c for c in chosen if c not in known]
    if unknown:
        raise InputError(
            Problem(
                kind, "", f"unknown {', '.join(map(repr, unknown))}; choose from {', '.join(known)}"
            )
        )
    if not chosen:
        raise InputError(Problem(kind, "", "choose at least one"))
    return list(dict.fromkeys(chosen))


def counter_uuids(prefix: str = "bench") -> Callable[[], str]:
    """Deterministic node uuids, so that repeated runs build identical trees."""
    counter = itertools.count()
    return lambda: f"{prefix}-{next(counter):06d}"


def run_bench(
    scenarios: Sequence[LoadedScenario],
    *,
    strategies: Sequence[str] | None = None,
    objectives: Sequence[str] | None = None,
    repeat: int = 1,
    time_limit: float = 5.0,
    progress: ProgressFn | None = None,
    keep_plans: bool = True,
    isolate: bool = False,
    run_timeout: float | None = None,
) -> BenchResult:
    """Plan every scenario with every strategy x objective, ``repeat`` times; check every plan.

    With ``isolate`` each run happens in a child process (``bench.isolate``): a planner that
    crashes the process, or runs past ``run_timeout`` seconds, becomes a failure naming the file,
    strategy and objective, and the bench goes on.
    """
    from delegation.allocation import OBJECTIVES, STRATEGIES

    strategies = check_choice("strategies", strategies or list(STRATEGIES), STRATEGIES)
    objectives = check_choice("objectives", objectives or list(OBJECTIVES), OBJECTIVES)
    if repeat < 1:
        raise InputError(Problem("repeat", "", f"must be at least 1, not {repeat}"))
    if not time_limit > 0:
        raise InputError(Problem("time-limit", "", f"must be > 0, not {time_limit}"))

    if scenarios:
        warm_up(strategies, objectives)
    result = BenchResult()
    total = len(scenarios) * len(strategies) * len(objectives) * repeat
    done = 0
    for item in scenarios:
        runs = len(strategies) * len(objectives) * repeat
        start = done
        try:
            tree = item.scenario.tree()
            units = item.scenario.units()
        except DelegationError as exc:
            result.failures.append(ScenarioFailure(item.source, str(exc)))
            done += runs
            if progress:
                progress(done, total, f"{item.source}: failed")
            continue
        result.scenarios[item.source] = (item.scenario, units)
        records: list[RunRecord] = []
        try:
            for rep, objective, strategy in itertools.product(
                range(repeat), objectives, strategies
            ):
                label = f"{item.scenario.name} {strategy}/{objective}"
                kwargs = {
                    "item": item,
                    "tree": tree,
                    "units": units,
                    "strategy": strategy,
                    "objective": objective,
                    "time_limit": time_limit,
                    "repeat": rep + 1,
                }
                done += 1
                if not isolate:
                    record, plan = run_one(**kwargs)  # type: ignore[arg-type]
                else:
                    outcome = call_isolated(run_one, kwargs, timeout=run_timeout)
                    if outcome.input_error is not None:
                        raise DelegationError(outcome.input_error)
                    if not outcome.ok:
                        why = outcome.crashed or f"stopped after {run_timeout:g} s (run timeout)"
                        result.failures.append(
                            ScenarioFailure(
                                item.source, f"{strategy}/{objective} run {rep + 1}: {why}"
                            )
                        )
                        if progress:
                            progress(done, total, f"{label}: failed")
                        continue
                    record, plan = outcome.value
                records.append(record)
                if keep_plans and rep == 0:
                    result.plans[(item.source, strategy, objective)] = plan
                if progress:
                    progress(done, total, label)
        except DelegationError as exc:
            # plan_mission never raises for infeasibility; this is input it could not accept.
            result.failures.append(ScenarioFailure(item.source, str(exc)))
            done = start + runs
            for key in [k for k in result.plans if k[0] == item.source]:
                del result.plans[key]
            if progress:
                progress(done, total, f"{item.source}: failed")
            continue
        add_ratios(records)
        result.records.extend(records)
    return result


def warm_up(strategies: Sequence[str], objectives: Sequence[str]) -> None:
    """Plan a tiny generated scenario once per strategy x objective, here, before measuring.

    The first plan of a process pays for lazy imports and solver start-up (measured: ~20 ms for
    nearest, ~170 ms for optimal); forked children inherit the warm state, so no run pays it.
    """
    from delegation.allocation import plan_mission
    from delegation.bench.generate import generate_scenario

    item = scenarios_from_dicts([generate_scenario(units=2, tasks=3, seed=0)])[0]
    tree, units = item.scenario.tree(), item.scenario.units()
    for strategy in strategies:
        for objective in objectives:
            plan_mission(tree, units, strategy=strategy, objective=objective, time_limit=0.5)


def run_one(
    item: LoadedScenario,
    tree: TstNode,
    units: Sequence[UnitState],
    *,
    strategy: str,
    objective: str,
    time_limit: float,
    repeat: int = 1,
) -> tuple[RunRecord, Plan]:
    """Plan once, check the plan's invariants, and make its record."""
    from delegation.allocation import check_invariants, plan_mission
    from delegation.tst import leaves

    started = time.perf_counter()
    plan = plan_mission(
        tree,
        units,
        strategy=strategy,
        objective=objective,
        time_limit=time_limit,
        new_uuid=counter_uuids(),
    )
    wall = time.perf_counter() - started
    problems = list(check_invariants(plan, tree, units))
    for problem in problems:
        log.error("%s %s/%s: invariant violated: %s", item.source, strategy, objective, problem)
    record = make_record(
        item, plan, units, tasks=len(leaves(tree)), repeat=repeat, wall_time=wall, problems=problems
    )
    return record, plan


def objective_value(plan: Plan, objective: Objective | str) -> float:
    """The number the objective minimises: makespan, or total time (travel + work)."""
    if Objective(objective) is Objective.MAKESPAN:
        return float(plan.makespan)
    return float(plan.total_time)


def _opt(value: float | None) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def make_record(
    item: LoadedScenario,
    plan: Plan,
    units: Sequence[UnitState],
    *,
    tasks: int,
    repeat: int,
    wall_time: float,
    problems: list[str],
) -> RunRecord:
    return RunRecord(
        scenario=item.scenario.name,
        source=item.source,
        strategy=plan.strategy,
        objective=plan.objective,
        repeat=repeat,
        units=len(units),
        tasks=tasks,
        feasible=bool(plan.feasible),
        makespan=float(plan.makespan),
        total_time=float(plan.total_time),
        total_distance=float(plan.total_distance),
        objective_value=objective_value(plan, plan.objective),
        solve_time=float(plan.solve_time),
        wall_time=wall_time,
        assigned=len(plan.assignments),
        unassigned=len(plan.unassigned),
        bound=_opt(plan.bound),
        gap=_opt(plan.gap),
        problems=problems,
        notes=[str(n) for n in getattr(plan, "notes", [])],
        fallback=plan.fallback,
        precedence_makespan=_opt(plan.precedence_makespan),
        instantiation_loss=_opt(plan.instantiation_loss),
        lower_bound=_opt(plan.lower_bound),
    )


def add_ratios(records: Sequence[RunRecord]) -> None:
    """Fill ``ratio_to_nearest`` for records of one scenario (same objective and repeat)."""
    base = {(r.source, r.objective, r.repeat): r for r in records if r.strategy == BASELINE}
    for r in records:
        ref = base.get((r.source, r.objective, r.repeat))
        if ref is None or ref.unassigned != r.unassigned:
            r.ratio_to_nearest = None
        elif ref.objective_value > 0:
            r.ratio_to_nearest = r.objective_value / ref.objective_value
        else:
            r.ratio_to_nearest = 1.0 if r.objective_value == 0 else None
