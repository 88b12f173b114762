"""``delegation bench``: compare allocation strategies on scenario files or generated scenarios.

Modes: scenario files/folders and TSPLIB instances (``--tsplib``) (tables, ``--out``
CSV/JSON/PNGs), ``--generate`` (random scenarios from a seed; ``--save`` writes them as YAML),
``--scale`` (a units x tasks sweep with a time budget, written as CSV + PNG), and
``bench compare A B`` (a paired comparison of two results.json). Runs happen here or on a Dask
cluster (``--executor dask``). The library does the work; this module parses and renders.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from delegation.allocation import OBJECTIVES, STRATEGIES
from delegation.errors import InputError, InputProblem

if TYPE_CHECKING:
    from delegation.bench.generate import GeneratorOptions
    from delegation.bench.runner import BenchResult, LoadedScenario, ScenarioFailure
    from delegation.bench.scale import ScaleRecord


#: ``--units``/``--tasks`` when not given, for ``--generate`` and (units) for ``--tsplib``;
#: ``--scale`` sweeps the grid of `delegation.bench.scale` (named in the help, not imported: it
#: loads numpy, and ``--help`` stays fast).
GENERATE_UNITS: tuple[int, ...] = (5,)
GENERATE_TASKS: tuple[int, ...] = (20,)
TSPLIB_UNITS: tuple[int, ...] = (3,)


def _words(text: str) -> list[str]:
    return [w.strip() for w in text.split(",") if w.strip()]


def _ints(text: str) -> list[int]:
    try:
        return [int(w) for w in _words(text)]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, not {text!r}"
        ) from None


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "bench",
        help="benchmark allocation strategies on scenarios",
        description=(
            "Run every chosen strategy x objective on every scenario (files, folders, --tsplib "
            "instances or --generate'd), report makespan, total time, distance, solve time, "
            "unassigned tasks, bound/gap, the ratio to the baseline and a summary across "
            "scenarios; --scale sweeps units x tasks instead; 'bench compare A.json B.json' "
            "compares two results in pairs. Ctrl-C writes the runs that finished and exits 130."
        ),
    )
    parser.add_argument(
        "scenarios",
        nargs="*",
        metavar="SCENARIO",
        help="scenario files (YAML/JSON) or folders of them",
    )
    _strategy_options(parser)
    _output_options(parser)
    _runner_options(parser)
    _generated_scenario_options(parser)
    _scale_options(parser)
    parser.set_defaults(func=run)


def _strategy_options(parser: argparse.ArgumentParser) -> None:
    """Which strategies and objectives run, how often, against which baseline."""
    parser.add_argument(
        "--strategies",
        type=_words,
        default=None,
        help=f"comma-separated names ({','.join(STRATEGIES)}, installed plugins) or "
        "package.module:function specs (default: every registered strategy)",
    )
    parser.add_argument(
        "--baseline",
        default=None,
        help="the strategy ratios are taken to (default: nearest, else the first strategy)",
    )
    parser.add_argument(
        "--objectives",
        type=_words,
        default=None,
        help=f"comma-separated (default: {','.join(OBJECTIVES)}; --scale: makespan)",
    )
    parser.add_argument(
        "--repeat", type=int, default=1, help="runs of each combination (default 1)"
    )
    parser.add_argument(
        "--time-limit",
        type=float,
        default=5.0,
        help="seconds for strategies that search (optimal); default 5",
    )


def _output_options(parser: argparse.ArgumentParser) -> None:
    """Where results go and which plots are drawn."""
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="folder for results.csv/.json/.md, aggregates.csv, summary.csv and PNG plots "
        "(--scale: scale.csv, scale.png, scale.md, default bench-out; otherwise no files "
        "without --out)",
    )
    parser.add_argument("--no-plots", action="store_true", help="write no PNGs")
    parser.add_argument(
        "--no-maps", action="store_true", help="bar charts only, no route map per strategy"
    )
    parser.add_argument(
        "--page",
        type=Path,
        default=None,
        help="also write a markdown results page here (e.g. docs/results.md); it embeds "
        "scale.png/scale.md found next to it (from --scale --out that folder)",
    )


def _runner_options(parser: argparse.ArgumentParser) -> None:
    """How runs are isolated and where they execute (child processes, Dask), TSPLIB input."""
    parser.add_argument(
        "--in-process",
        action="store_true",
        help="plan in this process (default: each run in a child process, so that a planner "
        "crash or a run past --run-timeout costs one run, not the whole bench)",
    )
    parser.add_argument(
        "--run-timeout",
        type=float,
        default=None,
        help="stop a run after this many seconds and report it as failed (not with --in-process)",
    )
    parser.add_argument(
        "--tsplib",
        type=Path,
        action="append",
        default=[],
        metavar="FILE",
        help="a TSPLIB file as an mTSP (depot node 1, homes at the depot, 1 m/s) with --units "
        "units each (repeatable; --units 3,5 makes one scenario per count)",
    )
    parser.add_argument(
        "--executor",
        choices=("local", "dask"),
        default="local",
        help="where runs happen: here (default) or as tasks on a Dask cluster",
    )
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="Dask scheduler, e.g. tcp://10.0.0.5:8786 (default: a local cluster on 127.0.0.1)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        help="worker processes of the local Dask cluster (default: CPU count)",
    )
    parser.add_argument(
        "--no-gantt", action="store_true", help="no Gantt chart per strategy"
    )
    parser.add_argument(
        "--max-map-tasks",
        type=int,
        default=150,
        help="draw route maps only for scenarios with at most this many tasks",
    )



def _generated_scenario_options(parser: argparse.ArgumentParser) -> None:
    """Generated scenarios (--generate, and the --scale grid)."""
    gen = parser.add_argument_group("generated scenarios (--generate, and the --scale grid)")
    gen.add_argument("--generate", action="store_true", help="benchmark random scenarios")
    gen.add_argument(
        "--count",
        type=int,
        default=1,
        help="scenarios per size, seeds SEED, SEED+1, ... (default 1)",
    )
    gen.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    _grid_axis(gen, "units", GENERATE_UNITS, scale=(5, 20, 50, 200))
    _grid_axis(gen, "tasks", GENERATE_TASKS, scale=(10, 30, 100, 300, 1000))
    gen.add_argument(
        "--site", default="granso", help="granso, motala or linkoping (default granso)"
    )
    gen.add_argument(
        "--mix",
        default=None,
        help="task types and weights, e.g. move-to=2,search-area=1 (default: all five equally)",
    )
    gen.add_argument("--structure", default="mixed", help="mixed (conc of seqs), conc or seq")
    gen.add_argument(
        "--radius", type=float, default=2000.0, help="metres around the site (default 2000)"
    )
    gen.add_argument("--homes", action="store_true", help="units return home (closed tours)")
    gen.add_argument(
        "--save", type=Path, default=None, help="write the generated scenarios as YAML here"
    )
    gen.add_argument(
        "--family", default="mixed", choices=("mixed", "team-search"),
        help="mixed (random tasks, default) or team-search (one free search over a concave "
        "area of 0.2-4 km2, 3-6 heterogeneous units, every third an endurance case; --count "
        "cases from --seed; --units/--tasks/--mix/--structure/--radius do not apply)",
    )
    gen.add_argument(
        "--no-split", action="store_true",
        help="also run auction and optimal with searches never shared, as the comparison "
        "('auction --no-split')",
    )


def _grid_axis(gen: Any, axis: str, default: Sequence[int], scale: Sequence[int]) -> None:
    """``--units`` or ``--tasks``: one axis of the grid of generated scenarios, ``default``
    without ``--scale``, ``scale`` (the sweep's own grid, said in the help) with it."""
    gen.add_argument(
        f"--{axis}",
        type=_ints,
        default=None,
        help=f"{axis} per scenario, comma-separated (default {_listed(default)}; --scale: "
        f"{_listed(scale)})",
    )


def _listed(values: Sequence[int]) -> str:
    """``5,20,50``: a comma-separated axis as the flags take it."""
    return ",".join(map(str, values))


def _scale_options(parser: argparse.ArgumentParser) -> None:
    """The units x tasks sweep (--scale)."""
    scale = parser.add_argument_group("scale sweep (--scale)")
    scale.add_argument("--scale", action="store_true", help="sweep a grid of units x tasks")
    scale.add_argument(
        "--budget",
        type=float,
        default=None,
        help="seconds per plan; a strategy that exceeds it skips larger sizes (default 20)",
    )


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    console = Console()
    if not console.is_terminal:
        console = Console(width=200)  # piped or captured: the whole table, unwrapped
    err = Console(stderr=True, soft_wrap=True)
    if args.in_process and args.run_timeout is not None:
        raise InputError(
            InputProblem("bench", "--run-timeout", "needs child processes: drop --in-process")
        )
    if args.scenarios[:1] == ["compare"]:
        return _run_compare(args, console)
    if args.executor != "dask" and (args.scheduler or args.workers):
        raise InputError(InputProblem("bench", "--scheduler", "needs --executor dask"))
    if args.scale:
        if args.scenarios or args.page or args.save or args.tsplib:
            raise InputError(
                InputProblem(
                    "bench", "--scale",
                    "generates its own scenarios: no SCENARIO, --tsplib, --page, --save",
                )
            )
        return _run_scale(args, console, err)
    return _run_bench(args, console, err)


@contextmanager
def _progress(err: Any, description: str) -> Iterator[Callable[[int, int, str], None]]:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.fields[label]}"),
        console=err,
        transient=True,
    ) as bar:
        task = bar.add_task(description, total=None, label="")

        def update(done: int, total: int, label: str) -> None:
            bar.update(task, completed=done, total=total, label=label)

        yield update


