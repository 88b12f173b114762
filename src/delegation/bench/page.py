"""A markdown results page (``docs/results.md``) made from bench records, so it never goes stale.

Everything numeric on the page comes from the records of one ``delegation bench`` run; the scale
section embeds the sweep's PNG and summary when they sit next to the page (``--scale --out`` the
page's folder). The prose says how to read the numbers, never what they are.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from delegation.bench.report import SUMMARY_NOTE, markdown_columns, markdown_table
from delegation.bench.runner import BASELINE, RunRecord


def summary_table(records: Sequence[RunRecord], baseline: str = BASELINE) -> str:
    """The summary across scenarios (``bench.summary``), as the bench prints and writes it."""
    from delegation.bench.report import summary_markdown
    from delegation.bench.runner import BenchResult
    from delegation.bench.summary import summarise


    return summary_markdown(summarise(BenchResult(records=list(records), baseline=baseline)))


def _rel(target: Path, page: Path) -> str:
    return Path(os.path.relpath(target, page.parent)).as_posix()


def write_results_page(
    records: Sequence[RunRecord],
    page: str | Path,
    *,
    plots_dir: str | Path | None,
    command: str,
    time_limit: float,
    baseline: str = BASELINE,
) -> Path:
    """Write the page's markdown to ``page``; ``plots_dir`` holds the bar charts
    (``<scenario>-objective.png``), linked relative to the page."""
    page = Path(page)
    parts = [
        "# Allocation strategies: results",
        "",
        "Every number on this page was produced by `delegation bench`; regenerate the page with",
        "",
        "```sh",
        command,
        f"delegation bench --scale --out {page.parent.as_posix()}",
        "```",
        "",
        "(the second command writes `scale.png`, `scale.csv` and `scale.md` next to this page).",
        f"Each strategy planned each scenario once per objective; `optimal` had a time limit of "
        f"{time_limit:g} s. {_checks(records)}",
        "",
        "## Summary",
        "",
        f"Ratios are the plan's mean objective divided by `{baseline}`'s on the same scenario "
        "(below 1 is better; geometric mean over scenarios), over the scenarios where both "
        "plans leave the same tasks unassigned.",
        "",
        summary_table(records, baseline),
        "",
        SUMMARY_NOTE + ".",
        "",
        "## Every run",
        "",
        "makespan: when the last task ends (units with a home: when back home); total time: sum "
        "of all units' travel and work; distance: the same in metres; solve: the planner's own "
        "time; bound/gap: where CP-SAT proved a lower bound; vs baseline: the objective "
        f"(makespan or total time, as planned for) relative to `{baseline}`'s; `a (= b)`: "
        "a returned b's very plan.",
        "",
        markdown_table(records, markdown_columns(records)),
        "",
    ]
    if plots_dir is not None:
        parts += _chart_links(records, Path(plots_dir), page)
    parts += _scale_section(page)
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text("\n".join(parts), encoding="utf-8")
    return page


def _checks(records: Sequence[RunRecord]) -> str:
    """The sentence on the planner's invariant checks (how many plans failed them)."""
    violated = [r for r in records if r.problems]
    if violated:
        return (
            f"**{len(violated)} of {len(records)} plans failed the planner's invariant checks** "
            "(`check_invariants`): see the `checks` column."
        )
    return f"All {len(records)} plans passed the planner's invariant checks (`check_invariants`)."


def _chart_links(records: Sequence[RunRecord], plots_dir: Path, page: Path) -> list[str]:
    """The section linking each scenario's bar chart found in ``plots_dir``."""
    lines = ["## Objective per strategy, per scenario", ""]
    for name, units, tasks in dict.fromkeys((r.scenario, r.units, r.tasks) for r in records):
        png = plots_dir / f"{name}-objective.png"
        if png.exists():
            lines.append(f"- [{name}]({_rel(png, page)}) ({units} units, {tasks} tasks)")
    return [*lines, ""]


def _scale_section(page: Path) -> list[str]:
    """The scale sweep's section when its PNG (and summary) sit next to the page, else none."""
    scale_png = page.parent / "scale.png"
    scale_md = page.parent / "scale.md"
    if not scale_png.exists():
        return []
    lines = [
        "## Scale",
        "",
        "Generated scenarios (as `delegation bench --generate` makes them) on a grid of "
        "units x tasks, one scenario per cell shared by all strategies. Left: wall time per "
        "plan; a strategy that exceeds the budget is stopped there, and larger cells (at "
        "least as many units and tasks) are skipped for it. Right: objective relative to the "
        "best strategy on the same scenario; *strictly best* counts the cells where a "
        "strategy beat every other one. Raw numbers, with what each strategy reported doing "
        "(column `notes`: e.g. whether CP-SAT ran or the auction's plan was kept): "
        "[scale.csv](scale.csv).",
        "",
        f"![scale sweep]({_rel(scale_png, page)})",
        "",
    ]
    if scale_md.exists():
        lines += [scale_md.read_text(encoding="utf-8").strip(), ""]
    return lines
