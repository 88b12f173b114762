"""``delegation plan SCENARIO``: JSON is exactly docs/plan.md §1; table renders; errors are one
line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from delegation.cli import main

ROOT = Path(__file__).resolve().parents[1]
DEMO = str(ROOT / "scenarios" / "demo.yaml")

PLAN_KEYS = {"strategy", "objective", "feasible", "makespan", "total-time", "total-distance",
             "solve-time", "bound", "gap", "precedence-makespan", "instantiation-loss", "fallback",
             "assignments", "unassigned", "shared-searches", "tst", "notes"}
ASSIGNMENT_KEYS = {"node-uuid", "name", "execunit", "start", "end", "travel-time", "work-time",
                   "distance"}


@pytest.mark.parametrize("strategy", ["nearest", "auction", "optimal"])
def test_json_is_exactly_the_plan(strategy: str, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["plan", DEMO, "--strategy", strategy, "--objective", "total",
                 "--time-limit", "1", "--format", "json"])
    out = capsys.readouterr().out
    assert code == 0
    plan = json.loads(out)  # nothing else on stdout
    assert set(plan) == PLAN_KEYS
    assert plan["strategy"] == strategy and plan["objective"] == "total"
    assert plan["assignments"] and all(set(a) == ASSIGNMENT_KEYS for a in plan["assignments"])
    assert all(set(u) == {"node-uuid", "name", "reason"} for u in plan["unassigned"])
    assert plan["tst"]["common_params"]["execunit"] == "/op0"


def test_unassigned_tasks_are_listed_with_reasons(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["plan", str(ROOT / "scenarios" / "granso-impossible.yaml"), "--format", "json"])
    plan = json.loads(capsys.readouterr().out)
    assert code == 1  # an infeasible plan is printed, and the exit code says so
    assert plan["feasible"] is False
    assert plan["unassigned"] and all(u["reason"] for u in plan["unassigned"])


def test_table_format(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plan", DEMO, "--strategy", "auction"]) == 0
    out = capsys.readouterr().out
    assert "assignments" in out and "makespan" in out and "/dji0" in out


def test_table_says_when_optimal_kept_the_auctions_plan(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    # No unit can take the only vehicle task: optimal keeps the auction's plan and says so (the
    # plan is infeasible, so `plan` exits 1 after printing it).
    scenario = tmp_path / "one.yaml"
    scenario.write_text(
        "name: one\ndescription: one task nobody can take\nagents:\n"
        "  - {name: dji0, type: air, position: {latitude: 57.76, longitude: 16.68, altitude: 40},"
        " tasks: [search-area]}\n"
        "mission: {name: seq, children: [{name: move-to, params: {waypoint: "
        "{latitude: 57.761, longitude: 16.681, altitude: 40}}}]}\n")
    assert main(["plan", str(scenario), "--strategy", "optimal", "--time-limit", "1"]) == 1
    out = capsys.readouterr().out
    assert "optimal (= auction)" in out
    assert main(["plan", str(scenario), "--strategy", "optimal", "--time-limit", "1",
                 "--format", "json"]) == 1
    plan = json.loads(capsys.readouterr().out)
    assert plan["strategy"] == "optimal" and plan["fallback"] == "auction"


def test_unknown_strategy_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["plan", DEMO, "--strategy", "cheapest"])
    assert info.value.code == 2
    assert "invalid choice: 'cheapest'" in capsys.readouterr().err


def test_missing_file_is_one_clear_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["plan", str(tmp_path / "none.yaml")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "none.yaml" in err and "Traceback" not in err


def test_cli_choices_are_the_planners_names() -> None:
    import subprocess
    import sys

    from delegation.allocation import OBJECTIVES, STRATEGIES
    from delegation.cli.plan import OBJECTIVE_CHOICES, STRATEGY_CHOICES

    assert tuple(STRATEGY_CHOICES) == ("nearest", "auction", "optimal") == tuple(STRATEGIES)
    assert OBJECTIVE_CHOICES == ("makespan", "total") == tuple(OBJECTIVES)
    assert "--objective {makespan,total}" in _help(["plan", "--help"])
    # The names alone do not load the planner (numpy, OR-Tools): the CLI starts quickly.
    loaded = subprocess.run(
        [sys.executable, "-c", "import sys, delegation.cli.plan; print('numpy' in sys.modules)"],
        capture_output=True, text=True, check=True,
    ).stdout.strip()
    assert loaded == "False"


def _help(argv: list[str]) -> str:
    import contextlib
    import io

    from delegation.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        main(argv)
    return out.getvalue()


def test_demo_rejects_an_unknown_strategy_before_starting_anything(capsys) -> None:
    import pytest

    from delegation.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["demo", "--strategy", "bogus"])
    assert exc.value.code == 2
    assert "invalid choice: 'bogus'" in capsys.readouterr().err


def test_plan_runs_optimal_on_both_cores_and_leaves_nothing_behind(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`delegation plan` is a composition root: its `optimal` runs the helper search on the
    second core (the note says so), and the in-process call puts the one-core default back."""
    import os

    import yaml

    from delegation.allocation.optimal.parallel import second_core
    from delegation.bench.generate import generate_scenario

    if (os.cpu_count() or 1) < 2:
        pytest.skip("one CPU: optimal searches on one core by design")
    path = tmp_path / "mixed.yaml"
    path.write_text(yaml.safe_dump(generate_scenario(units=10, tasks=30, seed=0,
                                                     structure="mixed")))
    assert not second_core()
    code = main(["plan", str(path), "--strategy", "optimal", "--time-limit", "2",
                 "--format", "json"])
    plan = json.loads(capsys.readouterr().out)
    assert code == 0
    assert any("on the second core" in note for note in plan["notes"]), plan["notes"]
    assert not second_core()
