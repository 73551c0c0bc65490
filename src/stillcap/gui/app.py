"""The GUI's Starlette application: the route modules, the static pages, and the security around
them.

:func:`create_app` mounts ``routes(ctx)`` of each of ``stillcap.gui.puppet``, ``.pitch`` and
``.hand`` that exists under ``/api/puppet``, ``/api/pitch`` and ``/api/hand``, the background
jobs (:mod:`stillcap.gui.jobs`) under ``/api/jobs``, ``/api/info`` (what folder is open), and the
pages of ``gui/static/`` (``index.html`` is the shell; pages are ``puppet.html``, ``pitch.html``,
``hand.html``; three.js under ``vendor/three/``).

Security (a local server is reachable by every web page the user visits, through the browser):

- **Host** must be ``127.0.0.1:PORT`` or ``localhost:PORT`` (any port when the app is built
  without one): a DNS-rebinding page's requests carry its own host name and are refused.
- **Origin**, when sent, must be this server's own; **Sec-Fetch-Site**, when sent, must be
  ``same-origin`` or ``none`` (the user opened the URL): requests from other sites are refused.
- **The session token**: API calls carry it in the ``X-Stillcap-Token`` header. A page is opened
  once with ``?token=...``; the server answers with an HttpOnly, SameSite=Strict cookie and
  redirects to the same page without the token (out of the address bar and history). After that
  the cookie authorises page and static loads, and ``GET`` API calls (so that ``<img src>`` and
  download links work); every other API call (``POST``, ``PUT``, ``DELETE``) needs the header,
  which another site's page cannot set.
- **Uploads** are limited in size (``Content-Length`` checked first, the body counted while it
  is read: 413 above the limit); images are decoded with :func:`stillcap.files.images.decode_image`
  (header size checked before decoding).
- **Files**: route modules read and write only through ``ctx.resolve`` (confined to the opened
  folder, symlinks included). No shell is run anywhere in the GUI.
- Pages get a Content-Security-Policy (scripts only from this server, the inline import map by a
  per-response nonce), ``frame-ancestors 'none'``, ``nosniff`` and ``no-referrer``.
"""

from __future__ import annotations

import contextlib
import hmac
import importlib
import json
import re
import secrets
from http.cookies import SimpleCookie
from pathlib import Path
from urllib.parse import parse_qs, urlencode

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import (
    HTMLResponse,
    JSONResponse,
    PlainTextResponse,
    RedirectResponse,
    Response,
)
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from stillcap.gui import jobs as jobs_module
from stillcap.gui.context import GuiContext

__all__ = ["MAX_UPLOAD_BYTES", "STATIC_DIR", "TOKEN_HEADER", "VIEW_MODULES", "create_app", "folder_kind"]

STATIC_DIR = Path(__file__).parent / "static"
#: Largest request body accepted (a photo of a 24-megapixel camera is under 20 MB as JPEG).
MAX_UPLOAD_BYTES = 64 * 1024 * 1024
TOKEN_HEADER = "x-stillcap-token"
#: The route modules mounted when importable: ``stillcap.gui.<name>`` under ``/api/<name>``.
VIEW_MODULES = ("puppet", "pitch", "hand")
_LOCAL_HOSTS = ("127.0.0.1", "localhost")
_SAFE_METHODS = ("GET", "HEAD")


def folder_kind(root: Path) -> str:
    """What the opened folder holds: ``"puppet"`` (a project, ``project.json``), a capture's kind
    (``capture.json``'s ``kind``: ``"pitch"``, ``"hand"``, ...), ``"session"`` (subfolders holding
    captures) or ``"empty"``. Only peeks: the route modules validate what they open."""
    root = Path(root)
    if (root / "project.json").is_file():
        return "puppet"
    cap = root / "capture.json"
    if cap.is_file():
        try:
            kind = json.loads(cap.read_text(encoding="utf-8")).get("kind")
        except (OSError, ValueError, AttributeError):
            return "unknown"
        return kind if isinstance(kind, str) else "unknown"
    if root.is_dir():
        try:
            if any((p / "capture.json").is_file() for p in root.iterdir() if p.is_dir()):
                return "session"
        except OSError:
            return "unknown"
    return "empty"