def _generator_options(args: argparse.Namespace, units: int, tasks: int, seed: int) -> Any:
    from delegation.bench.generate import GeneratorOptions, parse_mix

    extra: dict[str, Any] = {}
    if args.mix:
        extra["mix"] = parse_mix(args.mix)
    return GeneratorOptions(
        units=units,
        tasks=tasks,
        site=args.site,
        seed=seed,
        structure=args.structure,
        radius=args.radius,
        homes=args.homes,
        family=getattr(args, "family", "mixed"),
        **extra,
    )


def _generated(args: argparse.Namespace) -> list[dict[str, Any]]:
    from delegation.bench.generate import generate_many

    if args.count < 1:
        raise InputError(InputProblem("count", "", f"must be at least 1, not {args.count}"))
    if getattr(args, "family", "mixed") == "team-search":  # (its sizes are the family's own)
        return generate_many(_generator_options(args, 1, 1, args.seed), args.count)
    out = []
    for units in args.units or GENERATE_UNITS:
        for tasks in args.tasks or GENERATE_TASKS:
            out += generate_many(_generator_options(args, units, tasks, args.seed), args.count)
    return out


def _tsplib(args: argparse.Namespace) -> list[Any]:
    """One scenario per --tsplib file x --units count, with its best known values."""
    from delegation.bench.best_known import best_known
    from delegation.bench.runner import LoadedScenario
    from delegation.scenario import tsplib_scenario

    out = []
    for path in args.tsplib:
        if not path.is_file():
            raise InputError(InputProblem(str(path), "--tsplib", "no such file"))
        for units in args.units or TSPLIB_UNITS:
            scenario = tsplib_scenario(path, units)
            out.append(LoadedScenario(f"{path} (m={units})", scenario,
                                      best_known(path.stem, units)))
    return out


