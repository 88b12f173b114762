"""Plans that match the fleet: the service's plan vs what the fleet flew, mission after mission.

The simulated fleet flies the scenario's real speeds; the service starts with a wrong idea of
them (``--start defaults``: no profile, the agent types' default speeds, as a ``serve`` without
``--profiles`` has; ``--start scaled``: a profile with every speed times ``--factor``). It learns
each unit's speed per speed class from ``sensor/speed`` while the first mission flies; the
second mission's plan should be within 10 % of what is flown.

    python benchmarks/learning.py                 # demo fleet, 2 missions, speed-up 5
    python benchmarks/learning.py --missions 3 --start scaled --factor 0.5

Prints, per mission: plan makespan, flown makespan (mission seconds: the service's start-to-end
wall time x speed-up) and the error; exit 1 when the last mission is off by more than 10 %.
Open-ended tasks (look-at-*) are left out of the mission: they end when told, not by plan.
"""

from __future__ import annotations

import argparse
import queue
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from delegation.learning import speed_class  # noqa: E402
from delegation.local import LocalSystem  # noqa: E402
from delegation.runtime.client import ServiceClient  # noqa: E402
from delegation.scenario import load_scenario  # noqa: E402
from delegation.service import ServiceConfig  # noqa: E402
from delegation.tst.node import TstNode, parse_tree  # noqa: E402

OPEN_ENDED = ("look-at-position", "look-at-object", "image-object-detection")


def closed_mission(tree: TstNode) -> dict[str, Any]:
    """The tree without its open-ended tasks (and without node-uuids, so it can run again)."""

    def strip(node: TstNode) -> dict[str, Any] | None:
        if node.name in OPEN_ENDED:
            return None
        d = node.to_dict()
        d.get("common_params", {}).pop("node-uuid", None)
        if node.children:
            kids = [k for k in (strip(c) for c in node.children) if k is not None]
            d["children"] = kids
        return d

    out = strip(tree)
    assert out is not None
    return out


def run_once(client: ServiceClient, tst: dict[str, Any], speedup: float,
             timeout: float) -> tuple[float, float, str]:
    """Plan makespan, flown makespan (mission s) and the final status of one mission."""
    answer = client.request({"command": "delegate", "tst": tst, "start": True}, timeout=60)
    if answer.get("response") != "started":
        raise SystemExit(f"not started: {answer.get('fail-reason')}")
    plan = answer["plan"]
    root = plan["tst"]["common_params"]["node-uuid"]
    deadline = time.monotonic() + timeout
    status = ""
    while time.monotonic() < deadline and status not in ("succeeded", "failed", "aborted"):
        try:
            ev = client.events.get(timeout=0.5)
        except queue.Empty:
            continue
        if ev.kind == "mission" and ev.data.get("root-uuid") == root:
            status = str(ev.data.get("status"))
    mission = client.query_mission(root)
    flown = (float(mission["ended"] or 0) - float(mission["started"] or 0)) * speedup
    return float(plan["makespan"]), flown, status or "timeout"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default=str(ROOT / "scenarios" / "demo.yaml"))
    ap.add_argument("--missions", type=int, default=2)
    ap.add_argument("--speedup", type=float, default=5.0)
    ap.add_argument("--start", choices=("defaults", "scaled"), default="defaults")
    ap.add_argument("--factor", type=float, default=0.4, help="with --start scaled")
    ap.add_argument("--timeout", type=float, default=120.0, help="wall seconds per mission")
    args = ap.parse_args()

    scenario = load_scenario(args.scenario)
    tst = closed_mission(scenario.tree())
    if args.start == "defaults":
        profiles = None
    else:
        profiles = {name: {**p, "speeds": {k: v * args.factor for k, v in p["speeds"].items()}}
                    for name, p in scenario.profiles().items() if "speeds" in p}
    config = replace(ServiceConfig(), profiles=profiles)
    rates = {a.name: a.rate for a in scenario.agents if a.rate is not None}
    classes = sorted({c for n in [parse_tree(tst)] for c in _classes(n)})
    print(f"{scenario.name}: {len(scenario.agents)} units, speed classes {', '.join(classes)}; "
          f"service starts with {args.start}"
          + (f" x{args.factor:g}" if args.start == "scaled" else "")
          + f"; speed-up {args.speedup:g}")
    print(f"{'mission':>7} {'plan s':>8} {'flown s':>8} {'error':>7}  status")
    errors = []
    with LocalSystem(scenario.units(), config=config, speedup=args.speedup, rates=rates) as system:
        assert system.settings is not None
        with ServiceClient(system.settings, prefix=system.prefix) as client:
            for i in range(1, args.missions + 1):
                plan, flown, status = run_once(client, tst, args.speedup, args.timeout)
                err = (plan - flown) / flown if flown > 0 else float("inf")
                errors.append(err)
                print(f"{i:>7} {plan:>8.1f} {flown:>8.1f} {100 * err:>+6.1f}%  {status}")
    ok = abs(errors[-1]) <= 0.10
    print(f"last mission's plan within 10 % of flown: {'yes' if ok else 'no'}")
    return 0 if ok else 1


def _classes(node: TstNode) -> list[str]:
    out = [c for c in [speed_class(node)] if c]
    for child in node.children:
        out += _classes(child)
    return out


if __name__ == "__main__":
    sys.exit(main())
