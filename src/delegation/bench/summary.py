"""Bench results summarised: repeats per scenario x strategy, and strategies across scenarios.

A strategy whose plan is another's (``RunRecord.same_plan_as``: optimal keeping the auction's)
is labelled ``optimal (= auction)`` and never counts as a win: it did not find that plan.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

from delegation.bench.runner import BenchResult, RunRecord
from delegation.bench.stats import describe, geomean

#: Relative tolerance for two objective values to count as tied.
TIE = 1e-6


def strategy_label(strategy: str, runs: Sequence[RunRecord]) -> str:
    """``strategy``, or ``strategy (= other)`` when its plan was another strategy's in every
    run (``(= other in k of n)`` in some)."""
    same = [r.same_plan_as for r in runs if r.same_plan_as]
    if not same:
        return strategy
    other = max(set(same), key=same.count)
    if len(same) == len(runs):
        return f"{strategy} (= {other})"
    return f"{strategy} (= {other} in {len(same)} of {len(runs)})"


@dataclass
class Aggregate:
    """One scenario x objective x strategy over its repeats."""

    scenario: str
    source: str
    objective: str
    strategy: str
    label: str
    runs: int
    mean: float
    median: float
    std: float | None
    ci95_low: float | None
    ci95_high: float | None
    min: float
    max: float
    solve_time_mean: float
    unassigned: int
    feasible: bool
    bound: float | None
    ratio_to_baseline: float | None
    best_known: float | None
    gap_to_best_known: float | None
    same_plan_as: str | None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


AGGREGATE_FIELDS: tuple[str, ...] = tuple(Aggregate.__dataclass_fields__)


def aggregate(records: Sequence[RunRecord]) -> list[Aggregate]:
    """One row per scenario x objective x strategy, in record order."""
    groups: dict[tuple[str, str, str], list[RunRecord]] = {}
    for r in records:
        groups.setdefault((r.source, r.objective, r.strategy), []).append(r)
    out = []
    for (source, objective, strategy), runs in groups.items():
        stats = describe([r.objective_value for r in runs])
        ratios = [r.ratio_to_baseline for r in runs if r.ratio_to_baseline is not None]
        gaps = [r.gap_to_best_known for r in runs if r.gap_to_best_known is not None]
        bounds = [r.bound for r in runs if r.bound is not None]
        same = [r.same_plan_as for r in runs]
        out.append(Aggregate(
            scenario=runs[0].scenario, source=source, objective=objective, strategy=strategy,
            label=strategy_label(strategy, runs), runs=stats.n, mean=stats.mean,
            median=stats.median, std=stats.std, ci95_low=stats.ci_low, ci95_high=stats.ci_high,
            min=stats.min, max=stats.max,
            solve_time_mean=sum(r.solve_time for r in runs) / len(runs),
            unassigned=max(r.unassigned for r in runs),
            feasible=all(r.feasible for r in runs),
            bound=max(bounds) if bounds else None,
            ratio_to_baseline=geomean(ratios) if len(ratios) == len(runs) else None,
            best_known=runs[0].best_known,
            gap_to_best_known=sum(gaps) / len(gaps) if len(gaps) == len(runs) else None,
            same_plan_as=same[0] if same[0] and all(s == same[0] for s in same) else None,
        ))
    return out


@dataclass
class StrategySummary:
    """One strategy x objective across scenarios."""

    objective: str
    strategy: str
    baseline: str
    scenarios: int
    #: geometric mean over scenarios of (mean objective / the baseline's), where comparable
    geomean_ratio: float | None
    compared: int
    #: scenarios where it alone had the lowest mean objective (fewest unassigned first)
    wins: int
    ties: int
    #: scenarios where its plan was another strategy's (never a win)
    same_plan: int
    infeasible: int
    failed_runs: int

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


SUMMARY_FIELDS: tuple[str, ...] = tuple(StrategySummary.__dataclass_fields__)


def summarise(result: BenchResult) -> list[StrategySummary]:
    """Per objective x strategy: ratio to the baseline, wins, ties, copies, failures."""
    rows = aggregate(result.records)
    objectives = list(dict.fromkeys(
        [a.objective for a in rows] + [f.objective for f in result.failed]))
    strategies = list(dict.fromkeys(
        [a.strategy for a in rows] + [f.strategy for f in result.failed]))
    out = []
    for objective in objectives:
        mine = [a for a in rows if a.objective == objective]
        verdict = _verdicts(mine)
        for strategy in strategies:
            own = [a for a in mine if a.strategy == strategy]
            failed = [f for f in result.failed if f.strategy == strategy
                      and f.objective == objective]
            if not own and not failed:
                continue
            ratios = [a.ratio_to_baseline for a in own if a.ratio_to_baseline is not None]
            out.append(StrategySummary(
                objective=objective, strategy=strategy, baseline=result.baseline,
                scenarios=len(own), geomean_ratio=geomean(ratios), compared=len(ratios),
                wins=sum(1 for a in own if verdict.get((a.source, a.strategy)) == "win"),
                ties=sum(1 for a in own if verdict.get((a.source, a.strategy)) == "tie"),
                same_plan=sum(1 for a in own if a.same_plan_as),
                infeasible=sum(1 for a in own if not a.feasible),
                failed_runs=len(failed),
            ))
    return out


def _verdicts(rows: Sequence[Aggregate]) -> dict[tuple[str, str], str]:
    """(source, strategy) -> "win" | "tie" among one objective's rows; a copied plan is out."""
    out: dict[tuple[str, str], str] = {}
    for source in dict.fromkeys(a.source for a in rows):
        own = [a for a in rows if a.source == source and not a.same_plan_as]
        if len(own) < 2:
            continue
        fewest = min(a.unassigned for a in own)
        best = min(a.mean for a in own if a.unassigned == fewest)
        top = [a for a in own if a.unassigned == fewest and a.mean <= best * (1 + TIE) + TIE]
        for a in top:
            out[(source, a.strategy)] = "win" if len(top) == 1 else "tie"
    return out
