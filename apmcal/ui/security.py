"""Who may use the browser interface: the page opened from the address ``apmcal ui`` printed,
on this computer, and nothing else.

The server listens on 127.0.0.1 only, and every request must

- carry the access token: ``?token=...`` in the address (the first visit; the token then goes
  into a cookie that only this address gets back, ``SameSite=Strict``, and the address bar loses
  it), the cookie, or an ``X-Apmcal-Token`` header;
- name this server in its ``Host`` header (127.0.0.1 or localhost with this port): a web page
  whose own host name was made to resolve to 127.0.0.1 (DNS rebinding) sends its own name;
- come, when it says where from (``Origin``), from this server's own pages.

Anything else is refused (403) with one line saying why. So another web page open in the same
browser cannot drive an upload to the vehicle, and another user of this computer, who can reach
the port but cannot read the token, cannot either. The answers also tell the browser to load
nothing from anywhere but this server (``Content-Security-Policy``).
"""
from __future__ import annotations

import hmac
import secrets
from http.cookies import SimpleCookie
from urllib.parse import parse_qs, urlencode

TOKEN_PARAM = "token"
TOKEN_HEADER = b"x-apmcal-token"

#: nothing from the network: scripts, styles, images and connections from this server alone
#: (images also as data: URLs, as the reports embed their figures; the reports' own inline styles)
SECURITY_HEADERS = [
    (b"content-security-policy",
     b"default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
     b"img-src 'self' data: blob:; connect-src 'self'; frame-src 'self'; "
     b"frame-ancestors 'self'; form-action 'self'; base-uri 'none'"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"cache-control", b"no-store"),
]


def new_token() -> str:
    """A fresh random access token (192 bits, URL-safe)."""
    return secrets.token_urlsafe(24)


def cookie_name(port: int) -> str:
    """The token's cookie: one per port, so that two servers on one computer do not clash."""
    return f"apmcal_ui_{port}"


class TokenGuard:
    """ASGI middleware refusing every request that is not from this server's own page (see the
    module docstring).

    Parameters
    ----------
    app : ASGI application
    token : str
        The access token.
    port : int
        The port the server listens on (for the Host and Origin checks).
    """

    def __init__(self, app, token: str, port: int):
        self.app = app
        self.token = token
        self.port = port
        self.hosts = {f"127.0.0.1:{port}", f"localhost:{port}"}
        self.origins = {f"http://{h}" for h in self.hosts}
        self.cookie = cookie_name(port)

    async def __call__(self, scope, receive, send):
        """Pass the request on, or refuse it (the ASGI call)."""
        if scope["type"] == "lifespan":
            return await self.app(scope, receive, send)
        if scope["type"] != "http":          # no websockets here
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1")
                   for k, v in scope.get("headers", [])}
        why = self.refusal(scope, headers)
        if why is not None:
            return await self.refuse(send, why)
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        if scope["method"] == "GET" and TOKEN_PARAM in query and scope["path"] == "/":
            return await self.enter(send, scope, query)
        await self.app(scope, receive, self.with_headers(send))

    def refusal(self, scope, headers: dict[str, str]) -> str | None:
        """Why this request is refused, None when it may go on."""
        if headers.get("host", "") not in self.hosts:
            return "this server answers only to its own address (http://127.0.0.1:PORT)"
        origin = headers.get("origin")
        if origin is not None and origin not in self.origins:
            return "requests from other web pages are refused"
        if not self.has_token(scope, headers):
            return ("this address needs its access token: open the address `apmcal ui` "
                    "printed (http://127.0.0.1:PORT/?token=...)")
        return None

    def has_token(self, scope, headers: dict[str, str]) -> bool:
        """True when the token is in the address, the cookie or the header."""
        given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get(TOKEN_PARAM, [])
        given += [headers.get(TOKEN_HEADER.decode(), "")]
        cookie = SimpleCookie()
        try:
            cookie.load(headers.get("cookie", ""))
        except Exception:          # a malformed cookie header is no token
            pass
        if self.cookie in cookie:
            given.append(cookie[self.cookie].value)
        return any(hmac.compare_digest(g.encode(), self.token.encode()) for g in given if g)

    async def enter(self, send, scope, query: dict) -> None:
        """The first visit: the token into the cookie, and the address without it."""
        rest = {k: v for k, v in query.items() if k != TOKEN_PARAM}
        location = scope["path"] + (f"?{urlencode(rest, doseq=True)}" if rest else "")
        cookie = (f"{self.cookie}={self.token}; Path=/; HttpOnly; SameSite=Strict")
        await send({"type": "http.response.start", "status": 303,
                    "headers": [(b"location", location.encode()),
                                (b"set-cookie", cookie.encode()), *SECURITY_HEADERS]})
        await send({"type": "http.response.body", "body": b""})

    @staticmethod
    async def refuse(send, why: str) -> None:
        """403 with one line saying why."""
        body = (f"<!DOCTYPE html><meta charset='utf-8'><title>apmcal: refused</title>"
                f"<p>apmcal ui: refused: {why}</p>").encode()
        await send({"type": "http.response.start", "status": 403,
                    "headers": [(b"content-type", b"text/html; charset=utf-8"),
                                (b"content-length", str(len(body)).encode()),
                                *SECURITY_HEADERS]})
        await send({"type": "http.response.body", "body": body})

    @staticmethod
    def with_headers(send):
        """``send`` adding :data:`SECURITY_HEADERS` to the response's start."""
        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                message = dict(message)
                message["headers"] = [*message.get("headers", []), *SECURITY_HEADERS]
            await send(message)
        return send_with_headers
