"""Every JSON example of the seed parses on its topic and re-encodes to the same JSON.

The fixtures are the seed's examples (sections 5, 10, 11, 12, 14), repaired where the document was
damaged (see ``tests/fixtures/seed/README.md``).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from delegation.messages import (
    DirectExecutionInfo,
    ExecFeedback,
    ExecResponse,
    HeartBeat,
    Ping,
    SensorInfo,
    SignalExecutor,
    SignalTask,
    SignalTstNode,
    SignalTstTree,
    SignalUnit,
    StartTask,
    StartTst,
    TstFeedback,
    TstResponse,
    decode,
    encode,
    parse_message,
)
from delegation.tst import parse_and_validate, to_dict

SEED_DIR = Path(__file__).parent / "fixtures" / "seed"
FILES = sorted(SEED_DIR.glob("*.json"))
BASE = "waraps/unit/air/simulation/dji0"

#: (file name prefix, topic suffix, model) for every fixture.
ROUTES: list[tuple[str, str, type]] = [
    ("5.1-", "heartbeat", HeartBeat),
    ("5.2-", "sensor_info", SensorInfo),
    ("5.3-", "direct_execution_info", DirectExecutionInfo),
    ("10.", "exec/command", StartTask),
    ("11.", "tst/command", StartTst),
    ("12.2.1-", "exec/command", Ping),
    ("12.2.2-signal-task", "exec/command", SignalTask),
    ("12.2.2-signal-executor", "exec/command", SignalExecutor),
    ("12.3.", "exec/response", ExecResponse),
    ("12.4-", "exec/feedback", ExecFeedback),
    ("14.3.1-", "tst/command", SignalTstNode),
    ("14.3.2-", "tst/command", SignalTstTree),
    ("14.3.3-", "tst/command", SignalUnit),
    ("14.4.", "tst/response", TstResponse),
    ("14.5-", "tst/feedback", TstFeedback),
]

#: Examples that are not in the seed's canonical form: keys not sorted (5.3, 12.2.2, 14.3.3), or
#: an integer rate and a 17-digit stamp (5.2 dji0). They still re-encode to equal JSON values.
NOT_CANONICAL = {
    "5.2-sensor-info-dji0.json",
    "5.3-direct-execution-info.json",
    "5.3-direct-execution-info-tasks-executing.json",
    "12.2.2-signal-task.json",
    "12.2.2-signal-executor.json",
    "14.3.3-signal-unit.json",
}

_WS = re.compile(r'("(?:[^"\\]|\\.)*")|\s+')


def strip_ws(text: str) -> str:
    """Remove whitespace outside JSON strings."""
    return _WS.sub(lambda m: m.group(1) or "", text)


def route(path: Path) -> tuple[str, type]:
    for prefix, topic, model in ROUTES:
        if path.name.startswith(prefix):
            return f"{BASE}/{topic}", model
    raise AssertionError(f"no route for {path.name}")


def test_every_seed_section_has_examples() -> None:
    names = [p.name for p in FILES]
    assert len(names) == 39
    for section in (
        "5.1",
        "5.2",
        "5.3",
        "10.1.1",
        "10.1.9",
        "11.1.1",
        "11.1.4",
        "11.1.5",
        "11.1.9",
        "12.2.1",
        "12.3.3",
        "12.4",
        "14.3.3",
        "14.4.4",
        "14.5",
    ):
        assert any(n.startswith(section + "-") for n in names), section


def test_every_repaired_file_is_listed_in_the_readme() -> None:
    readme = (SEED_DIR / "README.md").read_text()
    for name in (
        "11.1.4-move-path.json",
        "11.1.5-move-to.json",
        "11.1.8-search-areas.json",
        "12.2.2-signal-task.json",
        "10.1.3-look-at-positions.json",
    ):
        assert f"`{name}`" in readme


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_seed_example_decodes_on_its_topic(path: Path) -> None:
    topic, model = route(path)
    message = decode(topic, path.read_bytes())
    assert type(message) is model
    # The same file without a topic (as ``delegation validate`` reads it) gives the same model.
    assert type(parse_message(json.loads(path.read_text()))) is model


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_seed_example_round_trips(path: Path) -> None:
    topic, _ = route(path)
    text = path.read_text()
    encoded = encode(decode(topic, text.encode()))
    assert json.loads(encoded) == json.loads(text)
    if path.name not in NOT_CANONICAL:
        assert encoded.decode() == strip_ws(text)


@pytest.mark.parametrize(
    "path", [p for p in FILES if p.name.startswith("11.")], ids=lambda p: p.name
)
def test_seed_start_tst_tree_validates_and_round_trips(path: Path) -> None:
    message = decode(f"{BASE}/tst/command", path.read_bytes())
    assert isinstance(message, StartTst)
    tree = parse_and_validate(message.tst)
    assert to_dict(tree) == json.loads(path.read_text())["tst"]
    assert tree.node_uuid == message.tst["common_params"]["node-uuid"]


@pytest.mark.parametrize(
    "path", [p for p in FILES if p.name.startswith("10.")], ids=lambda p: p.name
)
def test_seed_start_task_params_validate(path: Path) -> None:
    message = decode(f"{BASE}/exec/command", path.read_bytes())
    assert isinstance(message, StartTask)
    node = parse_and_validate({"name": message.task.name, "params": message.task.params})
    assert node.params == message.task.params
