"""User YAML is read without anchors and aliases (issue 23: an alias bomb is a few hundred
characters that expand to gigabytes once serialised), and too-deep nesting is an input error,
not a crash. Every reader of a user's file or text uses `delegation.safe_yaml.load_yaml`."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest
import yaml

from delegation.errors import InputError
from delegation.safe_yaml import load_yaml
from delegation.scenario import read_document
from delegation.web.mission_input import mission_tree

SRC = Path(__file__).resolve().parents[1] / "src" / "delegation"


def bomb(levels: int = 8) -> str:
    """A mission whose unvalidated ``meta`` is an alias bomb: x10 per level once expanded."""
    lines = ["name: move-to", "params:", "  waypoint: {latitude: 57.76, longitude: 16.68, "
             "altitude: 30}", "meta:", "  l0: &l0 [aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa]"]
    for k in range(1, levels):
        refs = ", ".join([f"*l{k - 1}"] * 10)
        lines.append(f"  l{k}: &l{k} [{refs}]")
    lines.append(f"  top: *l{levels - 1}")
    return "\n".join(lines) + "\n"


def test_plain_yaml_reads_as_before() -> None:
    text = "name: x\nlist: [1, 2.5, 'a', null, true]\nnested: {a: {b: [c]}}\n"
    assert load_yaml(text) == yaml.safe_load(text)
    assert load_yaml(b"a: 1\n") == {"a": 1}
    assert load_yaml("") is None


@pytest.mark.parametrize("text", [
    "a: &x 1\nb: *x\n",
    "a: &x [1]\n",  # an anchor alone is refused too: it is only there to be aliased
    "base: &b {x: 1}\nderived:\n  <<: *b\n",
    bomb(3),
])
def test_anchors_and_aliases_are_refused(text: str) -> None:
    with pytest.raises(yaml.YAMLError, match="anchors and aliases"):
        load_yaml(text)


def test_deep_nesting_is_a_yaml_error_not_a_crash() -> None:
    with pytest.raises(yaml.YAMLError, match="nested too deeply"):
        load_yaml("[" * 100_000)


def test_the_bomb_is_refused_by_the_page_and_in_files(tmp_path: Path) -> None:
    text = bomb()
    assert len(text) < 700
    with pytest.raises(InputError, match="anchors and aliases"):
        mission_tree(text)
    path = tmp_path / "bomb.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match="anchors and aliases"):
        read_document(path)


def test_deep_json_or_yaml_mission_text_is_a_400_not_a_crash() -> None:
    for text in ("[" * 100_000, "{\"a\": " * 100_000):
        with pytest.raises(InputError):
            mission_tree(text)


def test_no_module_reads_yaml_any_other_way() -> None:
    """``yaml.safe_load``/``yaml.load``/``yaml.full_load`` appear only in the safe loader."""
    found = []
    for path in SRC.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id == "yaml" and "load" in node.attr):
                found.append(f"{path.relative_to(SRC)}:{node.lineno} yaml.{node.attr}")
    assert [f for f in found if not f.startswith("safe_yaml.py")] == []


def test_the_bundled_and_generated_scenarios_still_load(tmp_path: Path) -> None:
    from delegation.bench.generate import GeneratorOptions, generate_many, save_scenarios

    root = SRC.parents[1]
    files = [*root.glob("scenarios/**/*.yaml"), *root.glob("examples/**/*.yaml"),
             *save_scenarios(generate_many(GeneratorOptions(), 2), tmp_path)]
    assert files
    for path in files:
        assert json.dumps(load_yaml(path.read_text())) is not None, path
