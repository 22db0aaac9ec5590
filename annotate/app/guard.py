"""The annotation server's gate: an ASGI middleware in front of marimo that refuses every
request (page, static files, API, websocket) that

- names a Host other than this server's loopback address and port (DNS rebinding: a web page
  whose name resolves to 127.0.0.1 still sends its own name as Host),
- comes from a page of another origin (the Origin header a browser sets on websockets and
  cross-site requests),
- or lacks the start's random token: ``?access_token=TOKEN`` in the URL (the command serving
  the page prints it: ``s2p annotate``, or ``s2p calibrate-camera`` for the calibration page;
  the answer sets a cookie for the rest of the session), that cookie, or an
  ``Authorization: Bearer TOKEN`` header.

A refused HTTP request gets 403 with one line saying why; a refused websocket is closed
before it opens (the client sees 403). Nothing reaches marimo or the project.

Every page it lets through carries a Content-Security-Policy whose ``connect-src`` is this
server alone: nothing in the page (the Rerun viewer's check for a newer version included) can
reach another machine. Each websocket connection is logged, one line with a timestamp.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import time
from http.cookies import SimpleCookie
from urllib.parse import parse_qs

TOKEN_PARAM = "access_token"  # the same query parameter as marimo's own token


def new_token() -> str:
    """A random token for one server start (32 bytes, URL-safe)."""
    return secrets.token_urlsafe(32)


def loopback_hosts(port: int) -> set[str]:
    """Host header values that name this server: the loopback addresses with its port."""
    return {f"127.0.0.1:{port}", f"localhost:{port}", f"[::1]:{port}"}


class Guard:
    """ASGI middleware: ``Guard(app, port, token, command)`` (see the module docstring);
    ``command`` is the command that serves the page, named in the refusals so that a user is
    sent to the URL that this command printed."""

    def __init__(self, app, port: int, token: str, command: str = "s2p annotate"):
        if len(token) < 16:
            raise ValueError("the access token must be at least 16 characters")
        self.app = app
        self.token = token
        self.command = command
        self.hosts = loopback_hosts(port)
        self.origins = {f"http://{h}" for h in self.hosts}
        self.cookie = f"s2p_annotate_{port}"
        # the cookie holds a keyed hash, not the token itself
        self.cookie_value = hmac.new(token.encode(), b"s2p-annotate-cookie",
                                     hashlib.sha256).hexdigest()
        # fetches, websockets and workers' requests may go to this server only
        self.csp = ("connect-src 'self' " + " ".join(f"ws://{h}" for h in sorted(self.hosts))
                    + " blob: data:").encode()

    def refusal(self, scope) -> tuple[str | None, bool]:
        """(why the request is refused or None, whether it brought the token in its URL)."""
        headers = {k.decode("latin-1").lower(): v.decode("latin-1")
                   for k, v in scope.get("headers", [])}
        host = headers.get("host")
        if host not in self.hosts:
            return (f"refused: Host {host!r} is not this server's loopback address "
                    f"(use {sorted(self.hosts)[0]})"), False
        origin = headers.get("origin")
        if origin is not None and origin not in self.origins:
            return f"refused: a page of origin {origin!r} may not use this server", False
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        if any(hmac.compare_digest(v, self.token) for v in query.get(TOKEN_PARAM, [])):
            return None, True
        auth = headers.get("authorization", "")
        if auth.lower().startswith("bearer ") and hmac.compare_digest(auth[7:].strip(), self.token):
            return None, False
        jar = SimpleCookie()
        try:
            jar.load(headers.get("cookie", ""))
        except Exception:  # a malformed cookie header is no token
            jar = SimpleCookie()
        got = jar.get(self.cookie)
        if got is not None and hmac.compare_digest(got.value, self.cookie_value):
            return None, False
        if got is not None:  # a tab of an earlier start of the server on this port
            return (f"refused: this page is from an earlier start of `{self.command}`; open "
                    f"the URL that `{self.command}` printed at its new start "
                    f"(?{TOKEN_PARAM}=...)"), False
        return (f"refused: no valid access token; open the URL that `{self.command}` printed "
                f"(it ends in ?{TOKEN_PARAM}=...)"), False

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        why, in_url = self.refusal(scope)
        if why is not None:
            if scope["type"] == "websocket":
                await receive()  # websocket.connect
                await send({"type": "websocket.close", "code": 1008, "reason": why[:120]})
                return
            body = (why + "\n").encode()
            await send({"type": "http.response.start", "status": 403,
                        "headers": [(b"content-type", b"text/plain; charset=utf-8"),
                                    (b"content-length", str(len(body)).encode())]})
            await send({"type": "http.response.body", "body": body})
            return
        if scope["type"] == "websocket":
            print(f"{time.strftime('%Y-%m-%d %H:%M:%S')} websocket {scope.get('path', '')} "
                  f"from {(scope.get('client') or ['?'])[0]}", flush=True)
            return await self.app(scope, receive, send)
        extra = [(b"content-security-policy", self.csp)]
        if in_url:
            extra.append((b"set-cookie", (f"{self.cookie}={self.cookie_value}; Path=/; HttpOnly; "
                                          "SameSite=Strict").encode()))

        async def send_with_headers(msg):
            if msg["type"] == "http.response.start":
                msg = {**msg, "headers": list(msg.get("headers", [])) + extra}
            await send(msg)

        return await self.app(scope, receive, send_with_headers)