class _TooLarge(Exception):
    pass


class _Guard:
    """The ASGI middleware enforcing host, origin, token and body size on every HTTP request."""

    def __init__(self, app, ctx: GuiContext, port: int | None, max_body: int):
        self.app, self.ctx, self.port, self.max_body = app, ctx, port, max_body
        self.cookie = f"stillcap_token_{port}" if port else "stillcap_token"

    def _hosts(self) -> set[str] | None:
        if self.port is None:
            return None
        return {f"{h}:{self.port}" for h in _LOCAL_HOSTS}

    def _host_ok(self, host: str) -> bool:
        allowed = self._hosts()
        if allowed is not None:
            return host in allowed
        name = host.rsplit(":", 1)[0] if re.fullmatch(r".+:\d+", host) else host
        return name in _LOCAL_HOSTS

    def _token_ok(self, given: str | None) -> bool:
        return given is not None and hmac.compare_digest(given.encode(), self.ctx.token.encode())

    async def __call__(self, scope, receive, send):
        if scope["type"] == "lifespan":
            return await self.app(scope, receive, send)
        if scope["type"] != "http":  # no websockets are served
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        host = headers.get("host", "")
        refuse = None
        if not self._host_ok(host):
            refuse = f"host {host!r} refused: open the GUI at http://127.0.0.1:PORT/ as printed by stillcap gui"
        elif "origin" in headers and headers["origin"] != f"http://{host}":
            refuse = f"cross-origin request from {headers['origin']!r} refused"
        elif headers.get("sec-fetch-site", "same-origin") not in ("same-origin", "none"):
            refuse = f"cross-site request ({headers['sec-fetch-site']}) refused"
        if refuse:
            return await PlainTextResponse(refuse, status_code=403)(scope, receive, send)

        path, method = scope["path"], scope["method"]
        cookie = SimpleCookie()
        try:
            cookie.load(headers.get("cookie", ""))
        except Exception:
            pass
        cookie_token = cookie[self.cookie].value if self.cookie in cookie else None
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"), keep_blank_values=True)  # "?stay" survives the redirect
        if path.startswith("/api/"):
            ok = self._token_ok(headers.get(TOKEN_HEADER)) or (method in _SAFE_METHODS and self._token_ok(cookie_token))
            if not ok:
                return await JSONResponse({"error": "missing or wrong session token"}, status_code=403)(scope, receive, send)
        else:
            if "token" in query:
                if not self._token_ok(query["token"][0]):
                    return await PlainTextResponse("wrong session token: open the URL printed by stillcap gui",
                                                   status_code=403)(scope, receive, send)
                rest = {k: v for k, v in query.items() if k != "token"}
                target = path + ("?" + urlencode(rest, doseq=True) if rest else "")
                resp = RedirectResponse(target, status_code=303)
                resp.set_cookie(self.cookie, self.ctx.token, httponly=True, samesite="strict", path="/")
                return await resp(scope, receive, send)
            if not self._token_ok(cookie_token):
                return await PlainTextResponse("no session: open the URL printed by stillcap gui (it carries the token)",
                                               status_code=403)(scope, receive, send)

        length = headers.get("content-length")
        if length is not None and (not length.isdigit() or int(length) > self.max_body):
            return await PlainTextResponse(f"request body larger than the limit of {self.max_body} bytes",
                                           status_code=413)(scope, receive, send)
        seen, started = 0, False

        async def counted_receive():
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_body:
                    raise _TooLarge
            return message

        async def tracked_send(message):
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counted_receive, tracked_send)
        except _TooLarge:
            if not started:
                await PlainTextResponse(f"request body larger than the limit of {self.max_body} bytes",
                                        status_code=413)(scope, receive, send)


