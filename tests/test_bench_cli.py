"""``delegation bench`` end to end: files written, failures named, exit codes."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from delegation.cli import main as cli_main

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def main(argv: list[str]) -> int:
    """The real CLI; runs in child processes get a deadline, so a stuck child fails, not hangs."""
    if argv[:1] == ["bench"] and "--scale" not in argv and "--in-process" not in argv:
        argv = [*argv, "--run-timeout", "120"]
    return cli_main(argv)


@pytest.mark.slow
def test_generate_save_and_bench_the_saved_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    saved = tmp_path / "gen"
    out = tmp_path / "out"
    code = main(
        [
            "bench",
            "--generate",
            "--units",
            "2,3",
            "--tasks",
            "4",
            "--seed",
            "9",
            "--strategies",
            "nearest,auction",
            "--objectives",
            "makespan",
            "--time-limit",
            "0.5",
            "--save",
            str(saved),
            "--out",
            str(out),
        ]
    )
    assert code == 0
    files = sorted(p.name for p in saved.iterdir())
    assert files == ["gen-granso-u2-t4-s9.yaml", "gen-granso-u3-t4-s9.yaml"]
    with (out / "results.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 2 * 2
    data = json.loads((out / "results.json").read_text())
    assert data["meta"]["strategies"] == ["nearest", "auction"]
    assert [r["makespan"] for r in data["records"]] == [float(r["makespan"]) for r in rows]
    for png in out.glob("*.png"):
        assert png.read_bytes()[:8] == PNG_SIGNATURE
    assert (out / "gen-granso-u2-t4-s9-objective.png").exists()
    shown = capsys.readouterr().out
    assert "gen-granso-u2-t4-s9" in shown and "auction" in shown

    # The saved files give the same results when benchmarked from the folder.
    out2 = tmp_path / "out2"
    code = main(
        [
            "bench",
            str(saved),
            "--strategies",
            "nearest,auction",
            "--objectives",
            "makespan",
            "--time-limit",
            "0.5",
            "--out",
            str(out2),
            "--no-plots",
        ]
    )
    assert code == 0
    again = json.loads((out2 / "results.json").read_text())["records"]
    key = ("scenario", "strategy", "makespan", "total_time", "total_distance", "unassigned")
    assert [tuple(r[k] for k in key) for r in again] == [
        tuple(r[k] for k in key) for r in data["records"]
    ]
    assert not list(out2.glob("*.png"))


def test_bad_file_is_named_and_exit_code_is_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "s"
    main(
        [
            "bench",
            "--generate",
            "--units",
            "2",
            "--tasks",
            "3",
            "--save",
            str(folder),
            "--strategies",
            "nearest",
            "--objectives",
            "makespan",
        ]
    )
    (folder / "zz-bad.yaml").write_text("name: bad\nagents: 3\n", encoding="utf-8")
    capsys.readouterr()
    code = main(["bench", str(folder), "--strategies", "nearest", "--objectives", "makespan"])
    captured = capsys.readouterr()
    assert code == 1
    assert "zz-bad.yaml" in captured.err
    assert "gen-granso-u2-t3-s0" in captured.out


@pytest.mark.slow  # a scale sweep and its plot
def test_scale_writes_csv_png_and_summary(tmp_path: Path) -> None:
    code = main(
        [
            "bench",
            "--scale",
            "--units",
            "1,2",
            "--tasks",
            "2",
            "--strategies",
            "nearest",
            "--budget",
            "60",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    with (tmp_path / "scale.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["units"], r["tasks"], r["status"]) for r in rows] == [
        ("1", "2", "ok"),
        ("2", "2", "ok"),
    ]
    assert (tmp_path / "scale.png").read_bytes()[:8] == PNG_SIGNATURE
    assert "nearest" in (tmp_path / "scale.md").read_text()


def test_usage_errors_are_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench"]) == 1
    assert main(["bench", "--generate", "--strategies", "greedy"]) == 1
    assert main(["bench", "--generate", "--site", "atlantis"]) == 1
    assert main(["bench", "--scale", "scenarios/"]) == 1
    assert main(["bench", "--generate", "--in-process", "--run-timeout", "5"]) == 1
    err = capsys.readouterr().err
    assert "greedy" in err and "atlantis" in err
    assert "--scale" in err and "--run-timeout" in err
    assert "Traceback" not in err


@pytest.mark.slow  # bench runs and a results page
def test_results_page_is_made_from_the_same_records(tmp_path: Path) -> None:
    docs = tmp_path / "docs"
    assert (
        main(
            [
                "bench",
                "--scale",
                "--units",
                "1",
                "--tasks",
                "2",
                "--strategies",
                "nearest",
                "--out",
                str(docs),
            ]
        )
        == 0
    )
    code = main(
        [
            "bench",
            "--generate",
            "--units",
            "2",
            "--tasks",
            "3",
            "--strategies",
            "nearest,auction",
            "--objectives",
            "makespan",
            "--no-maps",
            "--out",
            str(docs / "bench"),
            "--page",
            str(docs / "results.md"),
        ]
    )
    assert code == 0
    page = (docs / "results.md").read_text()
    table, summary = (docs / "bench" / "results.md").read_text().strip().split("\n\n")[:2]
    assert table in page  # the full table, as the bench wrote it
    assert summary in page  # and the summary across scenarios
    assert "--page" in page and "delegation bench --scale" in page
    assert "](bench/gen-granso-u2-t3-s0-objective.png)" in page
    assert "![scale sweep](scale.png)" in page
    assert "| makespan | auction | 1 |" in page  # the summary row


def test_grid_help_names_the_scale_sweeps_own_grid() -> None:
    """``--units``/``--tasks`` say the --scale defaults in their help without importing
    `delegation.bench.scale` (numpy) at parse time: the help must not drift from the sweep."""
    import argparse

    from delegation.bench.scale import DEFAULT_TASKS, DEFAULT_UNITS
    from delegation.cli import bench

    sub = argparse.ArgumentParser().add_subparsers()
    bench.register(sub)
    parser = sub.choices["bench"]
    helps = {a.dest: a.help or "" for a in parser._actions}
    assert f"--scale: {','.join(map(str, DEFAULT_UNITS))})" in helps["units"]
    assert f"--scale: {','.join(map(str, DEFAULT_TASKS))})" in helps["tasks"]
