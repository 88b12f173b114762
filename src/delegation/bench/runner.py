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

from delegation.allocation.strategies import Objective, resolve_strategy
from delegation.errors import DelegationError, InputError, InputProblem

if TYPE_CHECKING:
    from delegation.allocation import Plan
    from delegation.bench.executor import Executor
    from delegation.fleet import UnitState
    from delegation.scenario import Scenario
    from delegation.tst import TstNode

log = logging.getLogger(__name__)

#: File suffixes a scenario folder is searched for.
SCENARIO_SUFFIXES: tuple[str, ...] = (".yaml", ".yml", ".json")

#: The strategy every other one is compared with, unless ``--baseline`` says otherwise.
BASELINE = "nearest"

#: Strategies that share searches among units (DESIGN 3.11; ``nearest`` never does).
SPLITTERS: frozenset[str] = frozenset({"auction", "optimal"})


@dataclass(frozen=True)
class LoadedScenario:
    """A scenario with where it came from (a file path, or ``generated:<name>``), and the best
    known objective values where a standard instance has them (``bench.best_known``)."""

    source: str
    scenario: Scenario
    best_known: dict[str, float] | None = None


@dataclass(frozen=True, slots=True)
class ScenarioFailure:
    """A scenario that could not be read or planned, named by its file."""

    source: str
    message: str

    def __str__(self) -> str:
        if self.message.startswith(self.source):  # the loader already named the file
            return self.message
        return f"{self.source}: {self.message}"


@dataclass(frozen=True, slots=True)
class FailedRun:
    """A run that produced no plan (crash or run timeout), for the summary's failure counts."""

    source: str
    strategy: str
    objective: str
    repeat: int
    reason: str


@dataclass
class RunRecord:
    """One strategy x objective run on one scenario: the numbers the table, CSV and JSON show.

    ``objective_value`` is the plan's makespan or total time, as the objective asks;
    ``ratio_to_baseline`` divides it by the baseline's (``nearest`` unless ``--baseline``) on the
    same scenario, objective and repeat, and is None where the baseline did not run or the two
    plans leave different numbers of tasks unassigned (their objectives then measure different
    work). ``same_plan_as`` names an earlier strategy that returned exactly this plan on the same
    run (optimal keeping the auction's plan), so that it is never shown as its own result.
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
    ratio_to_baseline: float | None = None
    #: the best known objective value of this standard instance, and the gap to it
    best_known: float | None = None
    gap_to_best_known: float | None = None
    #: a digest of the plan (who does what, when), and the earlier strategy with the same plan
    plan_digest: str = ""
    same_plan_as: str | None = None
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
    #: searches shared among units (DESIGN 3.11): False for a ``--no-split`` comparison run;
    #: the largest shareable search's lower bound (every unit free at the start, s) and the
    #: makespan over it (None without a shareable search)
    split: bool = True
    search_bound: float | None = None
    vs_search_bound: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def label(self) -> str:
        """The strategy (``strategy`` already says ``--no-split``), with whose plan it returned
        when that was another's."""
        return self.strategy + (f" (= {self.same_plan_as})" if self.same_plan_as else "")


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
    #: the strategy the ratios divide by
    baseline: str = BASELINE
    #: runs that crashed or timed out (each also in ``failures``)
    failed: list[FailedRun] = field(default_factory=list)
    #: runs asked for, and whether Ctrl-C stopped the bench before all had finished
    total_runs: int = 0
    interrupted: bool = False

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
            InputProblem(
                kind, "", f"unknown {', '.join(map(repr, unknown))}; choose from {', '.join(known)}"
            )
        )
    if not chosen:
        raise InputError(InputProblem(kind, "", "choose at least one"))
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
    baseline: str | None = None,
    executor: Executor | None = None,
    no_split: bool = False,
) -> BenchResult:
    """Plan every scenario with every strategy x objective, ``repeat`` times; check every plan.

    With ``isolate`` each run happens in a child process (``bench.isolate``): a planner that
    crashes the process, or runs past ``run_timeout`` seconds, becomes a failure naming the file,
    strategy and objective, and the bench goes on. ``executor`` says where runs happen (default:
    here, one after another); the records are the same whichever runs them. Ctrl-C stops the
    bench and returns the runs that finished (``interrupted``). ``no_split`` adds, for each
    strategy that shares searches (``SPLITTERS``), a run with sharing off, as the comparison
    (its strategy reads ``auction --no-split``).
    """
    from delegation.allocation import OBJECTIVES, STRATEGIES
    from delegation.bench.executor import LocalExecutor

    strategies = [resolve_strategy(s) for s in strategies or list(STRATEGIES)]
    strategies = check_choice("strategies", strategies, STRATEGIES)
    objectives = check_choice("objectives", objectives or list(OBJECTIVES), OBJECTIVES)
    baseline = baseline or (BASELINE if BASELINE in strategies else strategies[0])
    if baseline not in strategies:
        raise InputError(InputProblem("baseline", "", f"{baseline!r} is not among the strategies "
                                 f"run ({', '.join(strategies)})"))
    if repeat < 1:
        raise InputError(InputProblem("repeat", "", f"must be at least 1, not {repeat}"))
    if not time_limit > 0:
        raise InputError(InputProblem("time-limit", "", f"must be > 0, not {time_limit}"))

    result = BenchResult(baseline=baseline)
    runs: list[dict[str, Any]] = []
    for item in scenarios:
        try:
            tree, units = item.scenario.tree(), item.scenario.units()
        except DelegationError as exc:
            result.failures.append(ScenarioFailure(item.source, str(exc)))
            continue
        result.scenarios[item.source] = (item.scenario, units)
        for rep, objective, strategy in itertools.product(range(repeat), objectives, strategies):
            for split in (True, False) if no_split and strategy in SPLITTERS else (True,):
                runs.append({"item": item, "tree": tree, "units": units, "strategy": strategy,
                             "objective": objective, "time_limit": time_limit,
                             "repeat": rep + 1, "split": split})
    result.total_runs = len(runs)
    executor = executor or LocalExecutor(isolate)
    outcomes: dict[int, Any] = {}
    if runs:
        executor.prepare(warm_up, strategies, objectives)
        try:
            for index, outcome in executor.run(run_one, runs, run_timeout):
                outcomes[index] = outcome
                if progress:
                    run = runs[index]
                    label = (f"{run['item'].scenario.name} {run['strategy']}/{run['objective']}"
                             + ("" if outcome.ok else ": failed"))
                    progress(len(outcomes), len(runs), label)
        except KeyboardInterrupt:
            result.interrupted = True
    _collect(result, runs, outcomes, run_timeout, keep_plans)
    return result


