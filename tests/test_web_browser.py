"""The operator page in a real browser: Debian's Chromium, headless, driven by Playwright, against
the demo's fleet, engine and service on a private mosquitto with the page's server in a thread.

What an operator relies on: the units appear on the map; a mission pasted into the page shows its
plan per strategy, starts, and reaches ``succeeded`` on the page (after ``$enough`` for its
open-ended look-at-position); Cancel aborts a running mission (dropped on the page as a file);
a unit whose heartbeat stops is shown as lost. The page loads nothing from outside the server.

``DELEGATION_UI_SCREENSHOTS=docs/ui`` saves overview.png, preview.png, mission.png and shared.png
there (the README's pictures). Chromium: /usr/bin/chromium or ``$CHROMIUM`` (``.ci/run`` installs
it); Playwright's own browser download is never used.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from delegation.fleet import FleetRegistry
from delegation.local import LocalSystem
from delegation.runtime.broker import PrivateMosquitto, mosquitto_binary
from delegation.scenario import load_scenario, scenario_from_dict
from delegation.service import ServiceConfig
from delegation.sim import SimFleet

playwright_api = pytest.importorskip("playwright.sync_api")
expect = playwright_api.expect

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "scenarios" / "demo.yaml"
CHROMIUM = os.environ.get("CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]
SHOTS = os.environ.get("DELEGATION_UI_SCREENSHOTS")
#: Simulated time runs this much faster: the demo mission (about 60-80 s planned) takes seconds.
#: Slower for screenshots, so that the timeline's actual bars can be compared with the plan's.
SPEEDUP = 2.0 if SHOTS else 30.0
#: The page judges a unit lost after 3 heartbeat periods, here at least 2 s (its default is 5 s):
#: the spare unit beats at 4 Hz, so the rule applies unchanged, in less than half the time.
LOST_AFTER = 2.0

pytestmark = [
    pytest.mark.mqtt,
    pytest.mark.slow,
    pytest.mark.xdist_group("chromium"),  # one worker: Chromium and the demo system start once
    pytest.mark.skipif(mosquitto_binary() is None, reason="no mosquitto binary"),
    pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"no Chromium at {CHROMIUM} "
                       "(apt-get install chromium; .ci/run does)"),
]


@dataclass
class Served:
    """The running system and the page's address."""

    system: LocalSystem
    url: str
    prefix: str
    settings: Any
    bridge: Any


@pytest.fixture(scope="module")
def served() -> Iterator[Served]:
    """Broker, the demo's fleet + engine + service, and the page's server (bridge + uvicorn)."""
    from delegation.web.app import create_app
    from delegation.web.bridge import Bridge
    from delegation.web.server import WebServer

    prefix = f"ui-{uuid.uuid4().hex[:8]}"
    with PrivateMosquitto() as broker:
        settings = broker.settings()
        # The page is under test here, not fault handling: units and the engine get 15 s
        # before the service judges them lost, so a worker starved of CPU by the rest of the
        # suite (4 workers, 2 cores, Chromium) does not re-delegate the mission mid-test.
        config = ServiceConfig(min_heartbeat_timeout=15.0)
        with LocalSystem.from_scenario(load_scenario(DEMO), settings=settings, prefix=prefix,
                                       speedup=SPEEDUP, config=config) as system:
            bridge = Bridge(settings, prefix=prefix, service=system.config.name,
                            sender="ui-tester", time_scale=SPEEDUP).start()
            bridge.view.timeout = FleetRegistry(min_timeout=LOST_AFTER).timeout
            try:
                server = WebServer(create_app(bridge), "127.0.0.1", 0).start()
                try:
                    yield Served(system, server.url, prefix, settings, bridge)
                finally:
                    server.stop()
            finally:
                bridge.stop()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with playwright_api.sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page(browser: Any, served: Served) -> Iterator[Any]:
    """A fresh page on the operator page, live (its first snapshot applied). It records every
    request and every script error; the test fails on an error or a request off the server."""
    context = browser.new_context(viewport={"width": 1400, "height": 900})
    p = context.new_page()
    requests: list[str] = []
    errors: list[str] = []
    p.on("request", lambda r: requests.append(r.url))
    p.on("pageerror", lambda e: errors.append(str(e)))
    p.goto(served.url + "/")
    p.wait_for_selector("body[data-ready]", timeout=15_000)
    expect(p.locator("#conn")).to_have_attribute("data-state", "live")
    try:
        yield p
    finally:
        context.close()
    assert errors == [], f"script errors on the page: {errors}"
    outside = [u for u in requests if not (u.startswith(served.url) or u.startswith("data:"))]
    assert outside == [], f"the page fetched from outside its server: {outside}"


