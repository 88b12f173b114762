"""Standard instances (any TSPLIB file as an mTSP, gap to the best known value), bad input as
one clear error with nothing written, and Ctrl-C keeping the runs that finished."""

from __future__ import annotations

import csv
import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from delegation.bench.best_known import best_known
from delegation.cli import main
from delegation.errors import InputError
from delegation.scenario import read_tsplib, tsplib_scenario

ROOT = Path(__file__).resolve().parents[1]


def wait_started(fifo: Path, process: subprocess.Popen[str], timeout: float) -> bool:
    """Wait (bounded) for the sleepy strategy to write to ``fifo``; False when the child exits
    first or the deadline passes."""
    fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    try:
        deadline = time.monotonic() + timeout
        while process.poll() is None:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            readable, _, _ = select.select([fd], [], [], min(left, 1.0))
            if readable and os.read(fd, 64):
                return True
        return False
    finally:
        os.close(fd)
BERLIN = ROOT / "benchmarks" / "data" / "berlin52.tsp"

SMALL = """NAME : tiny5
TYPE : TSP
DIMENSION : 5
EDGE_WEIGHT_TYPE : EUC_2D
NODE_COORD_SECTION
1 0 0
2 100 0
3 100 100
4 0 100
5 50 50
"""


def test_any_tsplib_file_is_an_mtsp_with_homes_at_the_depot(tmp_path: Path) -> None:
    path = tmp_path / "tiny5.tsp"
    path.write_text(SMALL)
    scenario = tsplib_scenario(path, 2)
    units = scenario.units()
    assert scenario.name == "tiny5-2u" and len(units) == 2
    assert all(u.home is not None and u.home == u.position for u in units)
    assert len(scenario.tree().children) == 4  # every node but the depot


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("NAME: x\nEDGE_WEIGHT_TYPE : GEO\nNODE_COORD_SECTION\n1 1 1\n2 2 2\n", "GEO is not"),
        ("NAME: x\nDIMENSION : 3\nNODE_COORD_SECTION\n1 1 1\n2 2 2\nEOF\n", "says 3 nodes"),
        ("hello, not a TSPLIB file\n", "no coordinates found"),
        ("NODE_COORD_SECTION\n1 1 x\n", "not numbers"),
    ],
)
def test_bad_tsplib_files_are_named(tmp_path: Path, text: str, why: str) -> None:
    path = tmp_path / "bad.tsp"
    path.write_text(text)
    with pytest.raises(InputError, match=why):
        read_tsplib(path)


def test_berlin52_gap_to_best_known_is_a_column(tmp_path: Path) -> None:
    out = tmp_path / "out"
    code = main(["bench", "--tsplib", str(BERLIN), "--units", "3", "--strategies",
                 "nearest,auction", "--in-process", "--no-plots", "--out", str(out)])
    assert code == 0
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == 4
    known = best_known("berlin52", 3)
    assert known == {"total": 7735.0, "makespan": 3070.0}
    for row in rows:
        assert float(row["best_known"]) == known[row["objective"]]
        value = float(row["objective_value"])
        assert float(row["gap_to_best_known"]) == pytest.approx(value / known[row["objective"]] - 1)
        assert float(row["gap_to_best_known"]) > -0.01  # real-valued vs rounded distances
    assert "vs best known" in (out / "results.md").read_text()


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "nope.yaml"],
        ["bench", "--tsplib", "nope.tsp"],
        ["bench", "--tsplib", "{bad}"],
    ],
)
def test_a_missing_or_bad_file_is_one_error_and_nothing_written(
    tmp_path: Path, argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.tsp"
    bad.write_text("not tsplib\n")
    argv = [a.replace("{bad}", str(bad)) for a in argv]
    out = tmp_path / "out"
    code = main([*argv, "--in-process", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert not out.exists()  # never empty result files
    assert any(("nope" in line or "bad.tsp" in line) for line in err), err
    assert len(err) == 1 and err[0].startswith("error"), err


def test_ctrl_c_writes_the_finished_runs_and_exits_130(tmp_path: Path) -> None:
    marker, out = tmp_path / "started", tmp_path / "out"
    os.mkfifo(marker)
    env = {**os.environ, "BENCH_TEST_MARKER": str(marker),
           "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT / "tests")])}
    process = subprocess.Popen(
        [sys.executable, "-m", "delegation", "bench", "--generate", "--units", "2", "--tasks",
         "4", "--objectives", "makespan", "--strategies",
         "nearest,auction,bench_crash_strategy:sleepy", "--no-plots", "--out", str(out)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True,
    )
    try:
        assert wait_started(marker, process, 60.0), "the sleepy run never started"
        os.killpg(process.pid, signal.SIGINT)  # Ctrl-C in a terminal: the whole group
        _, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=10)
    assert process.returncode == 130, stderr
    assert "interrupted: 2 of 3 runs finished (written)" in stderr
    data = json.loads((out / "results.json").read_text())
    assert [r["strategy"] for r in data["records"]] == ["nearest", "auction"]
    assert data["meta"]["interrupted"] is True and data["meta"]["runs_asked"] == 3
    assert (out / "results.md").read_text().startswith("**Interrupted: partial results.**")


def test_ctrl_c_in_the_scale_sweep_writes_the_finished_runs(tmp_path: Path) -> None:
    marker, out = tmp_path / "started", tmp_path / "out"
    os.mkfifo(marker)
    env = {**os.environ, "BENCH_TEST_MARKER": str(marker),
           "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT / "tests")])}
    process = subprocess.Popen(
        [sys.executable, "-m", "delegation", "bench", "--scale", "--units", "2", "--tasks", "3",
         "--strategies", "nearest,bench_crash_strategy:sleepy", "--budget", "100", "--no-plots",
         "--out", str(out)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True,
    )
    try:
        assert wait_started(marker, process, 60.0), "the sleepy run never started"
        os.killpg(process.pid, signal.SIGINT)
        _, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=10)
    assert process.returncode == 130, stderr
    assert "interrupted: wrote the 1 runs that finished" in stderr
    rows = list(csv.DictReader((out / "scale.csv").open()))
    assert [(r["strategy"], r["status"]) for r in rows] == [("nearest", "ok")]
