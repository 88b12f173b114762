"""``delegation bench compare A B``: two results.json compared run by run.

Runs pair up by (scenario source, strategy, objective, repeat); a pair counts only when both
plans left the same number of tasks unassigned (otherwise their objectives measure different
work). Per strategy x objective and over all pairs: the geometric mean of B / A, how often each
was better, and two-sided p-values of the Wilcoxon signed-rank test (on log B - log A) and of
the sign test. The provenance of both files is printed with them.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.table import Table

from delegation.bench.stats import geomean, sign_test, wilcoxon
from delegation.errors import InputError, InputProblem

#: Relative difference below which a pair counts as equal.
EQUAL = 1e-9


@dataclass
class PairGroup:
    """The pairs of one strategy x objective (or ``all``)."""

    strategy: str
    objective: str
    pairs: int
    geomean_ratio: float | None
    b_better: int
    a_better: int
    equal: int
    wilcoxon_p: float | None
    sign_p: float | None


@dataclass
class Comparison:
    a: Path
    b: Path
    groups: list[PairGroup]
    provenance: tuple[dict[str, Any], dict[str, Any]]
    unpaired: tuple[int, int]
    notes: list[str] = field(default_factory=list)


def _records(path: Path) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(InputProblem(
            str(path), "", f"cannot read: {exc.strerror or exc}")) from None
    except ValueError as exc:
        raise InputError(InputProblem(str(path), "", f"not JSON: {exc}")) from None
    if not isinstance(data, dict) or not isinstance(data.get("records"), list):
        raise InputError(InputProblem(str(path), "records", "not a bench results.json"))
    meta = data.get("meta") or {}
    return data["records"], meta.get("provenance") or {}


def _key(r: dict[str, Any]) -> tuple[str, str, str, int]:
    return (str(r["source"]), str(r["strategy"]), str(r["objective"]), int(r["repeat"]))


def _group(strategy: str, objective: str, pairs: list[tuple[float, float]]) -> PairGroup:
    positive = [(a, b) for a, b in pairs if a > 0 and b > 0]
    logs = [math.log(b) - math.log(a) for a, b in positive]
    diffs = [d if abs(d) > EQUAL else 0.0 for d in logs]
    return PairGroup(
        strategy, objective, len(pairs),
        geomean([b / a for a, b in positive]) if positive else None,
        b_better=sum(1 for d in diffs if d < 0), a_better=sum(1 for d in diffs if d > 0),
        equal=sum(1 for d in diffs if d == 0),
        wilcoxon_p=wilcoxon(diffs), sign_p=sign_test(diffs),
    )


def compare_files(a: Path, b: Path) -> Comparison:
    records_a, prov_a = _records(a)
    records_b, prov_b = _records(b)
    by_a = {_key(r): r for r in records_a}
    by_b = {_key(r): r for r in records_b}
    common = [k for k in by_a if k in by_b]
    if not common:
        raise InputError(InputProblem("bench compare", "", f"{a} and {b} have no run in common "
                                 "(same scenario source, strategy, objective and repeat)"))
    groups: dict[tuple[str, str], list[tuple[float, float]]] = {}
    skipped = 0
    for k in common:
        ra, rb = by_a[k], by_b[k]
        if ra["unassigned"] != rb["unassigned"]:
            skipped += 1
            continue
        groups.setdefault((k[1], k[2]), []).append(
            (float(ra["objective_value"]), float(rb["objective_value"])))
    out = [_group(s, o, p) for (s, o), p in groups.items()]
    everything = [p for ps in groups.values() for p in ps]
    if len(groups) > 1:
        out.append(_group("all", "all", everything))
    notes = [
        "ratio: geometric mean of B / A over the pairs (< 1: B lower, i.e. better); p: two-sided "
        "Wilcoxon signed-rank and sign test on log(B / A); equal pairs are dropped by both",
    ]
    if skipped:
        notes.append(f"{skipped} pair(s) left out: different numbers of tasks unassigned")
    for name, path, prov in (("A", a, prov_a), ("B", b, prov_b)):
        notes.append(f"{name}: {path}: " + (", ".join(f"{k} {prov[k]}" for k in (
            "delegation", "commit", "ortools", "python", "cpu_count", "date") if k in prov)
            or "no provenance recorded"))
    return Comparison(a, b, out, (prov_a, prov_b),
                      (len(by_a) - len(common), len(by_b) - len(common)), notes)


def _p(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"


def comparison_table(c: Comparison) -> list[Table]:
    from delegation.bench.report import compact_table

    table = compact_table(f"[bold]B / A[/bold]  A = {c.a}  B = {c.b}")
    for header, right in (("strategy", False), ("objective", False), ("pairs", True),
                          ("ratio B/A", True), ("B better", True), ("A better", True),
                          ("equal", True), ("Wilcoxon p", True), ("sign p", True)):
        table.add_column(header, justify="right" if right else "left")
    for g in c.groups:
        table.add_row(g.strategy, g.objective, str(g.pairs),
                      "-" if g.geomean_ratio is None else f"{g.geomean_ratio:.4f}",
                      str(g.b_better), str(g.a_better), str(g.equal), _p(g.wilcoxon_p),
                      _p(g.sign_p))
    if any(c.unpaired):
        table.caption = f"runs without a partner: A {c.unpaired[0]}, B {c.unpaired[1]}"
    return [table]