def shot(page: Any, name: str) -> None:
    if SHOTS:
        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(SHOTS) / name))


def drawn(page: Any) -> dict[str, Any]:
    """What the map has drawn (names, positions, statuses; mission and preview layers)."""
    return dict(page.evaluate("window.delegationUI.describe()"))


def drop_file(page: Any, name: str, text: str) -> None:
    """Drop a file on the submit box, as from a file manager."""
    transfer = page.evaluate_handle(
        "([name, text]) => { const dt = new DataTransfer();"
        " dt.items.add(new File([text], name, {type: 'application/json'})); return dt; }",
        [name, text],
    )
    page.dispatch_event("#drop-zone", "drop", {"dataTransfer": transfer})
    expect(page.locator("#mission-text")).to_have_value(text)
    expect(page.locator("#mission-text")).to_have_attribute("data-file", name)


def start_from_page(page: Any, mission_text: str) -> str:
    """Drop a mission file on the page, press Start, and return the id the page reports."""
    drop_file(page, "mission.json", mission_text)
    page.click("#btn-start")
    result = page.locator("#submit-result")
    expect(result).to_have_attribute("data-mission-id", re.compile(r".+"), timeout=30_000)
    mission_id = str(result.get_attribute("data-mission-id"))
    expect(page.locator("#mission-detail")).to_have_attribute("data-mission-id", mission_id)
    return mission_id


def test_units_appear_on_the_map(page: Any, served: Served) -> None:
    scenario = load_scenario(DEMO)
    for agent in scenario.agents:
        row = page.locator(f'#units tr[data-unit="{agent.name}"]')
        expect(row).to_have_attribute("data-status", "alive", timeout=15_000)
        expect(row).to_contain_text(agent.name)
    expect(page.locator("#map")).to_have_attribute("data-units-drawn", str(len(scenario.agents)))
    units = drawn(page)["units"]
    # units without a task hold still: each marker is where the server says the unit is (the
    # scenario's start, unless another test of this module flew it elsewhere first)
    state = page.evaluate("fetch('/api/state').then((r) => r.json())")
    where = {u["name"]: (u["latitude"], u["longitude"]) for u in state["units"]}
    for agent in scenario.agents:
        u = units[agent.name]
        assert u["onMap"] and u["status"] == "alive"
        assert abs(u["lat"] - where[agent.name][0]) < 1e-4
        assert abs(u["lon"] - where[agent.name][1]) < 1e-4
    # the map's vector layers are canvas (not one DOM node per unit) and there is a scale
    assert page.locator("#map canvas").count() >= 2
    expect(page.locator("#map .leaflet-control-scale-line")).to_be_visible()
    expect(page.locator("#events li[data-kind='unit-new']").first).to_be_visible()


def test_the_grid_labels_each_line_once(page: Any) -> None:
    """Without tiles the map's metric grid labels each line in view once, east along the top and
    north along the left edge (labels drawn per tile repeated mid-view); still so after a pan."""
    overlay = page.locator("#map canvas.metric-grid-labels")
    expect(overlay).to_have_count(1, timeout=15_000)
    expect(overlay).to_have_attribute("data-labels", re.compile(r"E.*N"))

    def labels() -> list[str]:
        found = json.loads(str(overlay.get_attribute("data-labels")))
        assert len(found) == len(set(found)), f"a label repeats: {found}"
        assert any(t.endswith(" E") for t in found) and any(t.endswith(" N") for t in found)
        return list(found)

    before = labels()
    box = page.locator("#map").bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(cx, cy)
    page.mouse.down()
    page.mouse.move(cx - 400, cy - 300, steps=8)
    page.mouse.up()
    page.wait_for_function(
        "(old) => document.querySelector('#map canvas.metric-grid-labels').dataset.labels !== old",
        arg=json.dumps(before, separators=(",", ":")))
    after = labels()
    assert after != before


