"""Who may talk to the dashboard: an Origin check and, with --expose, a token.

A browser lets any web page open a websocket to 127.0.0.1, and viser's server accepts every
Origin, so without a check any page the user visits could read the runs and, with
--allow-launch, start processes. The check runs in the websocket handshake, before viser
sends or accepts a single message:

- Without --expose, only pages served from a loopback host (localhost, 127.0.0.0/8, ::1)
  may connect. A request without an Origin header is not a web page (a browser always sends
  one on a websocket) and is allowed.
- With --expose, a page may also come from the host the dashboard is reached by (the Origin
  equals the Host header: the page this server served), and every request needs the token
  printed at start-up: the printed URL carries it (`?token=...`), the first page load turns
  it into an HttpOnly, SameSite=Strict cookie, and the websocket presents that cookie.

Installed by `serve`: viser starts its websocket server inside `ViserServer()`, so the check
is composed with viser's own `process_request` while that constructor runs.
"""

from __future__ import annotations

import contextlib
import hmac
import ipaddress
import secrets
import sys
import threading
from dataclasses import dataclass
from http.cookies import SimpleCookie
from typing import Any, Callable, Iterator, Mapping
from urllib.parse import parse_qs, urlsplit

COOKIE = "detach_dashboard_token"
LOOPBACK_NAMES = ("localhost",)


def new_token() -> str:
    """A random token for --expose (printed once, at start-up)."""
    return secrets.token_urlsafe(24)


def is_loopback(host: str | None) -> bool:
    if not host:
        return False
    host = host.strip("[]").lower()
    if host in LOOPBACK_NAMES or host.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True)
class AccessPolicy:
    """`expose`: reachable from other machines (then `token` is required)."""

    expose: bool = False
    token: str | None = None

    def origin_refusal(self, headers: Mapping[str, str]) -> str | None:
        """Why the page that opened this connection may not use the dashboard (None: it may)."""
        origin = headers.get("Origin")
        if origin is None:
            return None  # not a browser page
        parts = urlsplit(origin)
        if parts.scheme in ("http", "https") and is_loopback(parts.hostname):
            return None
        if self.expose and parts.netloc and parts.netloc == headers.get("Host"):
            return None
        return (f"a page from {origin!r} may not connect (only pages served from this machine"
                + (" or from this dashboard's own address" if self.expose else
                   "; start with --expose to serve other machines") + ")")

    def token_refusal(self, path: str, headers: Mapping[str, str]) -> str | None:
        """Why the request lacks the token (None: it carries it, or none is required)."""
        if self.token is None:
            return None
        given = presented_tokens(path, headers)
        if any(hmac.compare_digest(t.encode(), self.token.encode()) for t in given):
            return None
        return "the dashboard needs its token: open the URL printed by detach-dashboard at start-up"

    def refusal(self, path: str, headers: Mapping[str, str], websocket: bool) -> str | None:
        """Why this HTTP request (page load or websocket upgrade) is refused, or None."""
        if websocket:
            return self.origin_refusal(headers) or self.token_refusal(path, headers)
        return self.token_refusal(path, headers)

    def cookie(self, path: str) -> str | None:
        """The Set-Cookie value that keeps the token after a page load with `?token=`."""
        if self.token is None:
            return None
        query = parse_qs(urlsplit(path).query).get("token", [])
        if not any(hmac.compare_digest(t.encode(), self.token.encode()) for t in query):
            return None
        return f"{COOKIE}={self.token}; HttpOnly; SameSite=Strict; Path=/"


def presented_tokens(path: str, headers: Mapping[str, str]) -> list[str]:
    """Tokens a request presents: `?token=` in its URL and the dashboard's cookie."""
    found = list(parse_qs(urlsplit(path).query).get("token", []))
    jar: SimpleCookie = SimpleCookie()
    with contextlib.suppress(Exception):
        jar.load(headers.get("Cookie", ""))
    if COOKIE in jar:
        found.append(jar[COOKIE].value)
    return found


def _checked(policy: AccessPolicy, viser_process: Callable[..., Any] | None,
             report: Callable[[str], None]) -> Callable[..., Any]:
    """A websockets `process_request` that applies `policy` before viser's own."""
    from websockets.datastructures import Headers
    from websockets.http11 import Response

    def process_request(connection: Any, request: Any) -> Any:
        websocket = request.headers.get("Upgrade", "").lower() == "websocket"
        reason = policy.refusal(request.path, request.headers, websocket)
        if reason is not None:
            report(f"detach-dashboard: refused {'a websocket' if websocket else 'a request'}: "
                   f"{reason}")
            body = f"detach-dashboard: {reason}\n".encode()
            return Response(403, "Forbidden", Headers({"Content-Type": "text/plain; charset=utf-8",
                                                      "Content-Length": str(len(body))}), body)
        response = viser_process(connection, request) if viser_process is not None else None
        cookie = policy.cookie(request.path)
        if response is not None and cookie is not None:
            response.headers["Set-Cookie"] = cookie
        return response

    return process_request


_INSTALL_LOCK = threading.Lock()


@contextlib.contextmanager
def checked_handshakes(policy: AccessPolicy,
                       report: Callable[[str], None] | None = None) -> Iterator[None]:
    """While the block runs, websocket servers that start check `policy` in their handshake."""
    import websockets.asyncio.server as ws_server

    report = report or (lambda line: print(line, file=sys.stderr, flush=True))
    with _INSTALL_LOCK:
        original = ws_server.serve

        def serve(*args: Any, process_request: Callable[..., Any] | None = None,
                  **kwargs: Any) -> Any:
            return original(*args, process_request=_checked(policy, process_request, report),
                            **kwargs)

        ws_server.serve = serve  # type: ignore[misc, assignment]
        try:
            yield
        finally:
            ws_server.serve = original  # type: ignore[misc]


def serve(host: str, port: int, policy: AccessPolicy, **kwargs: Any):
    """A viser server on (host, port) whose connections pass `policy`."""
    import viser

    with checked_handshakes(policy):
        return viser.ViserServer(host=host, port=port, verbose=False, **kwargs)
