"""Statistics people can check: repeats summarised, the summary across scenarios (copied plans
never win), the paired comparison of two result files, and provenance in every result."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from delegation.bench.compare import compare_files
from delegation.bench.runner import BenchResult, FailedRun, RunRecord, mark_same_plans
from delegation.bench.stats import describe, geomean, sign_test, t95, wilcoxon
from delegation.bench.summary import aggregate, summarise
from delegation.cli import main


def test_describe_gives_the_students_t_interval() -> None:
    s = describe([1.0, 2.0, 3.0, 4.0])
    assert (s.n, s.mean, s.median) == (4, 2.5, 2.5)
    assert s.std == pytest.approx(math.sqrt(5 / 3))
    half = 3.182 * math.sqrt(5 / 3) / 2  # t(0.975, 3) = 3.182
    assert (s.ci_low, s.ci_high) == (pytest.approx(2.5 - half), pytest.approx(2.5 + half))
    one = describe([7.0])
    assert one.std is None and one.ci_low is None and one.mean == 7.0
    assert t95(1) == 12.706 and t95(35) == 2.042 and t95(1000) == 1.960


def test_paired_tests_match_their_textbook_values() -> None:
    # Exact Wilcoxon: W- = 1 + 3 = 4 of n = 8 -> 7 of 256 sign patterns at or below, two-sided.
    assert wilcoxon([0.6, -0.2, 0.9, 1.1, -0.4, 0.7, 0.3, 0.8]) == pytest.approx(14 / 256)
    # All nine differences positive: 2 / 2**9.
    assert wilcoxon([1.83, 0.5, 1.62, 2.48, 1.68, 1.88, 1.55, 3.06, 1.3]) == pytest.approx(2 / 512)
    assert sign_test([1, 1, 1, 1, 1, -1]) == pytest.approx(2 * 7 / 64)
    assert wilcoxon([0.0, 0.0]) is None and sign_test([]) is None
    # Large samples with ties use the normal approximation and stay a probability.
    p = wilcoxon([1.0] * 20 + [-1.0] * 10 + [2.0] * 10)
    assert p is not None and 0 < p < 0.05
    assert geomean([2.0, 8.0]) == pytest.approx(4.0)


def _record(source: str, strategy: str, value: float, *, repeat: int = 1, digest: str = "",
            unassigned: int = 0) -> RunRecord:
    return RunRecord(
        scenario=source, source=source, strategy=strategy, objective="makespan", repeat=repeat,
        units=2, tasks=3, feasible=True, makespan=value, total_time=value, total_distance=value,
        objective_value=value, solve_time=0.01, wall_time=0.02, assigned=3,
        unassigned=unassigned, plan_digest=digest or f"{source}-{strategy}-{value}",
    )


def test_a_copied_plan_is_labelled_and_never_wins() -> None:
    records = [
        _record("a", "nearest", 10.0), _record("a", "auction", 6.0, digest="same"),
        _record("a", "optimal", 6.0, digest="same"),
        _record("b", "nearest", 10.0), _record("b", "auction", 8.0),
        _record("b", "optimal", 5.0),
    ]
    mark_same_plans(records)
    assert records[2].same_plan_as == "auction" and records[2].label == "optimal (= auction)"
    assert records[1].same_plan_as is None
    for r in records:
        r.ratio_to_baseline = r.objective_value / 10.0
    result = BenchResult(records=records, baseline="nearest",
                         failed=[FailedRun("c", "optimal", "makespan", 1, "crashed")])
    rows = {r.strategy: r for r in summarise(result)}
    assert rows["auction"].wins == 1  # scenario a: optimal only copied the auction's plan
    assert rows["optimal"].wins == 1 and rows["optimal"].same_plan == 1
    assert rows["optimal"].failed_runs == 1
    assert rows["optimal"].geomean_ratio == pytest.approx(math.sqrt(0.6 * 0.5))
    labels = {a.strategy: a.label for a in aggregate(records) if a.source == "a"}
    assert labels["optimal"] == "optimal (= auction)"


def test_aggregates_summarise_the_repeats() -> None:
    records = [_record("a", "auction", v, repeat=i + 1) for i, v in enumerate((4.0, 6.0, 8.0))]
    [row] = aggregate(records)
    assert (row.runs, row.mean, row.median, row.min, row.max) == (3, 6.0, 6.0, 4.0, 8.0)
    assert row.std == pytest.approx(2.0)
    assert row.ci95_high - row.mean == pytest.approx(4.303 * 2.0 / math.sqrt(3))


def _bench(out: Path, *extra: str) -> int:
    return main(["bench", "--generate", "--count", "3", "--units", "2", "--tasks", "5",
                 "--strategies", "nearest,auction", "--objectives", "makespan",
                 "--in-process", "--no-plots", "--out", str(out), *extra])


def test_results_carry_provenance_aggregates_and_summary(tmp_path: Path) -> None:
    assert _bench(tmp_path / "a", "--repeat", "2", "--baseline", "auction") == 0
    data = json.loads((tmp_path / "a" / "results.json").read_text())
    prov = data["meta"]["provenance"]
    for key in ("delegation", "commit", "python", "ortools", "cpu_count", "date", "command"):
        assert key in prov
    assert prov["command"].startswith("delegation bench --generate --count 3")
    assert data["meta"]["baseline"] == "auction"
    assert len(data["aggregates"]) == 3 * 2 and data["aggregates"][0]["runs"] == 2
    assert {s["strategy"] for s in data["summary"]} == {"nearest", "auction"}
    auction = next(s for s in data["summary"] if s["strategy"] == "auction")
    assert auction["geomean_ratio"] == 1.0
    for name in ("aggregates.csv", "summary.csv", "results.md"):
        assert (tmp_path / "a" / name).stat().st_size > 0


def test_compare_pairs_two_result_files(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert _bench(tmp_path / "a") == 0
    assert _bench(tmp_path / "b") == 0
    data = json.loads((tmp_path / "b" / "results.json").read_text())
    for r in data["records"]:
        if r["strategy"] == "auction":
            r["objective_value"] *= 0.5  # B's auction twice as good on every scenario
    (tmp_path / "b" / "results.json").write_text(json.dumps(data))
    c = compare_files(tmp_path / "a" / "results.json", tmp_path / "b" / "results.json")
    groups = {g.strategy: g for g in c.groups}
    assert groups["nearest"].equal == 3 and groups["nearest"].geomean_ratio == pytest.approx(1)
    assert groups["auction"].b_better == 3 and groups["auction"].geomean_ratio == pytest.approx(.5)
    assert groups["auction"].sign_p == pytest.approx(0.25)
    assert groups["all"].pairs == 6
    capsys.readouterr()
    code = main(["bench", "compare", str(tmp_path / "a" / "results.json"),
                 str(tmp_path / "b" / "results.json")])
    out = capsys.readouterr().out
    assert code == 0 and "Wilcoxon p" in out and "0.5000" in out and "commit" in out


def test_compare_refuses_files_that_are_not_results(tmp_path: Path) -> None:
    bad = tmp_path / "x.json"
    bad.write_text("{}")
    assert main(["bench", "compare", str(bad), str(bad)]) == 1
    assert main(["bench", "compare", str(bad)]) == 1


def test_scale_sweep_shows_a_copied_plan_and_never_counts_it_best() -> None:
    from delegation.bench.generate import GeneratorOptions
    from delegation.bench.scale import run_scale, summary_rows

    records = run_scale(["auction", "optimal"], units=[2], tasks=[3], budget=60.0,
                        time_limit=1.0, generator=GeneratorOptions(seed=1), isolate=False)
    by = {r.strategy: r for r in records}
    assert by["optimal"].plan_digest == by["auction"].plan_digest  # CP-SAT kept this plan
    assert by["optimal"].same_plan_as == "auction" and by["auction"].same_plan_as is None
    rows = {row["strategy"]: row for row in summary_rows(records)}
    assert rows["optimal"]["copied"] == 1 and rows["optimal"]["strictly_best"] == 0
    assert rows["auction"]["strictly_best"] == 0  # nobody else planned: nothing was beaten