def test_a_submitted_mission_shows_its_plan_and_succeeds(page: Any, served: Served) -> None:
    page.fill("#mission-text", DEMO.read_text())
    page.click("#btn-preview")
    rows = page.locator("#preview tbody tr")
    expect(rows).to_have_count(3, timeout=60_000)  # nearest, auction, optimal
    makespans = {}
    for i in range(3):
        row = rows.nth(i)
        name = str(row.get_attribute("data-strategy"))
        makespans[name] = float(str(row.get_attribute("data-makespan")))
    assert set(makespans) == {"nearest", "auction", "optimal"}
    assert all(m > 0 for m in makespans.values())
    assert makespans["optimal"] <= makespans["auction"] + 1e-6
    best = min(makespans, key=lambda k: makespans[k])
    expect(page.locator(f'#preview tr[data-strategy="{best}"] input[type=radio]')).to_be_checked()
    assert drawn(page)["preview"] > 0, "the chosen plan's routes and tasks are drawn"
    expect(page.locator("#missions tbody tr")).to_have_count(0)  # a dry run starts nothing
    shot(page, "preview.png")

    page.click("#btn-start")
    result = page.locator("#submit-result")
    expect(result).to_have_attribute("data-mission-id", re.compile(r".+"), timeout=30_000)
    mission_id = str(result.get_attribute("data-mission-id"))
    expect(result).to_contain_text(f"with {best}")
    detail = page.locator("#mission-detail")
    expect(detail).to_have_attribute("data-mission-id", mission_id)
    row = page.locator(f'#missions tr[data-mission-id="{mission_id}"]')
    expect(row).to_contain_text(best)
    # the plan: every task of the tree is on the timeline with its planned interval
    expect(page.locator("#gantt g[data-node-uuid] rect.plan")).to_have_count(6, timeout=15_000)
    expect(page.locator("#tree li[data-node-uuid]").first).to_be_visible()
    assert drawn(page)["missions"].get(mission_id, 0) > 0, "its tasks and routes are on the map"

    if SHOTS:  # the overview mid-flight: tracks beside the routes
        page.wait_for_function(
            "document.querySelectorAll(\"#gantt g[data-status='succeeded']\").length >= 2",
            timeout=90_000)
        shot(page, "overview.png")

    # look-at-position is open-ended: once the five other tasks are done, the operator says
    # $enough, as `delegation submit --enough` would
    tasks = page.locator("#gantt g[data-node-uuid]")
    try:
        expect(page.locator("#gantt g[data-status='succeeded']")).to_have_count(5,
                                                                               timeout=90_000)
    except AssertionError:  # say what each side knows, to find where a status stopped
        service = served.system.service
        known = service.inspect(lambda core: (lambda m: {
            "status": m.status.value, "nodes": dict(m.node_status),
            "redelegations": m.redelegations, "fail-reason": m.fail_reason})(
                core.book.get(mission_id))) if service is not None else {}
        page_nodes = page.evaluate("fetch('/api/state').then((r) => r.json())")
        # The page's server (its view) and its browser side (the timeline's DOM), told apart.
        view = page.evaluate(f"fetch('/api/missions/{mission_id}').then((r) => r.json())")
        dom = page.evaluate("Array.from(document.querySelectorAll('#gantt g[data-node-uuid]'))"
                            ".map((g) => [g.dataset.nodeUuid, g.dataset.status])")
        raise AssertionError(f"not every task succeeded: service {known}; page missions "
                             f"{page_nodes.get('missions')}; page view {view}; "
                             f"timeline {dom}") from None
    expect(page.locator("#tree li[data-status='running'] > .node-name").filter(
        has_text="look-at-position")).to_have_count(1)
    page.click("#btn-enough")
    expect(page.locator("#detail-response")).to_have_text("$enough: ok", timeout=30_000)
    expect(detail).to_have_attribute("data-status", "succeeded", timeout=30_000)
    expect(row).to_have_attribute("data-status", "succeeded")
    # every task finished, and the timeline shows when each ran
    expect(tasks.locator("rect.actual")).to_have_count(6, timeout=15_000)
    statuses = [str(tasks.nth(i).get_attribute("data-status")) for i in range(tasks.count())]
    assert statuses and all(s in ("succeeded", "finished") for s in statuses), statuses
    expect(page.locator(f"#events li[data-kind='succeeded'][data-mission='{mission_id}']")
           ).to_have_count(1)
    for b in ("#btn-enough", "#btn-pause", "#btn-continue", "#btn-cancel"):
        expect(page.locator(b)).to_be_disabled()
    shot(page, "mission.png")
    page.click("#detail-close")
    expect(detail).to_be_hidden()


