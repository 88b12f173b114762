"""The operator page under load: 200 units at 2 Hz, the page's frame times and event lag, the
server's CPU.

A private mosquitto; N units publish heartbeat, position, heading and battery at R Hz straight
onto the broker from a few publisher threads (no simulator: only the load the page must follow);
``delegation ui`` runs as a subprocess (so its CPU is its own, read from /proc/PID/stat); headless
Chromium (Playwright, /usr/bin/chromium or $CHROMIUM) opens the page. In the page: every
requestAnimationFrame delta (p50/p95/max), long tasks (> 50 ms, PerformanceObserver), and the
event lag of each `units` event (the page's wall clock when the frame that applied it ran, minus
the event's ``at``); and Chromium's own CPU over the window (/proc: the renderers, and all its
processes), which tells page work from a page merely starved by a busy machine: a frame or a long
task is wall time, and on a loaded 2-core machine much of it can be waiting for a core. The
server's CPU is measured once idle (the units not yet publishing) and once over the loaded window,
as % of one core.

    python benchmarks/ui_load.py                      # 200 units, 2 Hz, 30 s loaded window
    python benchmarks/ui_load.py --units 50 --duration 10

Targets (issue 14): frame p95 well under 50 ms; server CPU under 10 % of one core at this load.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
import uuid
from pathlib import Path
from typing import IO, Any

from delegation.runtime.broker import PrivateMosquitto, free_port
from delegation.runtime.core import Identity, heartbeat
from delegation.runtime.mqtt import MqttClient
from delegation.runtime.settings import BrokerSettings

CHROMIUM_ARGS = [
    "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]

# Collects frame deltas and long tasks from page start; `window.__bench.on` gates recording.
PROBE = """
window.__bench = {on: false, frames: [], longtasks: [], last: undefined};
(function loop(t) {
  const b = window.__bench;
  if (b.on && b.last !== undefined) b.frames.push(t - b.last);
  b.last = t;
  requestAnimationFrame(loop);
})(performance.now());
try {
  new PerformanceObserver((list) => {
    if (!window.__bench.on) return;
    for (const e of list.getEntries()) window.__bench.longtasks.push(e.duration);
  }).observe({entryTypes: ["longtask"]});
} catch (e) { window.__bench.noLongtasks = String(e); }
"""

CENTRE = (57.76, 16.68)


class Publishers:
    """``units`` fake units on ``threads`` MQTT clients, each unit flying a circle."""

    def __init__(self, settings: BrokerSettings, units: int, rate: float, threads: int) -> None:
        self.settings = settings
        self.rate = rate
        self.stop_event = threading.Event()
        self.sent = 0
        self.cycles_late = 0
        self._lock = threading.Lock()
        idents = [
            Identity(
                name=f"u{i:03d}",
                agent_type="air" if i % 4 else "surface",
                agent_uuid=str(uuid.uuid4()),
                prefix="waraps",
                rate=rate,
            )
            for i in range(units)
        ]
        self.groups = [idents[k::threads] for k in range(threads)]
        self.threads: list[threading.Thread] = []
        self.clients: list[MqttClient] = []

    def start(self) -> None:
        for k, group in enumerate(self.groups):
            client = MqttClient(self.settings, f"ui-load-{k}-{uuid.uuid4().hex[:6]}")
            client.connect()
            self.clients.append(client)
            t = threading.Thread(target=self._run, args=(client, group), daemon=True)
            t.start()
            self.threads.append(t)

    def stop(self) -> None:
        self.stop_event.set()
        for t in self.threads:
            t.join(5)
        for c in self.clients:
            c.disconnect()

    def _run(self, client: MqttClient, group: list[Identity]) -> None:
        period = 1.0 / self.rate
        t0 = time.monotonic()
        n = 0
        while not self.stop_event.is_set():
            now = time.time()
            for ident in group:
                i = int(ident.name[1:])
                # 100-300 m circles spread over ~4 km, a lap every ~2 min
                cx = CENTRE[0] + 0.018 * ((i % 15) / 14 - 0.5)
                cy = CENTRE[1] + 0.034 * ((i // 15) / 14 - 0.5)
                r = 100 + 15 * (i % 13)
                a = now * 0.05 + i
                lat = cx + r / 111_000 * math.sin(a)
                lon = cy + r / (111_000 * math.cos(math.radians(cx))) * math.cos(a)
                heading = (math.degrees(-a) + 360) % 360
                hb = heartbeat(ident, ["sensor", "direct execution"], now)
                client.publish(hb.topic, hb.payload)
                pos = {"latitude": lat, "longitude": lon, "altitude": 40.0, "rostype": "GeoPoint"}
                client.publish(ident.topic("sensor/position"), json.dumps(pos))
                client.publish(ident.topic("sensor/heading"), json.dumps({"value": heading}))
                battery = max(0.0, 1.0 - (i % 50) / 60 - (now % 600) / 6000)
                client.publish(
                    ident.topic("sensor/battery_state"),
                    json.dumps({"percentage": round(battery, 3), "charging": False}),
                )
            with self._lock:
                self.sent += 4 * len(group)
            n += 1
            wait = t0 + n * period - time.monotonic()
            if wait < 0:
                self.cycles_late += 1
            self.stop_event.wait(max(wait, 0.0))


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process (and its waited-for children), seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = sum(int(x) for x in fields[11:15])  # utime stime cutime cstime
    return ticks / os.sysconf("SC_CLK_TCK")


def descendants(root: int) -> list[int]:
    """Every process below ``root`` (Playwright's driver, Chromium's browser, GPU, renderers)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [root]
    while todo:
        for kid in children.get(todo.pop(), []):
            out.append(kid)
            todo.append(kid)
    return out


