"""The operator page's HTTP face (Starlette): static files, the JSON API, server-sent events.

The contract is docs/ui.md. Blocking work (commands to the service) runs in the thread pool;
the event stream is one asyncio task per page that wakes when the bridge says something changed,
and sends unit moves at most every 500 ms (coalesced: only the units that changed).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import (
    FileResponse,
    JSONResponse,
    RedirectResponse,
    Response,
    StreamingResponse,
)
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from delegation.errors import DelegationError, InputError
from delegation.topics import MAX_PAYLOAD
from delegation.web.auth import COOKIE, Users, bearer, cross_site_refusal, user_of
from delegation.web.bridge import OBJECTIVES, STRATEGIES, ApiError, Bridge
from delegation.web.mission_input import mission_tree
from delegation.web.view import item_mission

log = logging.getLogger(__name__)

STATIC = Path(__file__).parent / "static"
#: Seconds between unit batches on a stream (the coalescing window).
UNITS_EVERY = 0.5
#: Seconds between keep-alive comments.
KEEPALIVE = 15.0
#: Bytes of a request body read: what fits in one command to the service (larger: 413, unread).
MAX_BODY = MAX_PAYLOAD

Handler = Callable[[Request, str], Awaitable[Response]]


def _error(status: int, reason: str) -> JSONResponse:
    return JSONResponse({"fail-reason": reason}, status_code=status)


def _sse(event: str, data: Any) -> str:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n"


async def _capped(request: Request) -> bytes:
    """The body, read only up to `MAX_BODY` bytes (413 beyond, whatever Content-Length says)."""
    too_long = ApiError(413, f"the body is larger than {MAX_BODY} bytes")
    length = request.headers.get("content-length", "")
    if length.isdigit() and int(length) > MAX_BODY:
        raise too_long
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_BODY:
            raise too_long
    return bytes(body)


async def _seen(sight: Sight, items: list[tuple[int, str, dict[str, Any]]]) -> list[str]:
    """The stream items ``sight`` allows, as SSE (a unit's events are everyone's)."""
    about = [(kind, data, item_mission(kind, data)) for _, kind, data in items]
    await sight.learn({root for _, _, root in about if root is not None})
    return [_sse(kind, data) for kind, data, root in about if root is None or sight.sees(root)]


class Sight:
    """The missions one user sees on the page: those `list-missions` answers them (the service
    decides: their own, or every one for an operator), asked again when a mission it was not
    told of appears. Unknown until asked: nothing is shown that the service did not list."""

    def __init__(self, bridge: Bridge, user: str, *, everything: bool = False) -> None:
        self.bridge, self.user, self.everything = bridge, user, everything
        self.ids: set[str] = set()
        self._asked: set[str] = set()

    async def refresh(self) -> None:
        if self.everything:
            return
        try:
            self.ids = await run_in_threadpool(self.bridge.missions_of, self.user)
        except ApiError as exc:  # no service: what was listed before stands
            log.info("ui: missions of %s not listed: %s", self.user, exc.reason)

    async def learn(self, roots: set[str]) -> None:
        """Ask again if one of ``roots`` is new to this user's sight."""
        new = roots - self.ids - self._asked
        if new and not self.everything:
            self._asked |= new
            await self.refresh()

    def sees(self, root: str) -> bool:
        return self.everything or root in self.ids