def test_start_runs_the_previewed_plan_the_operator_picks(page: Any, served: Served) -> None:
    """Every strategy ticked, previewed for the total-time objective: the page suggests the plan
    best by that objective (not the first ticked, nor the shortest makespan); the operator picks
    another with a click on its row; Start names it, runs it (its plan is the one previewed), and
    a changed objective forgets the preview rather than start a plan nobody compared."""
    page.fill("#mission-text", DEMO.read_text())
    page.select_option("#objective", "total")
    page.click("#btn-preview")
    rows = page.locator("#preview tbody tr")
    expect(rows).to_have_count(3, timeout=60_000)
    previewed = {}
    for i in range(3):
        row = rows.nth(i)
        previewed[str(row.get_attribute("data-strategy"))] = (
            float(str(row.get_attribute("data-makespan"))),
            float(str(row.get_attribute("data-total-time"))))
    assert set(previewed) == {"nearest", "auction", "optimal"}
    suggested = min(previewed, key=lambda k: previewed[k][1])
    expect(page.locator(f'#preview tr[data-strategy="{suggested}"] input[type=radio]')
           ).to_be_checked()
    expect(page.locator("#btn-start")).to_have_text(f"Start {suggested}")
    picked = "auction" if suggested != "auction" else "nearest"  # deterministic planners
    page.click(f'#preview tr[data-strategy="{picked}"] td:nth-child(2)')  # the name, not the radio
    expect(page.locator(f'#preview tr[data-strategy="{picked}"] input[type=radio]')).to_be_checked()
    expect(page.locator("#btn-start")).to_have_text(f"Start {picked}")

    page.select_option("#objective", "makespan")  # not what was compared: the preview goes
    expect(page.locator("#preview")).to_be_hidden()
    expect(page.locator("#btn-start")).to_have_text("Start")
    page.select_option("#objective", "total")
    page.click("#btn-preview")
    expect(page.locator(f'#preview tr[data-strategy="{picked}"]')).to_have_count(1,
                                                                                 timeout=60_000)
    page.click(f'#preview tr[data-strategy="{picked}"] td:nth-child(3)')
    expect(page.locator("#btn-start")).to_have_text(f"Start {picked}")

    page.click("#btn-start")
    result = page.locator("#submit-result")
    expect(result).to_have_attribute("data-mission-id", re.compile(r".+"), timeout=30_000)
    mission_id = str(result.get_attribute("data-mission-id"))
    expect(result).to_contain_text(f"with {picked}")
    state = page.evaluate("fetch('/api/state').then((r) => r.json())")
    (started,) = [m for m in state["missions"] if m["id"] == mission_id]
    assert started["strategy"] == picked, started
    assert started["planned-makespan"] == pytest.approx(previewed[picked][0], abs=1e-3), (
        "the started plan is the one previewed", started, previewed)
    page.click("#btn-cancel")
    expect(page.locator("#mission-detail")).to_have_attribute("data-status", "aborted",
                                                               timeout=30_000)


def _timed(plan: dict[str, Any]) -> list[tuple[str, str, float, float]]:
    return sorted((a["node-uuid"], a["execunit"], a["start"], a["end"])
                  for a in plan["assignments"])


def test_start_starts_the_optimal_plan_previewed_not_a_new_one(page: Any, served: Served) -> None:
    """Issue 22: ``optimal`` within a time limit may plan differently each time; Start starts the
    plan the operator compared (its tree, units and times), and the page says it did."""
    page.fill("#mission-text", DEMO.read_text())
    for box in page.locator("#strategy-choices input").all():
        if box.get_attribute("value") != "optimal":
            box.uncheck()
    page.fill("#time-limit", "0.5")
    page.click("#btn-preview")
    expect(page.locator("#preview tbody tr")).to_have_count(1, timeout=60_000)
    expect(page.locator("#btn-start")).to_have_text("Start optimal")
    previewed = page.evaluate("window.delegationUI.store.submit.plans.optimal")
    assert previewed["preview-id"], previewed
    page.click("#btn-start")
    result = page.locator("#submit-result")
    expect(result).to_have_attribute("data-mission-id", re.compile(r".+"), timeout=30_000)
    expect(result).to_contain_text("with optimal (the plan previewed)")
    mission_id = str(result.get_attribute("data-mission-id"))
    assert mission_id == previewed["tst"]["common_params"]["node-uuid"], "the previewed tree"
    detail = page.evaluate(f"fetch('/api/missions/{mission_id}').then((r) => r.json())")
    assert detail["plan"]["from-preview"] == {"id": previewed["preview-id"], "started": True}
    assert _timed(detail["plan"]) == _timed(previewed), "the previewed units and times"
    assert detail["plan"]["makespan"] == previewed["makespan"]
    # the page shows the operator's tree with the previewed plan's times
    expect(page.locator("#gantt g[data-node-uuid] rect.plan")).to_have_count(6, timeout=15_000)
    page.click("#btn-cancel")
    expect(page.locator("#mission-detail")).to_have_attribute("data-status", "aborted",
                                                               timeout=30_000)


