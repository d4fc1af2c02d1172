"""The console's web server: Starlette on uvicorn, in rescue-hq's process.

Threads (besides the HQ's own): ``hq-web`` runs uvicorn's event loop (HTTP,
server-sent events; every open page gets each new state from hq.web.feed.Hub);
``hq-web-db`` (hq.web.feed.ConsoleDatabase) owns the console's registry
connection, runs the pages' writes and builds the states.

Operator actions take the HQ's existing path: they are written to the registry's
``actions`` table exactly as ``rescue-hq mark``, ``look`` and ``looks`` write them
(a victim's card: confirmed, rescued, false alarm, look closer; a robot's closer
looks off or on: POST /api/robots/{sysid}/looks), and the HQ's main
thread (which notices within 0.25 s) sends them to the robots and resends until
acknowledged.

Access (hq.web.access): on a loopback address with no token configured, open; a
configured token is required everywhere (cookie from the sign-in form, or
``Authorization: Bearer``), otherwise 401.
"""

from __future__ import annotations

import asyncio
import html
import json
import logging
import re
import socket
import sqlite3
import threading
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

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
from starlette.types import Receive, Scope, Send

from fusion.types import Sensor
from hq.errors import HqError
from hq.records import OperatorAction
from hq.registry import Registry
from hq.registry_file import RegistryError
from hq.view import HqVictim, hq_victims
from hq.web import access, assets
from hq.web.downloads import EXPORTS, coverage_job, export_job
from hq.web.feed import ConsoleDatabase, Hub, Job, T, picture_job
from hq.web.limits import ConnectionLimits, capped_protocol
from hq.web.notes import BadNote, Notes
from hq.web.state import LiveRobots

log = logging.getLogger(__name__)

_KEEPALIVE_S = 15.0  # an SSE comment line keeps proxies and the browser's timer happy
_MAX_BODY_BYTES = 4096
_BACKLOG = 128  # pending connections; also how many one accept round takes
_PICTURE_VERSION = re.compile(r"\d{1,3}-\d{1,10}-\d{1,10}")  # robot-victim-picture_id
_ACTIONS = {
    "confirmed": OperatorAction.CONFIRMED,
    "rescued": OperatorAction.RESCUED,
    "false_alarm": OperatorAction.FALSE_ALARM,
    "look_closer": OperatorAction.LOOK_CLOSER,
}
_LOOKS = {"off": OperatorAction.LOOKS_OFF, "on": OperatorAction.LOOKS_ON}


class ConsoleError(HqError):
    """The console cannot start (the address is taken or not ours); one line."""


@dataclass(frozen=True)
class ConsoleOptions:
    host: str = "127.0.0.1"
    port: int = 8080
    token: str | None = None
    link_timeout_s: float = 5.0
    asset_dir: Path | None = None
    max_connections: int | None = None  # None: hq.web.limits' defaults
    max_streams: int | None = None


def _static(name: str) -> str:
    return resources.files("hq.web").joinpath("static", name).read_text(encoding="utf-8")


def _find(registry: Registry, hq_id: int) -> HqVictim:
    for v in hq_victims(registry):
        if v.hq_id == hq_id:
            return v
    raise LookupError(f"no HQ victim {hq_id}")


def _act(hq_id: int, action: OperatorAction) -> Job[list[int]]:
    def job(registry: Registry, _notes: Notes) -> list[int]:
        victim = _find(registry, hq_id)
        return [registry.add_action(r, v, action) for r, v in victim.sources]

    return job


def _looks(sysid: int, action: OperatorAction) -> Job[int]:
    def job(registry: Registry, _notes: Notes) -> int:
        return registry.add_action(sysid, 0, action)  # KeyError: a robot never heard

    return job


def _note(hq_id: int, text: str) -> Job[int]:
    def job(registry: Registry, notes: Notes) -> int:
        _find(registry, hq_id)
        return notes.add(hq_id, text).note_id

    return job


