"""``delegation validate``: exit codes and output lines, in-process and as the console script."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from delegation.cli import main

SEED = Path(__file__).parent / "fixtures" / "seed"


def gp(lat: float, lon: float) -> dict[str, Any]:
    return {"altitude": 40.0, "latitude": lat, "longitude": lon, "rostype": "GeoPoint"}


def good_tree() -> dict[str, Any]:
    return {
        "name": "seq",
        "common_params": {"node-uuid": "r"},
        "children": [
            {
                "name": "move-to",
                "common_params": {"node-uuid": "a"},
                "params": {"waypoint": gp(57.76, 16.68)},
            },
            {
                "name": "search-area",
                "common_params": {"node-uuid": "b"},
                "params": {"area": [gp(57.76, 16.68), gp(57.76, 16.69), gp(57.77, 16.69)]},
            },
        ],
    }


def run(tmp_path: Path, capsys: pytest.CaptureFixture[str], data: Any) -> tuple[int, list[str]]:
    path = tmp_path / "input.json"
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    code = main(["validate", str(path)])
    out = capsys.readouterr()
    assert "Traceback" not in out.out + out.err
    lines = [line.removeprefix(f"{path}: ") for line in out.out.splitlines()]
    return code, lines


def test_valid_tree(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert run(tmp_path, capsys, good_tree()) == (0, ["OK: TST, 3 nodes, 2 tasks"])


@pytest.mark.parametrize("path", sorted(SEED.glob("*.json")), ids=lambda p: p.name)
def test_every_seed_example_is_valid(path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["validate", str(path)]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    assert line.startswith(f"{path}: OK: ")


def test_start_tst_summary_counts_the_tree(capsys: pytest.CaptureFixture[str]) -> None:
    path = SEED / "11.1.7-search-area.json"
    assert main(["validate", str(path)]) == 0
    assert (
        capsys.readouterr().out == f"{path}: OK: start-tst command with a TST of 1 node, 1 task\n"
    )


def test_one_line_per_problem(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    tree = good_tree()
    tree["children"][0]["params"]["waypoint"]["latitude"] = 91.0
    tree["children"][1]["params"]["area"] = tree["children"][1]["params"]["area"][:2]
    tree["children"].append({"name": "fly-around"})
    code, lines = run(tmp_path, capsys, tree)
    assert code == 1
    assert lines == [
        "root/children[0] (move-to a): params.waypoint.latitude: 91.0 is outside [-90, 90]",
        "root/children[1] (search-area b): params.area: a search polygon needs at least 3 "
        "points, got 2",
        "root/children[2] (fly-around): name: unknown task 'fly-around': not in the catalogue",
    ]


def test_invalid_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, lines = run(tmp_path, capsys, '{"name": "seq", "children": [}')
    assert code == 1
    assert lines == ["invalid JSON: Expecting value (line 1, column 30)"]


def test_start_tst_command_checks_its_tree(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tree = good_tree()
    tree["children"][1]["common_params"]["node-uuid"] = "a"
    cmd = {
        "com-uuid": "c",
        "command": "start-tst",
        "receiver": "delegator0",
        "sender": "me",
        "tst": tree,
    }
    code, lines = run(tmp_path, capsys, cmd)
    assert code == 1
    assert lines == [
        "root/children[1] (search-area a): common_params.node-uuid: duplicate node-uuid 'a' "
        "(also used by root/children[0])"
    ]


@pytest.mark.parametrize("command", ["delegate", "get-bids"])
def test_delegation_commands_check_their_tree(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    tree = good_tree()
    tree["children"][0]["children"] = []
    tree["children"][0]["params"]["speed"] = "warp"
    code, lines = run(tmp_path, capsys, {"com-uuid": "c", "command": command, "tst": tree})
    assert code == 1
    assert lines == [
        "root/children[0] (move-to a): params.speed: 'warp' is not one of slow, standard, fast"
    ]
    del tree["children"][0]["params"]["speed"]
    assert run(tmp_path, capsys, {"com-uuid": "c", "command": command, "tst": tree})[0] == 0


def test_command_and_tree_problems_together(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tree = good_tree()
    tree["children"] = {"name": "move-to"}
    code, lines = run(tmp_path, capsys, {"command": "start-tst", "sender": 3, "tst": tree})
    assert code == 1
    assert lines == [
        "start-tst: com-uuid: missing",
        "start-tst: sender: Input should be a valid string, got 3",
        "root: children: must be a list, not an object",
    ]


def test_start_task_checks_the_task(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cmd = json.loads((SEED / "10.1.5-move-to.json").read_text())
    cmd["task"]["params"]["waypoint"]["longitude"] = -190
    code, lines = run(tmp_path, capsys, cmd)
    assert (code, lines) == (
        1,
        ["start-task: task.params.waypoint.longitude: -190 is outside [-180, 180]"],
    )
    cmd["task"]["name"] = "teleport"
    assert run(tmp_path, capsys, cmd) == (1, ["start-task: task.name: unknown task 'teleport'"])


def test_unknown_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, lines = run(tmp_path, capsys, {"com-uuid": "c", "command": "launch"})
    assert code == 1
    assert len(lines) == 1
    assert lines[0].startswith("command: command: unknown command 'launch'; expected one of ")


def test_not_a_tree_at_all(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert run(tmp_path, capsys, [1, 2]) == (1, ["root: a node must be a JSON object, not a list"])


def test_missing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["validate", str(tmp_path / "nope.json")]) == 1
    assert (
        capsys.readouterr().out
        == f"{tmp_path / 'nope.json'}: cannot read: No such file or directory\n"
    )


def test_several_files_exit_1_if_any_is_bad(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good, bad = tmp_path / "good.json", tmp_path / "bad.json"
    good.write_text(json.dumps(good_tree()))
    bad.write_text("[")
    assert main(["validate", str(good), str(bad)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"{good}: OK: TST, 3 nodes, 2 tasks"
    assert out[1].startswith(f"{bad}: invalid JSON")


def test_stdin(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    stdin = io.TextIOWrapper(io.BytesIO(json.dumps(good_tree()).encode()))
    monkeypatch.setattr(sys, "stdin", stdin)
    assert main(["validate", "-"]) == 0
    assert capsys.readouterr().out == "<stdin>: OK: TST, 3 nodes, 2 tasks\n"


def _console_script() -> list[str]:
    script = Path(sys.executable).parent / "delegation"
    if script.exists():
        return [str(script)]
    found = shutil.which("delegation")
    return [found] if found else [sys.executable, "-m", "delegation"]


@pytest.mark.slow  # fresh processes of the installed script
def test_console_script(tmp_path: Path) -> None:
    tree = good_tree()
    # A bow tie: the edges (57.76, 16.68)-(57.77, 16.69) and (57.76, 16.69)-(57.77, 16.68) cross.
    tree["children"][1]["params"]["area"] = [
        gp(57.76, 16.68),
        gp(57.77, 16.69),
        gp(57.76, 16.69),
        gp(57.77, 16.68),
    ]
    path = tmp_path / "mission.json"
    path.write_text(json.dumps(tree))
    bad = subprocess.run(
        [*_console_script(), "validate", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert bad.returncode == 1, bad
    assert bad.stdout == (
        f"{path}: root/children[1] (search-area b): params.area: the polygon crosses itself\n"
    )
    assert "Traceback" not in bad.stderr
    ok = subprocess.run(
        [*_console_script(), "validate", "-"],
        input=json.dumps(good_tree()),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert (ok.returncode, ok.stdout) == (0, "<stdin>: OK: TST, 3 nodes, 2 tasks\n")


@pytest.mark.parametrize("depth", [65, 150])
def test_too_deep_tree_names_the_node(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], depth: int
) -> None:
    text = (
        '{"name": "seq", "children": [' * (depth - 1) + '{"name": "go-home"}' + "]}" * (depth - 1)
    )
    code, lines = run(tmp_path, capsys, text)
    assert code == 1
    assert lines == [
        "root" + "/children[0]" * 64 + ": children: tree is nested deeper than 64 levels"
    ]


def test_json_too_deep_for_python(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert run(tmp_path, capsys, "[" * 100_000) == (1, ["invalid JSON: nested too deeply"])


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        ({"strategy": "greedy"}, "delegate: strategy: unknown strategy 'greedy'; expected one of"),
        ({"objective": "speed"}, "delegate: objective: unknown objective 'speed'"),
        ({"time-limit": 61}, "delegate: time-limit: 61 s is above this service's maximum of 60 s"),
        ({"strategy": "auction", "objective": "makespan", "time-limit": 5}, None),
        ({}, None),
    ],
    ids=["unknown-strategy", "unknown-objective", "time-limit-too-long", "good", "defaults"],
)
def test_delegate_options_are_checked_as_the_service_would(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], options: dict[str, Any],
    expected: str | None,
) -> None:
    command = {"com-uuid": "c", "command": "delegate", "tst": good_tree(), **options}
    code, lines = run(tmp_path, capsys, command)
    if expected is None:
        assert (code, lines) == (0, ["OK: delegate command with a TST of 3 nodes, 2 tasks"])
        return
    assert code == 1
    assert len(lines) == 1 and lines[0].startswith(expected), lines