def test_a_preview_that_no_longer_holds_is_planned_again_and_the_page_says_so(
        page: Any, served: Served) -> None:
    """Never silently: a start whose preview the service no longer holds (here: expired) is
    planned again, and the page's result says so with the service's reason."""
    from delegation.service.previews import MAX_AGE

    service = served.system.service
    assert service is not None
    page.fill("#mission-text", json.dumps(FAR_MOVE, indent=1))
    for box in page.locator("#strategy-choices input").all():
        if box.get_attribute("value") != "auction":
            box.uncheck()
    page.click("#btn-preview")
    expect(page.locator("#preview tbody tr")).to_have_count(1, timeout=60_000)
    service.inspect(lambda core: setattr(core.planning.previews, "max_age", 0.0))
    try:
        page.click("#btn-start")
        result = page.locator("#submit-result")
        expect(result).to_have_attribute("data-mission-id", re.compile(r".+"), timeout=30_000)
    finally:
        service.inspect(lambda core: setattr(core.planning.previews, "max_age", MAX_AGE))
    expect(result).to_contain_text("with auction, planned again: preview")
    expect(result).to_have_attribute("data-replanned", re.compile("is not known"))
    page.click("#btn-cancel")
    expect(page.locator("#mission-detail")).to_have_attribute("data-status", "aborted",
                                                               timeout=30_000)


#: About 430 m x 300 m north of the demo's units: `auction` shares it between the two drones.
SHARED_SEARCH = {
    "name": "search-area",
    "common_params": {"execunit": "*"},
    "params": {"speed": "standard", "area": [
        {"latitude": lat, "longitude": lon, "altitude": 40.0}
        for lat, lon in ((57.7620, 16.6800), (57.7620, 16.6872), (57.7647, 16.6872),
                         (57.7647, 16.6800))]},
}


def test_a_shared_search_shows_its_parts_per_unit_and_one_tree_node(page: Any) -> None:
    """Issue 21 on the page: the preview and the mission draw each part of a shared search in
    its unit's colour, the timeline puts each part in its unit's lane (with its actual interval
    once flown), and the tree keeps the operator's one search node."""
    page.fill("#mission-text", json.dumps(SHARED_SEARCH, indent=1))
    for box in page.locator("#strategy-choices input").all():
        if box.get_attribute("value") != "auction":
            box.uncheck()
    page.click("#btn-preview")
    expect(page.locator("#preview tbody tr")).to_have_count(1, timeout=60_000)
    previewed = page.evaluate("window.delegationUI.store.submit.plans.auction")
    (search,) = previewed["shared-searches"]
    units = {p["execunit"].strip("/") for p in search["parts"]}
    assert len(units) >= 2, search
    parts = drawn(page)["parts"]["preview"]
    assert {p["unit"] for p in parts} == units
    assert len({p["color"] for p in parts}) == len(units), "each unit's part in its colour"

    page.click("#btn-start")
    result = page.locator("#submit-result")
    expect(result).to_have_attribute("data-mission-id", re.compile(r".+"), timeout=30_000)
    mission_id = str(result.get_attribute("data-mission-id"))
    lanes = page.locator(f"#gantt g[data-part-of='{search['node-uuid']}']")
    expect(lanes).to_have_count(len(search["parts"]), timeout=15_000)
    assert {str(lanes.nth(i).get_attribute("data-unit")) for i in range(lanes.count())} == units
    ys = {lanes.nth(i).locator("rect.plan").get_attribute("y") for i in range(lanes.count())}
    assert len(ys) == len(units), "one lane per unit"
    tree_nodes = page.locator("#tree li[data-node-uuid]")
    expect(tree_nodes).to_have_count(1)  # the operator's one search node, no part
    node = page.locator(f"#tree li[data-node-uuid='{search['node-uuid']}']")
    expect(node).to_have_attribute("data-parts", str(len(search["parts"])))
    for unit in units:
        expect(node.locator(".node-unit")).to_contain_text(unit)
    page.wait_for_function(f"(window.delegationUI.describe().parts['{mission_id}'] || [])"
                           f".length === {len(search['parts'])}")
    # flown: each part's actual interval, from what its unit says it executes
    expect(lanes.locator("rect.actual")).to_have_count(len(search["parts"]), timeout=60_000)
    if SHOTS:  # mid-flight, the parts' tracks beside them (simulated time runs slow here)
        page.wait_for_function("Object.values(window.delegationUI.describe().units)"
                               ".filter((u) => u.trackPoints > 40).length >= 2", timeout=120_000)
        shot(page, "shared.png")
        page.click("#btn-cancel")
        return
    expect(page.locator("#mission-detail")).to_have_attribute("data-status", "succeeded",
                                                               timeout=60_000)
    statuses = {lanes.nth(i).get_attribute("data-status") for i in range(lanes.count())}
    assert statuses == {"succeeded"}, statuses  # the engine's feedback for each part