def _collect(result: BenchResult, runs: Sequence[dict[str, Any]], outcomes: dict[int, Any],
             run_timeout: float | None, keep_plans: bool) -> None:
    """Records in run order, scenario by scenario; an input error fails its whole scenario."""
    by_source: dict[str, list[int]] = {}
    for index, run in enumerate(runs):
        by_source.setdefault(run["item"].source, []).append(index)
    for source, indices in by_source.items():
        done = [(i, outcomes[i]) for i in indices if i in outcomes]
        refused = next((o.input_error for _, o in done if o.input_error is not None), None)
        if refused is not None:
            # plan_mission never raises for infeasibility; this is input it could not accept.
            result.failures.append(ScenarioFailure(source, refused))
            continue
        records: list[RunRecord] = []
        for i, outcome in done:
            run = runs[i]
            if not outcome.ok:
                why = outcome.crashed or f"stopped after {run_timeout:g} s (run timeout)"
                result.failed.append(FailedRun(source, run["strategy"], run["objective"],
                                               run["repeat"], why))
                result.failures.append(ScenarioFailure(
                    source, f"{run['strategy']}/{run['objective']} run {run['repeat']}: {why}"))
                continue
            record, plan = outcome.value
            records.append(record)
            if keep_plans and run["repeat"] == 1:
                result.plans[(source, record.strategy, run["objective"])] = plan
        add_ratios(records, result.baseline)
        mark_same_plans(records)
        result.records.extend(records)


