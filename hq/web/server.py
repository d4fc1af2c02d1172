"""The console's web server: Starlette on uvicorn, in rescue-hq's process.

Threads (besides the HQ's own): ``hq-web`` runs uvicorn's event loop (HTTP,
server-sent events); ``hq-web-db`` owns the console's own registry connection
and notes, runs every database job the pages ask for (actions, notes, exports)
one after the other, and watches for changes: every 0.1 s it compares SQLite's
``data_version`` (which moves when the HQ's main thread commits a report, a
status or an acknowledgement), LiveRobots' version (positions) and the set of
robots whose link is lost; on a change it builds the whole page state
(hq.web.state.snapshot) at most every 0.2 s (every 1 s when only robots moved)
and hands it to the event loop, which pushes it to every open page.

Operator actions take the HQ's existing path: they are written to the registry's
``actions`` table exactly as ``rescue-hq mark`` writes them, and the HQ's main
thread (which notices within 0.25 s) sends them to the robots and resends until
acknowledged.

Access (hq.web.access): on a loopback address with no token configured, open; a
configured token is required everywhere (cookie from the sign-in form, or
``Authorization: Bearer``), otherwise 401.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import csv
import html
import io
import json
import logging
import queue
import socket
import sqlite3
import threading
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager, suppress
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import resources
from pathlib import Path
from typing import Any, Protocol, TypeVar

import uvicorn
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import (
    FileResponse,
    HTMLResponse,
    JSONResponse,
    PlainTextResponse,
    RedirectResponse,
    Response,
    StreamingResponse,
)
from starlette.routing import Route

from hq import export
from hq.registry import OperatorAction, Registry, RegistryError
from hq.view import HqVictim, hq_victims
from hq.web import access, assets
from hq.web.notes import BadNote, Notes
from hq.web.state import LiveRobots, robots_lost, snapshot

log = logging.getLogger(__name__)

_TICK_S = 0.1  # how often the console looks for news in the registry
_MIN_PUBLISH_S = 0.2  # pages get at most 5 states a second
_MOVED_PUBLISH_S = 1.0  # and robots' movements alone at most once a second
_KEEPALIVE_S = 15.0  # an SSE comment line keeps proxies and the browser's timer happy
_MAX_BODY_BYTES = 4096
_ACTIONS = {
    "confirmed": OperatorAction.CONFIRMED,
    "rescued": OperatorAction.RESCUED,
    "false_alarm": OperatorAction.FALSE_ALARM,
}
T = TypeVar("T")
_Job = tuple[Callable[["Registry", "Notes"], Any], "concurrent.futures.Future[Any]"]


class ConsoleError(Exception):
    """The console cannot start (the address is taken or not ours); one line."""


@dataclass(frozen=True)
class ConsoleOptions:
    host: str = "127.0.0.1"
    port: int = 8080
    token: str | None = None
    link_timeout_s: float = 5.0
    asset_dir: Path | None = None


class Pictures(Protocol):
    """Evidence pictures by HQ victim ID (JPEG bytes). The robots do not send any yet."""

    def ids(self) -> frozenset[int]: ...

    def jpeg(self, hq_id: int) -> bytes | None: ...


class NoPictures:
    def ids(self) -> frozenset[int]:
        return frozenset()

    def jpeg(self, hq_id: int) -> bytes | None:
        return None


class _Hub:
    """The latest page state, in the event loop; SSE streams wait on it."""

    def __init__(self) -> None:
        self.version = 0
        self.data = ""
        self.closing = False
        self._changed = asyncio.Event()

    def publish(self, data: str) -> None:
        self.version += 1
        self.data = data
        self._changed.set()
        self._changed = asyncio.Event()

    def close(self) -> None:
        self.closing = True
        self._changed.set()

    async def wait(self, seen: int, timeout_s: float) -> None:
        if self.version != seen or self.closing:
            return
        with suppress(TimeoutError):
            await asyncio.wait_for(self._changed.wait(), timeout_s)


class _Database(threading.Thread):
    """The console's database thread: jobs in order, and the watch for news."""

    def __init__(
        self,
        db_path: Path,
        live: LiveRobots,
        pictures: Pictures,
        link_timeout_s: float,
        publish: Callable[[str], None],
    ) -> None:
        super().__init__(name="hq-web-db", daemon=True)
        self.db_path = db_path
        self.live = live
        self.pictures = pictures
        self.link_timeout_s = link_timeout_s
        self._publish = publish
        self._jobs: queue.Queue[_Job] = queue.Queue()
        self._halt = threading.Event()
        self.opened = threading.Event()
        self.open_error: str | None = None
        self._dirty = True

    def submit(self, job: Callable[[Registry, Notes], T]) -> concurrent.futures.Future[T]:
        future: concurrent.futures.Future[T] = concurrent.futures.Future()
        self._jobs.put((job, future))
        return future

    def stop(self) -> None:
        self._halt.set()

    def run(self) -> None:
        try:
            registry = Registry(self.db_path)
            notes = Notes(self.db_path)
        except (RegistryError, sqlite3.Error) as exc:
            self.open_error = str(exc)
            self.opened.set()
            return
        self.opened.set()
        try:
            self._loop(registry, notes)
        finally:
            notes.close()
            registry.close()

    def _loop(self, registry: Registry, notes: Notes) -> None:
        db_version = live_version = -1
        lost: frozenset[int] = frozenset()
        robots = registry.robots()
        next_tick = last_publish = 0.0
        while not self._halt.is_set():
            try:
                job, future = self._jobs.get(timeout=max(0.0, next_tick - time.monotonic()))
            except queue.Empty:
                pass
            else:
                if future.set_running_or_notify_cancel():
                    try:
                        future.set_result(job(registry, notes))
                    except BaseException as exc:  # handed to the request that asked
                        future.set_exception(exc)
                self._dirty = True
                continue
            now = time.monotonic()
            next_tick = now + _TICK_S
            try:
                version = registry.data_version()
                if version != db_version:
                    db_version, self._dirty = version, True
                    robots = registry.robots()
                moved = self.live.version != live_version
                now_lost = robots_lost(robots, self.live, time.time(), self.link_timeout_s)
                if now_lost != lost:
                    lost, self._dirty = now_lost, True
                since = now - last_publish
                if (self._dirty and since >= _MIN_PUBLISH_S) or (
                    moved and since >= _MOVED_PUBLISH_S
                ):
                    self._dirty = False
                    live_version = self.live.version
                    last_publish = now
                    self._publish(self.state_json(registry, notes))
            except (RegistryError, sqlite3.Error) as exc:  # busy or locked: the next tick
                log.debug("console: cannot read the registry: %s", exc)
            except Exception:  # a bug: say so, keep the pages served with the last state
                log.exception("console: cannot build the page state")
                next_tick = time.monotonic() + 1.0

    def state_json(self, registry: Registry, notes: Notes) -> str:
        state = snapshot(
            hq_victims(registry),
            registry.robots(),
            registry.actions(),
            notes.all(),
            self.live.tracks(),
            self.pictures.ids(),
            time.time(),
            self.link_timeout_s,
        )
        return json.dumps(state, separators=(",", ":"))