@contextmanager
def _executor(args: argparse.Namespace) -> Iterator[Any]:
    from delegation.bench.executor import DaskExecutor, LocalExecutor

    if args.executor == "dask":
        with DaskExecutor(args.scheduler, workers=args.workers,
                          isolate=not args.in_process) as executor:
            yield executor
    else:
        yield LocalExecutor(isolate=not args.in_process)


def _run_bench(args: argparse.Namespace, console: Any, err: Any) -> int:
    from delegation.bench.runner import run_bench

    if not args.scenarios and not args.generate and not args.tsplib:
        raise InputError(InputProblem("bench", "", "give scenario files/folders, --tsplib FILE, "
                                 "--generate or --scale"))
    loaded, failures, generated = _bench_scenarios(args, err)
    if not loaded:  # each bad file was named above: one line each, and no empty outputs
        if not failures:
            err.print("error: no scenario to run; nothing written")
        return 1

    with _executor(args) as executor, _progress(err, "planning") as update:
        result = run_bench(
            loaded,
            strategies=args.strategies,
            objectives=args.objectives,
            repeat=args.repeat,
            time_limit=args.time_limit,
            progress=update,
            isolate=not args.in_process,
            run_timeout=args.run_timeout,
            baseline=args.baseline,
            executor=executor,
            no_split=getattr(args, "no_split", False),
        )
    for failure in result.failures:
        err.print(f"[red]error[/red] {failure}", markup=True, highlight=False)
    failures += result.failures
    _print_bench(result, console, err)
    _write_bench(args, result, generated, err)
    if result.interrupted:
        err.print(f"interrupted: {len(result.records)} of {result.total_runs} runs finished"
                  + (" (written)" if args.out and result.records else ""))
        return 130
    return 1 if failures or result.violations or not result.records else 0