class Console:
    """The running console: start() binds and serves, stop() ends both threads."""

    def __init__(
        self,
        db_path: Path,
        options: ConsoleOptions,
        live: LiveRobots,
    ) -> None:
        access.check_binding(options.host, options.token)
        self.options = options
        self.live = live
        self.asset_dir = options.asset_dir or assets.default_asset_dir()
        self.asset_problems = assets.verify(self.asset_dir)
        self._hub: Hub | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ready = threading.Event()
        self._db = ConsoleDatabase(db_path, live, options.link_timeout_s, self._publish)
        self._limits = ConnectionLimits(options.max_connections, options.max_streams)
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
            http=capped_protocol(self._limits),
            backlog=_BACKLOG,
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
            self._loop.set_exception_handler(self._limits.loop_exception)
            self._hub = Hub()
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
            Route("/api/robots/{sysid:int}/looks", self._robot_looks, methods=["POST"]),
            Route("/victims/{hq_id:int}/picture", self._picture),
            Route("/export/{name}", self._export_file),
            Route("/api/coverage", self._coverage),
        ]
        app = Starlette(routes=routes, lifespan=lifespan)
        return access.Access(app, self.options.token, _static("login.html"))

    async def _run(self, job: Job[T]) -> T:
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
        limits = self._limits
        if not limits.open_stream():
            return PlainTextResponse(
                limits.busy_stream_text,
                status_code=503,
                headers={"Retry-After": "5", "Connection": "close"},
            )

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

        self._db.watchers = limits.streams
        if not hub.data:  # none kept while no page watched: the database thread builds one
            self._db.wanted.set()

        def closed() -> None:
            limits.close_stream()
            self._db.watchers = limits.streams
            if limits.streams == 0:
                hub.forget()  # no one watches: the next page waits for a fresh state

        return _CountedStream(
            closed,
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

    async def _robot_looks(self, request: Request) -> Response:
        """The operator's "no more looks" / "looks on" for one robot ({"looks": "off"})."""
        sysid = int(request.path_params["sysid"])
        try:
            switch = (await self._body(request)).get("looks")
            if switch not in _LOOKS:
                raise ValueError(f"looks must be off or on, not {switch!r}")
            if not 1 <= sysid <= 255:
                raise ValueError(f"system ID {sysid} is outside 1..255")
            seq = await self._run(_looks(sysid, _LOOKS[switch]))
        except ValueError as exc:
            return JSONResponse({"error": str(exc)}, status_code=400)
        except KeyError as exc:
            return JSONResponse({"error": str(exc.args[0])}, status_code=404)
        except RegistryError as exc:
            return JSONResponse({"error": f"not recorded, try again: {exc}"}, status_code=503)
        log.info("console: looks %s on robot %d -> action %d", switch, sysid, seq)
        return JSONResponse({"action_seq": seq})

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
        version = request.query_params.get("v")
        if version is not None and not _PICTURE_VERSION.fullmatch(version):
            return JSONResponse({"error": f"bad picture version {version[:40]!r}"}, 400)
        kind_text = request.query_params.get("kind", str(Sensor.COLOUR))
        try:
            kind = Sensor(kind_text)
        except ValueError:
            return JSONResponse(
                {"error": f"bad picture kind {kind_text[:40]!r}: colour or thermal"}, 400
            )
        try:
            jpeg = await self._run(picture_job(hq_id, version, kind))
        except RegistryError as exc:
            return JSONResponse({"error": f"cannot read the registry: {exc}"}, 503)
        if jpeg is None:
            return JSONResponse(
                {
                    "error": f"no {kind} evidence picture for victim {hq_id}:"
                    " no robot has sent one yet"
                },
                status_code=404,
            )
        # A version names one picture for good: the browser may keep it. The bytes
        # come from a robot: never let the browser guess they are anything but a JPEG.
        cache = "private, max-age=86400" if version else "no-cache"
        headers = {"Cache-Control": cache, "X-Content-Type-Options": "nosniff"}
        return Response(jpeg, media_type="image/jpeg", headers=headers)

    async def _coverage(self, _request: Request) -> Response:
        try:
            data = await self._run(coverage_job(self.live))
        except RegistryError as exc:
            return JSONResponse({"error": f"cannot read the registry: {exc}"}, 503)
        return Response(data, media_type="application/json", headers={"Cache-Control": "no-cache"})

    async def _export_file(self, request: Request) -> Response:
        name = request.path_params["name"]
        if name not in EXPORTS:
            return PlainTextResponse(f"no export {name!r}", status_code=404)
        try:
            data = await self._run(export_job(name))
        except RegistryError as exc:
            return PlainTextResponse(f"cannot read the registry: {exc}", status_code=503)
        return Response(
            data,
            media_type=EXPORTS[name][0],
            headers={"Content-Disposition": f'attachment; filename="{name}"'},
        )


class _CountedStream(StreamingResponse):
    """An event stream that gives its place back when it ends, however it ends."""

    def __init__(self, closed: Callable[[], None], *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._closed = closed

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            self._closed()


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    try:
        return socket.create_server((host, port), family=family)
    except OSError as exc:
        raise ConsoleError(
            f"console: cannot listen on {host}:{port}: {exc.strerror or exc}"
        ) from None