def chromium_cpu() -> dict[str, float]:
    """CPU seconds so far of this script's Chromium processes: all of them, and the renderers."""
    total = renderer = 0.0
    for pid in descendants(os.getpid()):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
            if b"chrom" not in cmdline.split(b"\0")[0]:
                continue
            secs = cpu_seconds(pid)
        except OSError:
            continue  # gone meanwhile
        total += secs
        if b"--type=renderer" in cmdline:
            renderer += secs
    return {"all": total, "renderer": renderer}


def wait_http(url: str, proc: subprocess.Popen[bytes], errors: IO[bytes],
              deadline: float) -> dict[str, Any]:
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            errors.seek(0)
            tail = errors.read().decode(errors="replace")[-2000:]
            raise SystemExit(f"delegation ui exited with {proc.returncode}:\n{tail}")
        try:
            with urllib.request.urlopen(url + "/api/config", timeout=2) as r:
                return dict(json.load(r))
        except (urllib.error.URLError, ConnectionError):
            time.sleep(0.2)
    raise SystemExit(f"delegation ui did not answer on {url} in time")


def pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, max(0, math.ceil(q / 100 * len(s)) - 1))]


def three(values: list[float], digits: int = 0) -> str:
    """p50 / p95 / max."""
    if not values:
        return "-"
    return " / ".join(f"{v:.{digits}f}" for v in (pct(values, 50), pct(values, 95), max(values)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--units", type=int, default=200)
    ap.add_argument("--rate", type=float, default=2.0, help="messages per unit per second (Hz)")
    ap.add_argument("--duration", type=float, default=30.0, help="loaded window measured (s)")
    ap.add_argument("--warmup", type=float, default=5.0, help="load before measuring (s)")
    ap.add_argument("--idle", type=float, default=5.0, help="idle window measured first (s)")
    ap.add_argument("--threads", type=int, default=4, help="publisher threads")
    ap.add_argument("--chromium", default=os.environ.get("CHROMIUM", "/usr/bin/chromium"))
    ap.add_argument("--screenshot", metavar="PNG", help="save the page at the end of the run")
    args = ap.parse_args()

    from playwright.sync_api import sync_playwright

    broker = PrivateMosquitto().start()
    http_port = free_port()
    url = f"http://127.0.0.1:{http_port}"
    cmd = [
        sys.executable, "-m", "delegation", "-q", "ui",
        "--broker", "127.0.0.1", "--port", str(broker.port),
        "--http", f"127.0.0.1:{http_port}",
    ]
    errors = tempfile.TemporaryFile()  # noqa: SIM115 (closed in the finally below)
    server = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=errors)
    pubs = Publishers(broker.settings(), args.units, args.rate, args.threads)
    try:
        wait_http(url, server, errors, time.monotonic() + 30)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(
                executable_path=args.chromium, headless=True, args=CHROMIUM_ARGS
            )
            page = browser.new_page(viewport={"width": 1400, "height": 860})
            page.add_init_script(PROBE)
            page.goto(url + "/")
            page.wait_for_selector("body[data-ready]", timeout=30_000)

            c0, t0 = cpu_seconds(server.pid), time.monotonic()
            time.sleep(args.idle)
            idle_cpu = (cpu_seconds(server.pid) - c0) / (time.monotonic() - t0) * 100

            pubs.start()
            page.wait_for_function(
                f"document.getElementById('map').dataset.unitsDrawn >= {args.units}",
                timeout=60_000,
            )
            time.sleep(args.warmup)
            page.evaluate(
                "() => { const b = window.__bench; b.frames = []; b.longtasks = []; b.on = true;"
                " const s = window.delegationUI.stats; s.lags.length = 0; s.flushMs.length = 0;"
                " s.trackMs.length = 0; s.canvasMs.length = 0;"
                " b.events0 = s.unitEvents; b.applied0 = s.unitsApplied; }"
            )
            sent0 = pubs.sent
            b0 = chromium_cpu()
            c0, t0 = cpu_seconds(server.pid), time.monotonic()
            load0 = Path("/proc/loadavg").read_text().split()[:3]
            time.sleep(args.duration)
            c1, t1 = cpu_seconds(server.pid), time.monotonic()
            b1 = chromium_cpu()
            load1 = Path("/proc/loadavg").read_text().split()[:3]
            sent = pubs.sent - sent0
            res = page.evaluate(
                "() => { const b = window.__bench; b.on = false;"
                " const s = window.delegationUI.stats;"
                " return {frames: b.frames, longtasks: b.longtasks, lags: s.lags.slice(),"
                " flush: s.flushMs.slice(), tracks: s.trackMs.slice(),"
                " canvas: s.canvasMs.slice(),"
                " events: s.unitEvents - b.events0, applied: s.unitsApplied - b.applied0,"
                " drawn: Number(document.getElementById('map').dataset.unitsDrawn),"
                " noLongtasks: b.noLongtasks || null}; }"
            )
            if args.screenshot:
                page.screenshot(path=args.screenshot)
            browser.close()
    finally:
        pubs.stop()
        server.terminate()
        try:
            server.wait(10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
        errors.close()
        broker.stop()

    wall = t1 - t0
    load_cpu = (c1 - c0) / wall * 100
    frames: list[float] = res["frames"]
    lags = [x * 1000 for x in res["lags"]]
    longtasks: list[float] = res["longtasks"]
    print(f"operator page under load: {args.units} units x {args.rate:g} Hz "
          f"(heartbeat, position, heading, battery), {wall:.1f} s measured")
    rows = [
        ("messages published / s", f"{sent / wall:.0f}"),
        ("units on the map", f"{res['drawn']}"),
        ("`units` events / s (page)", f"{res['events'] / wall:.2f}"),
        ("unit updates applied / s (page)", f"{res['applied'] / wall:.0f}"),
        ("frames", f"{len(frames)} ({len(frames) / wall:.1f} / s)"),
        ("frame time p50 / p95 / max (ms)",
         three(frames, 1)),
        ("long tasks (> 50 ms): count, total ms",
         f"{len(longtasks)}, {sum(longtasks):.0f}" if res["noLongtasks"] is None
         else f"n/a ({res['noLongtasks']})"),
        ("page's DOM work per frame p50 / p95 / max (ms)", three(res["flush"], 1)),
        ("units canvas redraws p50 / p95 / max (ms)", three(res["canvas"], 1)),
        ("track canvas redraws p50 / p95 / max (ms)", three(res["tracks"], 1)),
        ("event lag p50 / p95 / max (ms)",
         three(lags)),
        ("Chromium CPU: renderers / all (% of one core)",
         f"{(b1['renderer'] - b0['renderer']) / wall * 100:.1f} / "
         f"{(b1['all'] - b0['all']) / wall * 100:.1f}"),
        ("server CPU idle (% of one core)", f"{idle_cpu:.1f}"),
        ("server CPU loaded (% of one core)", f"{load_cpu:.1f}"),
        ("server CPU added by the load", f"{load_cpu - idle_cpu:.1f}"),
        ("publisher cycles late", f"{pubs.cycles_late}"),
        ("loadavg at start / end", f"{' '.join(load0)} / {' '.join(load1)}"),
        ("cores", f"{os.cpu_count()}"),
    ]
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"  {k:<{width}}  {v}")
    if frames:
        print(f"  (frame time mean {statistics.fmean(frames):.1f} ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