def _bench_scenarios(
    args: argparse.Namespace, err: Any
) -> tuple[list[LoadedScenario], list[ScenarioFailure], list[dict[str, Any]]]:
    """(scenarios to run, files that failed to load (named on ``err``), generated scenarios):
    from files, ``--tsplib`` and ``--generate`` (saved with ``--save``)."""
    from delegation.bench.generate import save_scenarios
    from delegation.bench.runner import load_scenarios, scenarios_from_dicts

    loaded, failures = load_scenarios(args.scenarios)
    loaded += _tsplib(args)
    generated = _generated(args) if args.generate else []
    if generated:
        if args.save:
            for path in save_scenarios(generated, args.save):
                err.print(f"wrote {path}")
        loaded += scenarios_from_dicts(generated)
    for failure in failures:
        err.print(f"[red]error[/red] {failure}", markup=True, highlight=False)
    return loaded, failures, generated


def _print_bench(result: BenchResult, console: Any, err: Any) -> None:
    """The per-scenario tables, the summary, and each violated invariant on ``err``."""
    from delegation.bench.report import SUMMARY_NOTE, results_tables, summary_table, table_note
    from delegation.bench.summary import summarise

    if result.records:
        for table in results_tables(result.records):
            console.print(table)
            console.print()
        console.print(table_note(result.baseline), style="dim")
        console.print()
    summary = summarise(result)
    if summary:
        console.print(summary_table(summary))
        console.print(SUMMARY_NOTE, style="dim")
    for record in result.violations:
        err.print(
            f"[red]invariant violated[/red] {record.source} {record.strategy}/{record.objective}: "
            + "; ".join(record.problems),
            markup=True,
            highlight=False,
        )


def _write_bench(
    args: argparse.Namespace, result: BenchResult, generated: list[dict[str, Any]], err: Any
) -> None:
    """``--out`` (results, plots, maps, Gantt charts, provenance) and ``--page``."""
    from delegation.bench.provenance import provenance
    from delegation.bench.report import write_outputs

    if args.out:
        meta = {
            "scenarios": [str(p) for p in args.scenarios],
            "tsplib": [str(p) for p in args.tsplib],
            "generated": [d["name"] for d in generated],
            "strategies": list(dict.fromkeys(r.strategy for r in result.records)),
            "objectives": list(dict.fromkeys(r.objective for r in result.records)),
            "repeat": args.repeat,
            "time_limit": args.time_limit,
            "executor": args.executor,
            "provenance": provenance(getattr(args, "argv", None)),
        }
        written = write_outputs(result, args.out, meta=meta, plots=not args.no_plots,
                                maps=not args.no_maps, gantt=not args.no_gantt,
                                max_map_tasks=args.max_map_tasks)
        if written:
            err.print(f"wrote {len(written)} files to {args.out}")
        else:
            err.print("error: no run finished; nothing written")
    if args.page and result.records:
        from delegation.bench.page import write_results_page

        page = write_results_page(
            result.records,
            args.page,
            plots_dir=None if args.no_plots or not args.out else args.out,
            command=_command_line(args),
            time_limit=args.time_limit,
            baseline=result.baseline,
        )
        err.print(f"wrote {page}")