def _static(name: str) -> str:
    return resources.files("hq.web").joinpath("static", name).read_text(encoding="utf-8")


def _find(registry: Registry, hq_id: int) -> HqVictim:
    for v in hq_victims(registry):
        if v.hq_id == hq_id:
            return v
    raise LookupError(f"no HQ victim {hq_id}")


def _act(hq_id: int, action: OperatorAction) -> Callable[[Registry, Notes], list[int]]:
    def job(registry: Registry, _notes: Notes) -> list[int]:
        victim = _find(registry, hq_id)
        return [registry.add_action(r, v, action) for r, v in victim.sources]

    return job


def _note(hq_id: int, text: str) -> Callable[[Registry, Notes], int]:
    def job(registry: Registry, notes: Notes) -> int:
        _find(registry, hq_id)
        return notes.add(hq_id, text).note_id

    return job


def _iso_utc(unix_s: float) -> str:
    return datetime.fromtimestamp(unix_s, UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


def csv_bytes(victims: list[HqVictim]) -> bytes:
    """Every HQ victim, one row each, local and global positions (spreadsheets, paper)."""
    out = io.StringIO()
    w = csv.writer(out)
    w.writerow(
        [
            "id", "urgency", "state", "visibility_pct", "robots", "north_m", "east_m",
            "sigma_m", "lat_deg", "lon_deg", "alt_m", "first_seen", "last_seen", "sightings",
        ]
    )  # fmt: skip
    for v in victims:
        w.writerow(
            [
                v.hq_id,
                v.urgency.name,
                v.state.name,
                f"{v.visibility_pct:.1f}",
                " ".join(str(r) for r in v.robots),
                f"{v.north_m:.2f}",
                f"{v.east_m:.2f}",
                f"{v.sigma_m:.2f}",
                "" if v.lat_deg is None else f"{v.lat_deg:.7f}",
                "" if v.lon_deg is None else f"{v.lon_deg:.7f}",
                "" if v.alt_m is None else f"{v.alt_m:.2f}",
                _iso_utc(v.first_seen_unix_s),
                _iso_utc(v.last_seen_unix_s),
                v.observations,
            ]
        )
    return out.getvalue().encode()


_EXPORTS: dict[str, tuple[str, Callable[[list[HqVictim], Any], bytes]]] = {
    export.GEOJSON_NAME: (
        "application/geo+json",
        lambda vs, _o: json.dumps(export.geojson(vs), indent=1).encode(),
    ),
    export.KML_NAME: ("application/vnd.google-earth.kml+xml", lambda vs, _o: export.kml(vs)),
    export.PLAN_NAME: (
        "application/json",
        lambda vs, o: json.dumps(export.plan(vs, o), indent=4).encode(),
    ),
    "victims.csv": ("text/csv", lambda vs, _o: csv_bytes(vs)),
}


def _export(name: str) -> Callable[[Registry, Notes], bytes]:
    def job(registry: Registry, _notes: Notes) -> bytes:
        return _EXPORTS[name][1](hq_victims(registry), registry.default_origin())

    return job


class Console:
    """The running console: start() binds and serves, stop() ends both threads."""

    def __init__(
        self,
        db_path: Path,
        options: ConsoleOptions,
        live: LiveRobots,
        pictures: Pictures | None = None,
    ) -> None:
        access.check_binding(options.host, options.token)
        self.options = options
        self.live = live
        self.pictures = pictures or NoPictures()
        self.asset_dir = options.asset_dir or assets.default_asset_dir()
        self.asset_problems = assets.verify(self.asset_dir)
        self._hub: _Hub | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ready = threading.Event()
        self._db = _Database(db_path, live, self.pictures, options.link_timeout_s, self._publish)
        self._server: uvicorn.Server | None = None
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self.url = ""

    # -- lifecycle -------------------------------------------------------------

    def start(self) -> str:
        """Bind, serve, and return the console's URL. ConsoleError if it cannot."""
        self._sock = _bind(self.options.host, self.options.port)
        host, port = self._sock.getsockname()[:2]
        shown = f"[{host}]" if ":" in host else host
        self.url = f"http://{shown}:{port}/"
        self._db.start()
        self._db.opened.wait(10.0)
        if self._db.open_error is not None:
            self._sock.close()
            raise ConsoleError(f"console: {self._db.open_error}")
        config = uvicorn.Config(
            self._app(),
            log_level="warning",
            access_log=False,
            log_config=None,
            lifespan="on",
            http="h11",
            ws="none",
            loop="asyncio",
            timeout_graceful_shutdown=2,
        )
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(
            target=self._server.run, kwargs={"sockets": [self._sock]}, name="hq-web", daemon=True
        )
        self._thread.start()
        if not self._ready.wait(10.0):
            self.stop()
            raise ConsoleError("console: the web server did not start within 10 s")
        return self.url

    def stop(self) -> None:
        self._db.stop()
        if self._loop is not None and self._hub is not None:
            self._loop.call_soon_threadsafe(self._hub.close)
        if self._server is not None:
            self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self._db.is_alive():
            self._db.join(timeout=2.0)
        if self._sock is not None:
            self._sock.close()

    def _publish(self, data: str) -> None:
        loop, hub = self._loop, self._hub
        if loop is not None and hub is not None:
            loop.call_soon_threadsafe(hub.publish, data)

    # -- the web app -----------------------------------------------------------

    def _app(self) -> Any:
        @asynccontextmanager
        async def lifespan(_app: Starlette) -> AsyncIterator[None]:
            self._loop = asyncio.get_running_loop()
            self._hub = _Hub()
            self._ready.set()
            yield

        routes = [
            Route("/", self._page),
            Route("/login", self._login, methods=["POST"]),
            Route("/static/{name}", self._static_file),
            Route("/vendor/{name}", self._vendor),
            Route("/api/state", self._state),
            Route("/api/events", self._events),
            Route("/api/victims/{hq_id:int}/action", self._action, methods=["POST"]),
            Route("/api/victims/{hq_id:int}/note", self._add_note, methods=["POST"]),
            Route("/victims/{hq_id:int}/picture", self._picture),
            Route("/export/{name}", self._export_file),
        ]
        app = Starlette(routes=routes, lifespan=lifespan)
        return access.Access(app, self.options.token, _static("login.html"))

    async def _run(self, job: Callable[[Registry, Notes], T]) -> T:
        return await asyncio.wrap_future(self._db.submit(job))

    async def _page(self, _request: Request) -> Response:
        page = _static("console.html").replace(
            "{{ASSETS_MISSING}}", html.escape("; ".join(self.asset_problems))
        )
        return HTMLResponse(page, headers={"Cache-Control": "no-cache"})

    async def _login(self, request: Request) -> Response:
        # Access lets this through only with the right token (it checked the form).
        response = RedirectResponse("/", status_code=303)
        if self.options.token is not None:
            response.set_cookie(
                access.COOKIE, self.options.token, httponly=True, samesite="strict", path="/"
            )
        return response

    async def _static_file(self, request: Request) -> Response:
        types = {"console.js": "text/javascript", "console.css": "text/css"}
        name = request.path_params["name"]
        if name not in types:
            return PlainTextResponse("not found", status_code=404)
        return Response(
            _static(name), media_type=types[name], headers={"Cache-Control": "no-cache"}
        )

    async def _vendor(self, request: Request) -> Response:
        spec = assets.ASSETS.get(request.path_params["name"])
        path = None if spec is None else self.asset_dir / spec.name
        if spec is None or path is None or not path.is_file():
            return PlainTextResponse(f"not found: {assets.FETCH_HINT}", status_code=404)
        return FileResponse(path, media_type=spec.media_type)

    async def _state(self, _request: Request) -> Response:
        data = await self._run(self._db.state_json)
        return Response(data, media_type="application/json", headers={"Cache-Control": "no-cache"})

    async def _events(self, _request: Request) -> Response:
        hub = self._hub
        assert hub is not None

        async def stream() -> AsyncIterator[str]:
            seen = -1
            yield "retry: 1000\n\n"
            while not hub.closing:
                if hub.version != seen and hub.data:
                    seen = hub.version
                    yield f"event: state\ndata: {hub.data}\n\n"
                    continue
                before = hub.version
                await hub.wait(seen if hub.data else before, _KEEPALIVE_S)
                if hub.version == before and not hub.closing:
                    yield ": keepalive\n\n"

        return StreamingResponse(
            stream(),
            media_type="text/event-stream",
            headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
        )

    async def _body(self, request: Request) -> dict[str, Any]:
        body = await request.body()
        if len(body) > _MAX_BODY_BYTES:
            raise ValueError(f"request body over {_MAX_BODY_BYTES} bytes")
        try:
            data = json.loads(body or b"{}")
        except ValueError:
            raise ValueError("request body is not JSON") from None
        if not isinstance(data, dict):
            raise ValueError("request body must be a JSON object")
        return data

    async def _action(self, request: Request) -> Response:
        hq_id = int(request.path_params["hq_id"])
        try:
            name = (await self._body(request)).get("action")
            if name not in _ACTIONS:
                raise ValueError(f"action must be one of {', '.join(_ACTIONS)}, not {name!r}")
            seqs = await self._run(_act(hq_id, _ACTIONS[name]))
        except ValueError as exc:
            return JSONResponse({"error": str(exc)}, status_code=400)
        except (LookupError, KeyError) as exc:
            return JSONResponse({"error": str(exc.args[0])}, status_code=404)
        except RegistryError as exc:
            return JSONResponse({"error": f"not recorded, try again: {exc}"}, status_code=503)
        log.info("console: %s on HQ victim %d -> actions %s", name, hq_id, seqs)
        return JSONResponse({"action_seqs": seqs})

    async def _add_note(self, request: Request) -> Response:
        hq_id = int(request.path_params["hq_id"])
        try:
            text = (await self._body(request)).get("text")
            if not isinstance(text, str):
                raise BadNote("a note needs some text")
            note_id = await self._run(_note(hq_id, text))
        except ValueError as exc:  # BadNote is one
            return JSONResponse({"error": str(exc)}, status_code=400)
        except LookupError as exc:
            return JSONResponse({"error": str(exc.args[0])}, status_code=404)
        except sqlite3.Error as exc:
            return JSONResponse({"error": f"not recorded, try again: {exc}"}, status_code=503)
        return JSONResponse({"note_id": note_id})

    async def _picture(self, request: Request) -> Response:
        hq_id = int(request.path_params["hq_id"])
        jpeg = self.pictures.jpeg(hq_id)
        if jpeg is None:
            return JSONResponse(
                {"error": f"no evidence picture for victim {hq_id}: the robots send none yet"},
                status_code=404,
            )
        return Response(jpeg, media_type="image/jpeg", headers={"Cache-Control": "no-cache"})

    async def _export_file(self, request: Request) -> Response:
        name = request.path_params["name"]
        if name not in _EXPORTS:
            return PlainTextResponse(f"no export {name!r}", status_code=404)
        try:
            data = await self._run(_export(name))
        except RegistryError as exc:
            return PlainTextResponse(f"cannot read the registry: {exc}", status_code=503)
        return Response(
            data,
            media_type=_EXPORTS[name][0],
            headers={"Content-Disposition": f'attachment; filename="{name}"'},
        )


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    try:
        return socket.create_server((host, port), family=family)
    except OSError as exc:
        raise ConsoleError(
            f"console: cannot listen on {host}:{port}: {exc.strerror or exc}"
        ) from None
