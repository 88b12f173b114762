"""The scenario generator: deterministic for a seed, valid missions, files that load back."""

from __future__ import annotations

from collections import Counter

import pytest
import yaml

from delegation.bench.generate import (
    SITES,
    TASK_TYPES,
    GeneratorOptions,
    generate_many,
    generate_scenario,
    parse_mix,
    save_scenarios,
)
from delegation.errors import InputError
from delegation.geo import GeoPoint, distance_m
from delegation.tst import leaves, parse_and_validate, walk


def test_same_seed_gives_identical_scenario() -> None:
    a = generate_scenario(seed=7, units=6, tasks=25, site="motala")
    b = generate_scenario(GeneratorOptions(seed=7, units=6, tasks=25, site="motala"))
    assert a == b
    assert yaml.safe_dump(a) == yaml.safe_dump(b)


def test_different_seed_gives_different_scenario() -> None:
    a = generate_scenario(seed=1, units=4, tasks=10)
    b = generate_scenario(seed=2, units=4, tasks=10)
    assert a["name"] != b["name"]
    assert a["agents"] != b["agents"]
    assert a["mission"] != b["mission"]


def test_generate_many_uses_consecutive_seeds() -> None:
    many = generate_many(GeneratorOptions(seed=10, units=2, tasks=3), 3)
    assert [s["name"] for s in many] == [f"gen-granso-u2-t3-s{i}" for i in (10, 11, 12)]
    assert many[1] == generate_scenario(seed=11, units=2, tasks=3)


@pytest.mark.parametrize("structure", ["mixed", "conc", "seq"])
@pytest.mark.parametrize("site", sorted(SITES))
def test_generated_mission_is_valid_and_complete(site: str, structure: str) -> None:
    data = generate_scenario(seed=3, units=5, tasks=30, site=site, structure=structure)
    tree = parse_and_validate(data["mission"])
    tasks = leaves(tree)
    assert len(tasks) == 30
    assert {t.name for t in tasks} <= set(TASK_TYPES)
    assert len(data["agents"]) == 5
    assert len({a["name"] for a in data["agents"]}) == 5
    # Every task type generated is offered by some unit.
    offered = {t for a in data["agents"] for t in a["tasks"]}
    assert {t.name for t in tasks} <= offered
    if structure != "mixed":
        assert tree.name == structure
        assert all(not c.is_control for c in tree.children)
    # Everything lies near the site.
    centre = GeoPoint(latitude=SITES[site].latitude, longitude=SITES[site].longitude)
    for agent in data["agents"]:
        assert distance_m(centre, GeoPoint(**agent["position"])) <= 2000.0 * 0.5 + 1.0
    for t in tasks:
        point = t.params.get("waypoint") or t.params.get("geopoint")
        if point is not None:
            assert distance_m(centre, GeoPoint(**point)) <= 2000.0 + 1.0


def test_mix_selects_task_types() -> None:
    data = generate_scenario(seed=0, units=3, tasks=40, mix=parse_mix("move-to=3,search-area=1"))
    counts = Counter(t.name for t in leaves(parse_and_validate(data["mission"])))
    assert set(counts) == {"move-to", "search-area"}
    assert counts["move-to"] > counts["search-area"]


def test_mixed_structure_has_conc_and_seq() -> None:
    data = generate_scenario(seed=5, units=3, tasks=60)
    names = {n.name for _, n in walk(parse_and_validate(data["mission"])) if n.is_control}
    assert names == {"conc", "seq"}


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"site": "atlantis"}, "site"),
        ({"units": 0}, "units"),
        ({"tasks": 0}, "tasks"),
        ({"structure": "tree"}, "structure"),
        ({"mix": {"fly": 1.0}}, "mix"),
    ],
)
def test_bad_options_are_input_errors(overrides: dict[str, object], field: str) -> None:
    with pytest.raises(InputError) as info:
        generate_scenario(**overrides)  # type: ignore[arg-type]
    assert any(p.field == field for p in info.value.problems)


def test_parse_mix_rejects_unknown_and_bad_weights() -> None:
    assert parse_mix("move-to, search-area=2") == {"move-to": 1.0, "search-area": 2.0}
    with pytest.raises(InputError, match="fly"):
        parse_mix("fly=1")
    with pytest.raises(InputError, match="not a number"):
        parse_mix("move-to=x")
    with pytest.raises(InputError, match="positive"):
        parse_mix("move-to=0")


def test_saved_scenarios_load_back(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from delegation.scenario import load_scenario

    data = [generate_scenario(seed=s, units=3, tasks=8, homes=True) for s in (0, 1)]
    paths = save_scenarios(data, tmp_path / "gen")
    assert [p.name for p in paths] == [f"{d['name']}.yaml" for d in data]
    for path, original in zip(paths, data, strict=True):
        assert yaml.safe_load(path.read_text()) == original
        scenario = load_scenario(path)
        assert scenario.name == original["name"]
        units = scenario.units()
        assert [u.name for u in units] == [a["name"] for a in original["agents"]]
        assert all(u.home is not None for u in units)
        assert units[0].speeds == original["agents"][0]["speeds"]
        assert len(leaves(scenario.tree())) == 8