def warm_up(strategies: Sequence[str], objectives: Sequence[str]) -> None:
    """Plan a tiny generated scenario once per strategy x objective, here, before measuring.

    The first plan of a process pays for lazy imports and solver start-up (measured: ~20 ms for
    nearest, ~170 ms for optimal); forked children inherit the warm state, so no run pays it.
    Plugins are imported (``resolve_strategy``) but not run here: only isolated runs may crash.
    """
    from delegation.allocation import plan_mission
    from delegation.allocation.strategies import BUILTIN_STRATEGIES
    from delegation.bench.generate import generate_scenario

    item = scenarios_from_dicts([generate_scenario(units=2, tasks=3, seed=0)])[0]
    tree, units = item.scenario.tree(), item.scenario.units()
    for strategy in [resolve_strategy(s) for s in strategies]:
        if strategy not in BUILTIN_STRATEGIES:
            continue
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
    split: bool = True,
) -> tuple[RunRecord, Plan]:
    """Plan once (``split``: searches may be shared), check the plan's invariants, and make its
    record."""
    from delegation.allocation import check_invariants, plan_mission
    from delegation.bench.team_search import team_bound
    from delegation.tst import leaves

    strategy = resolve_strategy(strategy)  # a module:function spec, on a Dask worker too
    started = time.perf_counter()
    plan = plan_mission(
        tree,
        units,
        strategy=strategy,
        objective=objective,
        time_limit=time_limit,
        new_uuid=counter_uuids(),
        split=split,
    )
    wall = time.perf_counter() - started
    problems = list(check_invariants(plan, tree, units))
    for problem in problems:
        log.error("%s %s/%s: invariant violated: %s", item.source, strategy, objective, problem)
    record = make_record(
        item, plan, units, tasks=len(leaves(tree)), repeat=repeat, wall_time=wall, problems=problems
    )
    record.search_bound = _opt(team_bound(tree, units))
    if record.search_bound and not plan.unassigned:
        record.vs_search_bound = record.makespan / record.search_bound
    if not split:
        record.split, record.strategy = False, f"{record.strategy} --no-split"
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


def plan_digest(plan: Plan) -> str:
    """A short digest of who does what, when: equal for equal plans of one tree."""
    import hashlib

    text = ";".join(
        f"{a.node_uuid}@{a.execunit}:{a.start:.6f}-{a.end:.6f}"
        for a in sorted(plan.assignments, key=lambda a: a.node_uuid)
    )
    return hashlib.sha1(text.encode()).hexdigest()[:12]


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
    value = objective_value(plan, plan.objective)
    best = (item.best_known or {}).get(plan.objective)
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
        objective_value=value,
        solve_time=float(plan.solve_time),
        wall_time=wall_time,
        assigned=plan.caller_counts()[0],
        unassigned=plan.caller_counts()[1],
        bound=_opt(plan.bound),
        gap=_opt(plan.gap),
        problems=problems,
        notes=[str(n) for n in getattr(plan, "notes", [])],
        best_known=best,
        gap_to_best_known=None if best is None or plan.unassigned else value / best - 1.0,
        plan_digest=plan_digest(plan),
        fallback=plan.fallback,
        precedence_makespan=_opt(plan.precedence_makespan),
        instantiation_loss=_opt(plan.instantiation_loss),
        lower_bound=_opt(plan.lower_bound),
    )


def add_ratios(records: Sequence[RunRecord], baseline: str = BASELINE) -> None:
    """Fill ``ratio_to_baseline`` for records of one scenario (same objective and repeat)."""
    base = {(r.source, r.objective, r.repeat): r for r in records if r.strategy == baseline}
    for r in records:
        ref = base.get((r.source, r.objective, r.repeat))
        if ref is None or ref.unassigned != r.unassigned:
            r.ratio_to_baseline = None
        elif ref.objective_value > 0:
            r.ratio_to_baseline = r.objective_value / ref.objective_value
        else:
            r.ratio_to_baseline = 1.0 if r.objective_value == 0 else None


def mark_same_plans(records: Sequence[RunRecord]) -> None:
    """``same_plan_as``: the first strategy (in run order) whose plan on the same scenario,
    objective and repeat is this very plan; such a result is not the strategy's own."""
    first: dict[tuple[str, str, int, str], str] = {}
    for r in records:
        key = (r.source, r.objective, r.repeat, r.plan_digest)
        owner = first.setdefault(key, r.strategy)
        r.same_plan_as = owner if owner != r.strategy and r.plan_digest else None
