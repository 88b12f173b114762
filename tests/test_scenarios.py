"""Scenario files: every bundled one loads and validates; bad files get one clear line."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from delegation.costs import cost_tables
from delegation.errors import InputError
from delegation.geo import distance_m
from delegation.scenario import (
    Scenario,
    berlin52_scenario,
    load_scenario,
    read_tsplib,
    scenario_from_dict,
)
from delegation.tst import ExecUnitKind, TstNode, classify_execunit, leaves, read_geopoint, walk

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "scenarios"
BERLIN52 = ROOT / "benchmarks" / "data" / "berlin52.tsp"  # TSPLIB, bundled
FILES = sorted(p for p in SCENARIOS.glob("*") if p.suffix in (".yaml", ".yml", ".json"))
SITES = {"granso": (57.76, 16.68), "motala": (58.54, 15.04), "linkoping": (58.41, 15.62)}


@pytest.fixture(scope="module")
def bundled() -> dict[str, Scenario]:
    return {p.stem: load_scenario(p) for p in FILES}


def test_there_are_enough_scenarios_in_both_formats() -> None:
    assert len(FILES) >= 9  # eight and the demo
    assert {p.suffix for p in FILES} >= {".yaml", ".json"}
    assert (SCENARIOS / "demo.yaml").exists()


@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_every_bundled_scenario_loads_and_validates(path: Path) -> None:
    scenario = load_scenario(path)
    assert scenario.description.strip()
    tree = scenario.tree()
    tasks = leaves(tree)
    assert tasks
    units = scenario.units()
    assert len({u.name for u in units}) == len(units)
    tables = cost_tables(units, tasks)
    assert tables.capable.shape == (len(units), len(tasks))
    assert np.isfinite(tables.work_distance[tables.capable]).all()
    # every scenario sits at a real WARA-PS site
    lat, lon = units[0].position.latitude, units[0].position.longitude
    assert min(math.hypot(lat - a, lon - b) for a, b in SITES.values()) < 0.1


def _names(tree: TstNode) -> list[str]:
    return [n.name for n in leaves(tree)]


def test_the_set_covers_what_the_issue_asks(bundled: dict[str, Scenario]) -> None:
    trees = {k: s.tree() for k, s in bundled.items()}
    # many move-tos under one conc (a routing problem)
    assert any(
        t.name == "conc" and sum(c.name == "move-to" for c in t.children) >= 10
        for t in trees.values()
    )
    # aliases
    assert any(
        classify_execunit(n.execunit)[0] is ExecUnitKind.ALIAS
        for t in trees.values()
        for _, n in walk(t)
    )
    # a mixed fleet: air, surface and ground together
    assert any({a.type for a in s.agents} >= {"air", "surface", "ground"} for s in bundled.values())
    # the three search tasks
    all_tasks = {name for t in trees.values() for name in _names(t)}
    assert {"search-area", "search-areas", "search-around-position"} <= all_tasks
    # battery-limited units and units with home
    assert any(
        a.battery is not None and a.battery < 0.5 for s in bundled.values() for a in s.agents
    )
    assert any(all(a.home is not None for a in s.agents) for s in bundled.values())


def test_routing_scenario(bundled: dict[str, Scenario]) -> None:
    tree = bundled["granso-routing"].tree()
    assert tree.name == "conc" and len(tree.children) >= 10
    assert all(c.name == "move-to" for c in tree.children)


def test_seq_whose_steps_need_different_units(bundled: dict[str, Scenario]) -> None:
    s = bundled["granso-seq-handover"]
    tree = s.tree()
    assert tree.name == "seq"
    t = cost_tables(s.units(), leaves(tree))
    capable = [tuple(np.flatnonzero(t.capable[:, j])) for j in range(t.n_tasks)]
    assert all(len(c) == 1 for c in capable)
    assert len({c[0] for c in capable}) >= 3  # at least three different units take turns


def test_impossible_tasks(bundled: dict[str, Scenario]) -> None:
    s = bundled["granso-impossible"]
    t = cost_tables(s.units(), leaves(s.tree()))
    nobody = [t.tasks[j].name for j in range(t.n_tasks) if not t.capable[:, j].any()]
    assert sorted(nobody) == ["observe-position", "search-around-position"]
    assert all("does not offer" in (t.reason(u, 1) or "") for u in range(t.n_units))


def test_battery_limited_unit(bundled: dict[str, Scenario]) -> None:
    s = bundled["motala-battery"]
    t = cost_tables(s.units(), leaves(s.tree()))
    dji0 = t.unit_index("dji0")
    assert dji0 is not None
    short = [j for j in range(t.n_tasks) if t.capable[dji0, j]]
    assert len(short) == 1 and t.tasks[short[0]].name == "move-to"
    assert all("endurance" in (t.reason(dji0, j) or "") for j in range(t.n_tasks) if j not in short)
    assert t.capable.any(axis=0).all()  # the others can take everything


def test_homes_and_aliases(bundled: dict[str, Scenario]) -> None:
    homes = bundled["linkoping-homes"]
    assert all(u.home is not None for u in homes.units())
    aliases = bundled["motala-aliases"].tree()
    kinds = [classify_execunit(n.execunit) for _, n in walk(aliases) if not n.is_control]
    assert sum(k == (ExecUnitKind.ALIAS, "A") for k in kinds) == 3
    assert sum(k == (ExecUnitKind.ALIAS, "B") for k in kinds) == 2
    assert (ExecUnitKind.FIXED, "dji3") in kinds
    assert sum(k[0] is ExecUnitKind.FREE for k in kinds) >= 2


def test_demo_is_small_and_quick(bundled: dict[str, Scenario]) -> None:
    s = bundled["demo"]
    units = s.units()
    tasks = leaves(s.tree())
    assert 3 <= len(units) <= 4
    assert 5 <= len(tasks) <= 8
    assert [n.name for n in tasks].count("search-area") == 1
    t = cost_tables(units, tasks)
    assert t.capable.any(axis=0).all()
    assert np.nanmax(t.dist_unit_to_start()) < 1000.0
    assert t.work_distance[np.isfinite(t.work_distance)].max() < 1000.0


def test_yaml_and_json_load_the_same(tmp_path: Path) -> None:
    s = load_scenario(SCENARIOS / "demo.yaml")
    as_json = tmp_path / "demo.json"
    as_json.write_text(json.dumps(s.to_dict()))
    again = load_scenario(as_json)
    assert again.to_dict() == s.to_dict()
    assert again.units() == s.units()


# --------------------------------------------------------------------------- bad files


def _good() -> dict[str, Any]:
    data = yaml.safe_load((SCENARIOS / "demo.yaml").read_text())
    assert isinstance(data, dict)
    return data


def _bad(tmp_path: Path, data: Any, name: str = "bad.yaml", raw: str | None = None) -> InputError:
    path = tmp_path / name
    path.write_text(raw if raw is not None else yaml.safe_dump(data))
    with pytest.raises(InputError) as info:
        load_scenario(path)
    text = str(info.value)
    assert "\n" not in text and str(path) in text
    return info.value


def test_bad_files_name_the_file_and_the_field(tmp_path: Path) -> None:
    d = _good()
    del d["agents"][1]["position"]["latitude"]
    assert "agents[1].position.latitude: missing" in str(_bad(tmp_path, d))

    d = _good()
    d["agents"][0]["type"] = "rocket"
    assert "agents[0].type" in str(_bad(tmp_path, d)) and "rocket" in str(_bad(tmp_path, d))

    d = _good()
    d["agents"][2]["tasks"].append("move_to")
    assert "agents[2].tasks" in str(_bad(tmp_path, d))

    d = _good()
    d["agents"][0]["battery"] = 1.5
    assert "agents[0].battery" in str(_bad(tmp_path, d))

    d = _good()
    d["agents"][0]["speed"] = {"standard": 3.0}  # a typo of speeds
    assert "agents[0].speed: unknown field" in str(_bad(tmp_path, d))

    d = _good()
    d["agents"][0]["speeds"] = {"standard": -3.0}
    assert "agents[0].speeds" in str(_bad(tmp_path, d))

    d = _good()
    d["agents"][1]["name"] = d["agents"][0]["name"]
    assert "agents[1].name: duplicate agent name" in str(_bad(tmp_path, d))

    d = _good()
    del d["description"]  # optional: an operator's quick scenario needs a fleet and a mission
    (tmp_path / "nodesc.yaml").write_text(yaml.safe_dump(d))
    assert load_scenario(tmp_path / "nodesc.yaml").description == ""


def test_bad_missions_name_the_node(tmp_path: Path) -> None:
    d = _good()
    d["mission"]["children"][1]["params"]["waypoint"]["latitude"] = 123.0
    err = str(_bad(tmp_path, d))
    assert "mission root/children[1]" in err and "params.waypoint.latitude" in err

    d = _good()
    d["mission"]["children"][2]["name"] = "fly-around"
    assert "unknown task 'fly-around'" in str(_bad(tmp_path, d))


def test_unreadable_files(tmp_path: Path) -> None:
    assert "not valid YAML (line 2" in str(_bad(tmp_path, None, raw="name: x\n  agents: [\n"))
    assert "not valid JSON" in str(_bad(tmp_path, None, name="bad.json", raw='{"name": '))
    assert "must be a mapping" in str(_bad(tmp_path, None, raw="- just\n- a list\n"))
    with pytest.raises(InputError, match="cannot read"):
        load_scenario(tmp_path / "missing.yaml")
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"\xff\xfename: x\n")
    with pytest.raises(InputError, match=r"binary\.yaml: not UTF-8 text: invalid start byte"):
        load_scenario(binary)
    with pytest.raises(InputError, match=r"binary\.yaml: not UTF-8 text"):
        read_tsplib(binary)


def test_scenario_from_dict_names_its_source() -> None:
    with pytest.raises(InputError, match=r"^generated: agents: missing"):
        scenario_from_dict(
            {"name": "x", "description": "y", "mission": {"name": "conc"}}, "generated"
        )


# --------------------------------------------------------------------------- berlin52


def test_berlin52_scenario() -> None:
    coords = np.array(read_tsplib(BERLIN52))
    assert coords.shape == (52, 2)
    s = berlin52_scenario(BERLIN52, units=3, speed=2.0)
    tree = s.tree()
    assert tree.name == "conc" and len(tree.children) == 51
    assert all(c.name == "move-to" for c in tree.children)
    units = s.units()
    assert [u.name for u in units] == ["u0", "u1", "u2"]
    assert all(u.home == units[0].position for u in units)
    assert all(u.speeds == {"slow": 2.0, "standard": 2.0, "fast": 2.0} for u in units)
    # geodesic distances reproduce the TSPLIB coordinates in metres
    geo = [units[0].position] + [read_geopoint(c.params["waypoint"]) for c in tree.children]
    for i, j in [(0, 1), (1, 2), (5, 40), (0, 51), (10, 33)]:
        want = float(np.hypot(*(coords[i] - coords[j])))
        assert distance_m(geo[i], geo[j]) == pytest.approx(want, rel=2e-3)
    # and the cost tables see them exactly (ENU around the mission)
    t = cost_tables(units, leaves(tree))
    want = np.hypot(*(coords[1:, None, :] - coords[None, 1:, :]).transpose(2, 0, 1))
    assert t.dist_end_to_start() == pytest.approx(want, abs=0.01)
    assert t.dist_unit_to_start()[0] == pytest.approx(
        np.hypot(*(coords[1:] - coords[0]).T), abs=0.01
    )
    near = s.agents[0].position
    assert abs(near.latitude - 57.76) < 0.01 and abs(near.longitude - 16.68) < 0.02


def test_berlin52_arguments_are_checked(tmp_path: Path) -> None:
    tsp = tmp_path / "tiny.tsp"
    tsp.write_text("NAME: tiny\nNODE_COORD_SECTION\n1 0 0\n2 3 4\nEOF\n")
    s = berlin52_scenario(tsp, units=1)
    assert len(s.tree().children) == 1
    with pytest.raises(InputError, match="units"):
        berlin52_scenario(tsp, units=0)
    tsp.write_text("NAME: empty\n")
    with pytest.raises(InputError, match="no coordinates"):
        read_tsplib(tsp)