class Page:
    """The routes, bound to one bridge and its settings."""

    def __init__(
        self,
        bridge: Bridge,
        *,
        users: Mapping[str, str] | None = None,
        tile_url: str | None = None,
        tile_attribution: str = "",
        strategies: tuple[str, ...] = STRATEGIES,
        static: Path = STATIC,
        loopback_only: bool = True,
    ) -> None:
        """``loopback_only``: the server listens on loopback, so requests must name it
        (`auth.cross_site_refusal`)."""
        self.bridge = bridge
        self.loopback_only = loopback_only
        self.users: Mapping[str, str] | None = (
            users if isinstance(users, Users) else dict(users) if users else None)
        self.tile_url = tile_url
        self.tile_attribution = tile_attribution
        self.strategies = strategies
        self.static = static
        #: Set by the server when it stops: streams end within their 500 ms tick.
        self.stopping = threading.Event()
        #: Users with a plan preview in flight (one each; event-loop thread only).
        self._previewing: set[str] = set()

    # ---- auth

    def user(self, request: Request) -> str | None:
        """The caller's name (the sender of its commands); None when not authenticated."""
        if self.users is None:
            return self.bridge.sender
        if isinstance(self.users, Users):  # edited on disk: tokens added or revoked
            self.users = self.users.current()
        token = bearer(request.headers.get("authorization")) or request.cookies.get(COOKIE)
        return user_of(self.users, token)

    def api(self, handler: Handler) -> Callable[[Request], Awaitable[Response]]:
        """An /api endpoint: 401 without a known token; ApiError/InputError as JSON."""

        async def endpoint(request: Request) -> Response:
            refused = cross_site_refusal(request.method, request.headers.get("host"),
                                         request.headers.get("origin"), self.loopback_only)
            if refused:
                return _error(403, refused)
            user = self.user(request)
            if user is None:
                return _error(401, "a valid token is needed (Authorization: Bearer TOKEN, or "
                                   "open the page once as /?token=TOKEN)")
            try:
                return await handler(request, user)
            except ApiError as exc:
                return _error(exc.status, exc.reason)
            except InputError as exc:
                return _error(400, exc.fail_reason)
            except DelegationError as exc:  # the broker connection is down
                log.warning("ui: %s %s: %s", request.method, request.url.path, exc)
                return _error(503, str(exc))

        return endpoint

    # ---- pages

    async def index(self, request: Request) -> Response:
        token = request.query_params.get("token")
        if token is not None and self.users is not None:
            if user_of(self.users, token) is None:
                return _error(401, "unknown token")
            response = RedirectResponse("/", status_code=303)
            response.set_cookie(COOKIE, token, httponly=True, samesite="strict",
                                secure=request.url.scheme == "https")
            return response
        index = self.static / "index.html"
        if not index.is_file():
            return Response("the page is not installed (web/static/index.html)",
                            status_code=404, media_type="text/plain")
        return FileResponse(index, headers={"Cache-Control": "no-cache"})

    # ---- reads

    async def config(self, request: Request, user: str) -> Response:
        return JSONResponse({"user": user, "tile-url": self.tile_url,
                             "tile-attribution": self.tile_attribution,
                             "strategies": list(self.strategies),
                             "objectives": list(OBJECTIVES),
                             "time-scale": self.bridge.view.scale})

    def _sight(self, user: str) -> Sight:
        return Sight(self.bridge, user, everything=self.users is None)

    async def state(self, request: Request, user: str) -> Response:
        sight = self._sight(user)
        await sight.refresh()
        return JSONResponse(self.bridge.state(sight.sees))

    async def mission(self, request: Request, user: str) -> Response:
        root = request.path_params["id"]
        return JSONResponse(await run_in_threadpool(self.bridge.mission, root, user))

    async def events(self, request: Request, user: str) -> Response:
        return StreamingResponse(self._stream(self._sight(user)), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache",
                                          "X-Accel-Buffering": "no"})

    async def _stream(self, sight: Sight) -> AsyncIterator[str]:
        bridge, view = self.bridge, self.bridge.view
        loop = asyncio.get_running_loop()
        wake = asyncio.Event()
        key = bridge.add_waker(loop, wake)
        try:
            await sight.refresh()
            with bridge.lock:
                state = view.state(bridge.clock(), sight.sees)
            cursor = units_cursor = int(state["seq"])
            yield _sse("snapshot", state)
            last_units = last_sent = loop.time()
            while not bridge.stopping and not self.stopping.is_set():
                timeout = max(0.05, UNITS_EVERY - (loop.time() - last_units))
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(wake.wait(), timeout)
                wake.clear()
                due = loop.time() - last_units >= UNITS_EVERY
                with bridge.lock:
                    items = view.items_since(cursor)
                    seq = view.seq
                    units = view.units_since(units_cursor) if due else []
                    snapshot = view.state(bridge.clock(), sight.sees) if items is None else None
                out: list[str] = []
                if snapshot is not None:  # fell behind: start again from a snapshot
                    out.append(_sse("snapshot", snapshot))
                    units_cursor = seq
                else:
                    out.extend(await _seen(sight, items or []))
                if due:
                    last_units = loop.time()
                    if units and snapshot is None:
                        out.append(_sse("units", {"seq": seq, "at": round(bridge.clock(), 3),
                                                  "units": units}))
                    units_cursor = seq
                cursor = seq
                if not out and loop.time() - last_sent >= KEEPALIVE:
                    out.append(": keep-alive\n\n")
                if out:
                    last_sent = loop.time()
                    yield "".join(out)
        finally:
            bridge.remove_waker(key)

    # ---- commands

    async def _body(self, request: Request) -> dict[str, Any]:
        # JSON only: another site's form or text/plain POST (no preflight) is not read.
        kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if kind != "application/json":
            raise ApiError(415, "the body must be JSON (Content-Type: application/json)")
        try:
            body = json.loads(await _capped(request))
        except (ValueError, RecursionError):
            raise ApiError(400, "the body must be a JSON object") from None
        if not isinstance(body, dict):
            raise ApiError(400, "the body must be a JSON object")
        return body

    def _options(self, body: Mapping[str, Any]) -> tuple[str | None, float | None]:
        objective = body.get("objective")
        if objective is not None and objective not in OBJECTIVES:
            raise ApiError(400, f"objective: must be one of {', '.join(OBJECTIVES)}")
        limit = body.get("time-limit")
        if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int | float)
                                  or not 0 < limit <= 600):
            raise ApiError(400, "time-limit: must be a number of seconds > 0")
        return objective, None if limit is None else float(limit)

    def _strategy(self, value: Any) -> str:
        if not isinstance(value, str) or value not in self.strategies:
            raise ApiError(400, f"strategy: must be one of {', '.join(self.strategies)}, "
                                f"not {value!r}")
        return value

    async def plan(self, request: Request, user: str) -> Response:
        """Previews: each strategy once, one request in flight per user (429 beyond): one
        request must not hold the page's threads and the service's planner for hours."""
        body = await self._body(request)
        tree = mission_tree(body.get("mission"))
        strategies = body.get("strategies") or list(self.strategies)
        if not isinstance(strategies, list):
            raise ApiError(400, "strategies: must be a list")
        chosen = list(dict.fromkeys(self._strategy(s) for s in strategies))
        objective, limit = self._options(body)
        if user in self._previewing:
            raise ApiError(429, "a plan preview of yours is in flight: wait for its answer")
        self._previewing.add(user)
        try:
            plans = await run_in_threadpool(self.bridge.plan, tree, chosen, objective, limit,
                                            user)
        finally:
            self._previewing.discard(user)
        return JSONResponse({"plans": plans})

    async def start(self, request: Request, user: str) -> Response:
        body = await self._body(request)
        tree = mission_tree(body.get("mission"))
        strategy = self._strategy(body["strategy"]) if body.get("strategy") else None
        objective, limit = self._options(body)
        preview = body.get("preview")
        if preview is not None and (not isinstance(preview, str) or not 0 < len(preview) <= 128):
            raise ApiError(400, "preview: must be the preview-id of a previewed plan")
        return JSONResponse(await run_in_threadpool(self.bridge.start_mission, tree, strategy,
                                                    objective, limit, user, preview))

    async def signal(self, request: Request, user: str) -> Response:
        body = await self._body(request)
        root = request.path_params["id"]
        answer = await run_in_threadpool(self.bridge.signal, root, str(body.get("signal")), user)
        return JSONResponse({"response": answer})

    async def cancel(self, request: Request, user: str) -> Response:
        root = request.path_params["id"]
        return JSONResponse({"response": await run_in_threadpool(self.bridge.cancel, root, user)})

    # ---- the app

    def routes(self) -> list[Route | Mount]:
        return [
            Route("/", self.index),
            Route("/api/config", self.api(self.config)),
            Route("/api/state", self.api(self.state)),
            Route("/api/events", self.api(self.events)),
            Route("/api/plan", self.api(self.plan), methods=["POST"]),
            Route("/api/missions", self.api(self.start), methods=["POST"]),
            Route("/api/missions/{id}", self.api(self.mission)),
            Route("/api/missions/{id}/signal", self.api(self.signal), methods=["POST"]),
            Route("/api/missions/{id}/cancel", self.api(self.cancel), methods=["POST"]),
            Mount("/static", StaticFiles(directory=self.static, check_dir=False), name="static"),
        ]


def create_app(bridge: Bridge, **options: Any) -> Starlette:
    """The Starlette app for a started bridge (options: `Page`'s keywords)."""
    page = Page(bridge, **options)
    app = Starlette(routes=page.routes())
    app.state.page = page
    return app