def _run_compare(args: argparse.Namespace, console: Any) -> int:
    from delegation.bench.compare import compare_files, comparison_table

    files = args.scenarios[1:]
    if len(files) != 2:
        raise InputError(InputProblem("bench compare", "", "give exactly two results.json: A B"))
    comparison = compare_files(Path(files[0]), Path(files[1]))
    for table in comparison_table(comparison):
        console.print(table)
        console.print()
    for line in comparison.notes:
        console.print(line, style="dim")
    return 0


def _run_scale(args: argparse.Namespace, console: Any, err: Any) -> int:
    from delegation.bench.scale import DEFAULT_BUDGET, DEFAULT_TASKS, DEFAULT_UNITS, summary_rows

    budget = args.budget if args.budget is not None else DEFAULT_BUDGET
    units, tasks = args.units or DEFAULT_UNITS, args.tasks or DEFAULT_TASKS
    generator = _generator_options(args, 1, 1, args.seed)
    if args.time_limit >= budget:
        err.print(
            f"[yellow]warning[/yellow] --time-limit {args.time_limit:g} s is not below the budget "
            f"{budget:g} s: optimal will exceed it at the first size"
        )
    records, interrupted = _scale_sweep(args, units, tasks, budget, generator, err)
    if interrupted and not records:
        err.print("interrupted: no run had finished; nothing written")
        return 130
    rows = summary_rows(records)
    console.print(_scale_table(rows, budget, args.time_limit))
    console.print(
        "largest ok: the largest cell (units x tasks) within budget; over at: cells where it "
        "exceeded the budget; vs best: median objective / the best strategy's; best on: cells "
        "where it beat every other strategy (a returned plan of another never counts); copied: "
        "cells where its plan was an earlier strategy's (e.g. optimal keeping the auction's)",
        style="dim",
    )
    setup = (
        f"Grid: units {', '.join(map(str, units))} x tasks "
        f"{', '.join(map(str, tasks))}; budget {budget:g} s per plan; "
        f"time limit {args.time_limit:g} s; generated at {generator.site} (seed {generator.seed}, "
        f"structure {generator.structure}, radius {generator.radius:g} m)."
    )
    for path in _write_scale(records, rows, args.out or Path("bench-out"), setup, budget,
                             plots=not args.no_plots):
        err.print(f"wrote {path}")
    problems = _print_scale_problems(records, err)
    if interrupted:
        err.print(f"interrupted: wrote the {len(records)} runs that finished")
        return 130
    return 1 if problems else 0


def _scale_sweep(
    args: argparse.Namespace,
    units: Sequence[int],
    tasks: Sequence[int],
    budget: float,
    generator: GeneratorOptions,
    err: Any,
) -> tuple[list[ScaleRecord], bool]:
    """The sweep's records, and whether Ctrl-C stopped it (then the records that finished)."""
    from delegation.bench.scale import ScaleInterrupted, run_scale

    try:
        with _executor(args) as executor, _progress(err, "scale sweep") as update:
            return run_scale(
                args.strategies,
                objectives=args.objectives or ["makespan"],
                units=units,
                tasks=tasks,
                budget=budget,
                time_limit=args.time_limit,
                generator=generator,
                progress=update,
                isolate=not args.in_process,
                executor=executor,
            ), False
    except ScaleInterrupted as stop:  # Ctrl-C: write what finished, then exit 130
        return stop.records, True


def _scale_table(rows: list[dict[str, Any]], budget: float, time_limit: float) -> Any:
    """The sweep's summary for the terminal, a row per strategy x objective."""
    from delegation.bench.report import compact_table

    table = compact_table(f"Scale sweep: budget {budget:g} s per plan, time limit {time_limit:g} s")
    cells = [_scale_cells(row) for row in rows]
    for i, header in enumerate(_SCALE_HEADERS):
        table.add_column(
            header,
            justify="left" if i < 2 else "right",
            overflow="fold",
            min_width=max(len(c[i]) for c in cells) if cells else None,
        )
    for row_cells in cells:
        table.add_row(*row_cells)
    return table