def _plan(makespan: float | None, total: float | None, distance: float = 100.0,
          **more: Any) -> dict[str, Any]:
    return {"makespan": makespan, "total-time": total, "total-distance": distance, **more}


# (plans in the order ticked, objective, the suggestion)
SUGGESTIONS: list[tuple[dict[str, Any], str, str | None]] = [
    ({"nearest": _plan(90, 100), "auction": _plan(60, 120), "optimal": _plan(70, 95)},
     "makespan", "auction"),
    ({"nearest": _plan(90, 100), "auction": _plan(60, 120), "optimal": _plan(70, 95)},
     "total", "optimal"),
    # a plan leaving a task unassigned is shorter, not better
    ({"nearest": _plan(20, 20, unassigned=["t3"]), "auction": _plan(60, 120)},
     "makespan", "auction"),
    ({"nearest": _plan(20, 20, feasible=False), "auction": _plan(60, 120)}, "makespan", "auction"),
    # ties on the objective: the other measure, then distance, then the order ticked
    ({"nearest": _plan(60, 130), "auction": _plan(60, 120)}, "makespan", "auction"),
    ({"nearest": _plan(60, 120, 900), "auction": _plan(60, 120, 800)}, "makespan", "auction"),
    ({"nearest": _plan(60, 120), "auction": _plan(60, 120)}, "makespan", "nearest"),
    # unknown measures (open-ended tasks) rank last, not first
    ({"nearest": _plan(None, None), "auction": _plan(60, 120)}, "makespan", "auction"),
    ({"nearest": {"fail-reason": "timeout"}, "auction": _plan(60, 120)}, "makespan", "auction"),
    ({"nearest": {"fail-reason": "timeout"}}, "makespan", None),
]


def test_the_suggested_plan_is_best_by_the_objective(page: Any) -> None:
    """The page's suggestion (submit.js ``suggest``), table-driven in the page's own browser."""
    found = page.evaluate(
        "async (cases) => { const m = await import('/static/submit.js');"
        " return cases.map(([plans, objective]) => m.suggest(plans, objective)); }",
        [[plans, objective] for plans, objective, _ in SUGGESTIONS])
    assert found == [expected for _, _, expected in SUGGESTIONS]


FAR_MOVE = {
    "name": "conc",
    "children": [{
        "name": "move-to",
        "common_params": {"execunit": "*"},
        "params": {"speed": "slow",
                   "waypoint": {"latitude": 57.785, "longitude": 16.68, "altitude": 40.0}},
    }],
}


def test_cancel_from_the_page_aborts_the_mission(page: Any, served: Served) -> None:
    mission_id = start_from_page(page, json.dumps(FAR_MOVE, indent=1))
    detail = page.locator("#mission-detail")
    # ~2.8 km at 4 m/s: minutes of simulated flight, so it is still running when cancelled
    expect(detail).to_have_attribute("data-status", re.compile("started|running"),
                                     timeout=30_000)
    page.click("#btn-cancel")
    expect(page.locator("#detail-response")).to_have_text(re.compile(r"^cancel: (ok|pending)$"),
                                                          timeout=30_000)
    expect(page.locator("#detail-error")).to_be_hidden()
    expect(detail).to_have_attribute("data-status", "aborted", timeout=30_000)
    expect(page.locator(f'#missions tr[data-mission-id="{mission_id}"]')
           ).to_have_attribute("data-status", "aborted")


