"""Who may use the console: loopback without a token, a network only with one.

``check_binding`` refuses a non-loopback address without a token (the console
would hand the victims and the operator's actions to anyone on the network).
``Access`` wraps the web app: with a token configured, every request must carry
it (the HttpOnly, SameSite=Strict cookie the sign-in form sets, or
``Authorization: Bearer <token>``), otherwise 401 (the page itself answers with
the sign-in form). Whatever the token, a POST from a page of another origin is
refused (403): a web page elsewhere in the operator's browser cannot press the
console's buttons.
"""

from __future__ import annotations

import hmac
import ipaddress
from typing import Any
from urllib.parse import parse_qs

from starlette.requests import Request
from starlette.responses import HTMLResponse, PlainTextResponse, Response

from hq.errors import HqError

COOKIE = "rescue_hq_token"
MIN_TOKEN_CHARS = 12
_MAX_FORM_BYTES = 1024


class AccessConfigError(HqError, ValueError):
    """The console's address and token do not go together; one line."""


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_binding(host: str, token: str | None) -> None:
    if token is not None and len(token) < MIN_TOKEN_CHARS:
        raise AccessConfigError(
            f"console token is {len(token)} characters; use at least {MIN_TOKEN_CHARS}"
        )
    if token is None and not is_loopback(host):
        raise AccessConfigError(
            f"console on {host} is reachable from the network: give a token "
            "(--web-token-file FILE), or bind it to 127.0.0.1"
        )


def _same(a: str | None, b: str) -> bool:
    return a is not None and hmac.compare_digest(a.encode(), b.encode())


class Access:
    """ASGI middleware: the token check and the same-origin check for POSTs."""

    def __init__(self, app: Any, token: str | None, login_page: str) -> None:
        self.app = app
        self.token = token
        self.login_page = login_page

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        request = Request(scope, receive)
        refusal = await self._refusal(request)
        if refusal is None:
            await self.app(scope, request.receive, send)
        else:
            await refusal(scope, receive, send)

    async def _refusal(self, request: Request) -> Response | None:
        if request.method == "POST":
            origin = request.headers.get("origin")
            if origin is not None and origin != f"http://{request.headers.get('host', '')}":
                return PlainTextResponse("refused: a request from another site", status_code=403)
        if self.token is None:
            return None
        if request.url.path == "/login" and request.method == "POST":
            body = await request.body()
            form = parse_qs(body[:_MAX_FORM_BYTES].decode("utf-8", "replace"))
            if _same(form.get("token", [None])[0], self.token):
                return None
            return self._login(request, "wrong token")
        if _same(request.cookies.get(COOKIE), self.token):
            return None
        scheme, _, value = request.headers.get("authorization", "").partition(" ")
        if scheme.lower() == "bearer" and _same(value.strip(), self.token):
            return None
        if request.url.path == "/":
            return self._login(request, "")
        return PlainTextResponse(
            "401: this console needs its token",
            status_code=401,
            headers={"WWW-Authenticate": "Bearer"},
        )

    def _login(self, _request: Request, message: str) -> Response:
        return HTMLResponse(self.login_page.replace("{{MESSAGE}}", message), status_code=401)