def _write_scale(
    records: list[ScaleRecord],
    rows: list[dict[str, Any]],
    out: Path,
    setup: str,
    budget: float,
    *,
    plots: bool,
) -> list[Path]:
    """``scale.csv``, ``scale.md`` (``setup``, then the summary) and ``scale.png`` in ``out``."""
    from delegation.bench.scale import scale_plot, write_scale_csv

    written = [write_scale_csv(records, out / "scale.csv")]
    md = out / "scale.md"
    md.write_text(setup + "\n\n" + _scale_markdown(rows) + "\n", encoding="utf-8")
    written.append(md)
    if plots:
        written.append(scale_plot(records, out / "scale.png", budget=budget))
    return written


def _print_scale_problems(records: list[ScaleRecord], err: Any) -> bool:
    """Each violated invariant, then each failed run, on ``err``; True when there was any."""
    violations = [r for r in records if r.problems]
    for r in violations:
        err.print(
            f"[red]invariant violated[/red] {r.units}x{r.tasks} {r.strategy}: "
            + "; ".join(r.problems)
        )
    failed = [r for r in records if r.status == "failed"]
    for r in failed:
        err.print(f"[red]failed[/red] {r.units}x{r.tasks} {r.strategy}: {r.note}")
    return bool(violations or failed)


def _command_line(args: argparse.Namespace) -> str:
    """The bench command that reproduces this run (for the results page)."""
    words = ["delegation", "bench", *(str(p) for p in args.scenarios)]
    for path in args.tsplib:
        words += ["--tsplib", str(path)]
    if args.tsplib and not args.generate:
        words += ["--units", _listed(args.units or TSPLIB_UNITS)]
    family = getattr(args, "family", "mixed")
    if args.generate and family != "mixed":
        words += ["--generate", "--family", family, "--seed", str(args.seed),
                  "--count", str(args.count)]
    elif args.generate:
        words += ["--generate", "--seed", str(args.seed), "--site", args.site]
        words += ["--units", _listed(args.units or GENERATE_UNITS)]
        words += ["--tasks", _listed(args.tasks or GENERATE_TASKS)]
    if args.strategies:
        words += ["--strategies", ",".join(args.strategies)]
    if args.objectives:
        words += ["--objectives", ",".join(args.objectives)]
    if getattr(args, "no_split", False):
        words.append("--no-split")
    if args.repeat != 1:
        words += ["--repeat", str(args.repeat)]
    if args.baseline:
        words += ["--baseline", args.baseline]
    words += ["--time-limit", f"{args.time_limit:g}"]
    if args.out:
        words += ["--out", args.out.as_posix()]
    if args.no_plots:
        words.append("--no-plots")
    if args.no_maps:
        words.append("--no-maps")
    words += ["--page", args.page.as_posix()]
    return " ".join(words)


#: The scale summary's columns, in `_scale_cells` order: the terminal header, the markdown
#: header, and whether the markdown column is right-aligned (numbers).
_SCALE_COLUMNS: tuple[tuple[str, str, bool], ...] = (
    ("strategy", "strategy", False),
    ("objective", "objective", False),
    ("largest ok", "largest cell within budget", False),
    ("time s", "its time s", True),
    ("over at", "exceeded the budget at", False),
    ("skipped", "skipped cells", True),
    ("failed", "failed", True),
    ("vs best", "median objective / best", True),
    ("best on", "strictly best on", True),
    ("copied", "returned an earlier strategy's plan", True),
)
_SCALE_HEADERS = tuple(short for short, _, _ in _SCALE_COLUMNS)


def _scale_cells(row: dict[str, Any]) -> list[str]:
    return [
        row["strategy"],
        row["objective"],
        row["largest_within_budget"] or "-",
        "-" if row["largest_time"] is None else f"{row['largest_time']:.2f}",
        row["exceeded_at"] or "-",
        str(row["skipped"]),
        str(row["failed"]),
        "-" if row["median_relative"] is None else f"{row['median_relative']:.3f}",
        f"{row['strictly_best']} of {row['compared']}",
        str(row["copied"]),
    ]


def _scale_markdown(rows: list[dict[str, Any]]) -> str:
    headers = [long for _, long, _ in _SCALE_COLUMNS]
    rule = ["---:" if numeric else "---" for _, _, numeric in _SCALE_COLUMNS]
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join(rule) + "|"]
    lines += ["| " + " | ".join(_scale_cells(row)) + " |" for row in rows]
    return "\n".join(lines)