def test_a_bad_mission_shows_the_servers_fail_reason(page: Any) -> None:
    page.fill("#mission-text", '{"name": "conc", "children": [{"name": "no-such-task"}]}')
    page.click("#btn-preview")
    error = page.locator("#submit-error")
    expect(error).to_be_visible(timeout=30_000)
    expect(error).to_contain_text("preview failed: 400")
    expect(error).to_contain_text("no-such-task")
    expect(page.locator("#preview")).to_be_hidden()


SPARE = {
    "name": "spare",
    "agents": [{
        "name": "spare0", "type": "air", "rate": 2.0,
        "position": {"latitude": 57.7598, "longitude": 16.6790, "altitude": 40.0},
        "speeds": {"slow": 4.0, "standard": 8.0, "fast": 14.0},
        # offers nothing the other tests' missions ask for, so the service never plans it
        "tasks": ["land"],
    }],
    "mission": {"name": "land", "common_params": {"execunit": "*"}, "params": {}},
}


def test_a_unit_that_stops_is_shown_lost(page: Any, served: Served) -> None:
    spare = scenario_from_dict(SPARE)
    fleet = SimFleet(served.settings, spare.units(), prefix=served.prefix, rates={"spare0": 4.0})
    fleet.start()
    try:
        row = page.locator('#units tr[data-unit="spare0"]')
        expect(row).to_have_attribute("data-status", "alive", timeout=15_000)
        page.wait_for_function("window.delegationUI.describe().units.spare0 !== undefined")
    finally:
        fleet.stop()
    # heartbeats stop: lost after 3 periods, at least LOST_AFTER (docs/protocol.md §11: 5 s)
    expect(row).to_have_attribute("data-status", "lost", timeout=30_000)
    expect(row.locator(".badge")).to_have_text("lost")
    page.wait_for_function("window.delegationUI.describe().units.spare0.status === 'lost'")
    assert drawn(page)["units"]["spare0"]["onMap"], "a lost unit stays on the map, marked lost"
    expect(page.locator("#events li[data-kind='unit-lost'][data-unit='spare0']")).to_have_count(1)
    expect(page.locator("#fleet-summary")).to_have_attribute("data-lost", re.compile(r"[1-9]"))


def test_tiles_and_tokens(browser: Any, served: Served) -> None:
    """With a tile URL the map uses it and its attribution instead of the grid; with users, the
    page needs its token once (as /?token=...) and then acts as that user."""
    from delegation.web.app import create_app
    from delegation.web.server import WebServer

    tiles = "/static/vendor/leaflet/images/layers.png?z={z}&x={x}&y={y}"  # any image will do
    app = create_app(served.bridge, users={"tok-alice": "alice"}, tile_url=tiles,
                     tile_attribution="Test tiles")
    with WebServer(app, "127.0.0.1", 0) as server:
        context = browser.new_context(viewport={"width": 1200, "height": 800})
        requests: list[str] = []
        try:
            p = context.new_page()
            p.on("request", lambda r: requests.append(r.url))
            p.goto(server.url + "/")
            conn = p.locator("#conn")
            expect(conn).to_have_attribute("data-state", "error")
            expect(conn).to_contain_text("401")
            p.goto(server.url + "/?token=tok-alice")
            p.wait_for_selector("body[data-ready]", timeout=15_000)
            assert p.url == server.url + "/", "the token is swapped for a cookie"
            expect(p.locator("#user")).to_have_text("as alice")
            expect(p.locator("#units tr[data-unit='dji0']")).to_have_count(1)
            tile = p.locator(".leaflet-tile-pane img.leaflet-tile").first
            expect(tile).to_have_attribute("src", re.compile(r"layers\.png\?z=\d+&x=\d+&y=\d+"))
            expect(p.locator(".leaflet-control-attribution")).to_contain_text("Test tiles")
            expect(p.locator(".metric-grid")).to_have_count(0)
        finally:
            context.close()
        outside = [u for u in requests if not u.startswith(server.url)]
        assert outside == [], outside