def _page_response(file: Path, token: str) -> Response:
    """An HTML page with its security headers; each ``<script`` gets this response's nonce, and
    ``<head>`` a ``<meta name="stillcap-token">`` the page's scripts put in the API header (the
    cookie is HttpOnly; another site cannot read this same-origin page)."""
    nonce = secrets.token_urlsafe(16)
    html = file.read_text(encoding="utf-8").replace("<script", f'<script nonce="{nonce}"')
    html = html.replace("<head>", f'<head>\n<meta name="stillcap-token" content="{token}">', 1)
    csp = (f"default-src 'self'; script-src 'self' 'nonce-{nonce}'; style-src 'self' 'unsafe-inline'; "
           "img-src 'self' blob: data:; media-src 'self' blob: mediastream:; connect-src 'self'; "
           "object-src 'none'; base-uri 'none'; frame-ancestors 'none'; form-action 'self'")
    return HTMLResponse(html, headers={"Content-Security-Policy": csp, "Cache-Control": "no-store"})


class _StaticFiles(StaticFiles):
    """``gui/static`` with the page headers on HTML files and ``nosniff`` on everything."""

    def __init__(self, *, token: str, **kwargs):
        super().__init__(**kwargs)
        self.token = token

    async def get_response(self, path, scope):
        full, _ = self.lookup_path(path)
        if full and Path(full).is_dir():
            full = str(Path(full) / "index.html")
        if full and full.endswith(".html") and Path(full).is_file():
            return _page_response(Path(full), self.token)
        return await super().get_response(path, scope)


class _SecurityHeaders:
    """``nosniff``, ``no-referrer``, no framing, same-origin resources; ``no-store`` on the API."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                hdrs = list(message.get("headers", []))
                names = {k.lower() for k, _ in hdrs}
                for k, v in ((b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer"),
                             (b"x-frame-options", b"DENY"), (b"cross-origin-resource-policy", b"same-origin")):
                    if k not in names:
                        hdrs.append((k, v))
                if scope.get("path", "").startswith("/api/") and b"cache-control" not in names:
                    hdrs.append((b"cache-control", b"no-store"))
                message = {**message, "headers": hdrs}
            await send(message)

        await self.app(scope, receive, send_with_headers)


def _view_routes(ctx: GuiContext) -> list[Mount]:
    mounts = []
    for name in VIEW_MODULES:
        try:
            module = importlib.import_module(f"stillcap.gui.{name}")
        except ModuleNotFoundError as e:
            if e.name != f"stillcap.gui.{name}":  # the module exists but an import inside it fails: a bug
                raise
            continue
        mounts.append(Mount(f"/api/{name}", routes=module.routes(ctx)))
    return mounts


def create_app(ctx: GuiContext, *, port: int | None = None, max_upload_bytes: int = MAX_UPLOAD_BYTES,
               static_dir: Path | None = None) -> Starlette:
    """The GUI application for ``ctx`` (see the module's text for what it serves and refuses).

    ``port`` is the port the server listens on: with it, the Host header must name exactly
    ``127.0.0.1:port`` or ``localhost:port``; the session cookie's name carries it too, so that two
    GUIs on one machine keep their own sessions.
    """
    ctx.state.setdefault("max_upload_bytes", max_upload_bytes)
    jm = jobs_module.job_manager(ctx)
    static = Path(static_dir) if static_dir is not None else STATIC_DIR

    async def info(request: Request):
        return JSONResponse({"root": str(ctx.root), "name": ctx.root.name, "kind": folder_kind(ctx.root),
                             "modules": [m.path.removeprefix("/api/") for m in view_mounts],
                             "max_upload_bytes": max_upload_bytes})

    view_mounts = _view_routes(ctx)
    routes = [Route("/api/info", info, methods=["GET"]),
              Mount("/api/jobs", routes=jobs_module.routes(ctx)),
              *view_mounts,
              Route("/api/{rest:path}", lambda r: JSONResponse({"error": "no such API"}, status_code=404)),
              Mount("/", app=_StaticFiles(token=ctx.token, directory=static, html=True))]
    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        jm.shutdown()

    app = Starlette(routes=routes, lifespan=lifespan)
    app.state.ctx = ctx
    app.add_middleware(_SecurityHeaders)  # added first: inside the guard
    app.add_middleware(_Guard, ctx=ctx, port=port, max_body=max_upload_bytes)
    return app
