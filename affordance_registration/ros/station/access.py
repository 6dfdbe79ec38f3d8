# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Who may use the operator station, and how much: the access secret, the Origin and Host checks,
the bounds on websocket frames and message rates, no share tunnel and no outbound connection.

The station drives a robot's picture of the world, so it admits its operator only:

* **an access secret** per start (random, 32 URL-safe characters; or configured with the
  ``AFFORDANCE_STATION_SECRET`` environment variable / the ``access_secret`` parameter) is
  required for the page and for the websocket. It goes where notebook servers put theirs: the
  URL that carries it (``http://127.0.0.1:8080/?token=...``) is printed to the terminal that
  started the station and kept in a file only its user can read (:func:`keep_url`); it never
  goes through the ROS logger (``/rosout``, the ROS log folder), and the ``access_secret``
  parameter is undeclared once read (no GetParameters answers it). The page's first request
  with it sets an HttpOnly, SameSite=Strict cookie named after the port, which the page's own
  websocket then presents. A plain websocket client gives it as ``?token=`` or the cookie.
* **no cross-origin websocket**: a browser always sends ``Origin``; it must be the station's own
  (``http://`` + the request's ``Host``), so a page of another origin opened in the operator's
  browser cannot use the station even with the cookie in the jar (cookies ignore ports).
* **the Host header** must name the loopback address the station is bound to
  (``127.0.0.1:PORT``, ``localhost:PORT``, ``[::1]:PORT``; any when bound to every interface),
  which defeats DNS rebinding.
* **bounded input**: websocket frames larger than :data:`MAX_FRAME_BYTES` close that connection
  (code 1009) before they are read into memory; each connection's messages are paced by a token
  bucket (:data:`MAX_MESSAGES_PER_S`, :data:`MAX_BYTES_PER_S`): a flooding client is slowed down
  (its reads wait; TCP pushes back), the other clients are not.
* **no share tunnel**: viser's ``ShareUrlRequest`` message is answered by a refusal logged in one
  line, never by a connection to the share server; and :func:`forbid_outbound` makes any other
  outbound connection from the station's Python code fail (an audit hook on ``socket.connect``,
  ``socket.sendto`` and name look-ups of hosts that are not this machine).

viser is not changed: :func:`guarded` wraps the ``websockets`` server viser starts (its
``process_request`` hook and its ``max_size``) while the :class:`viser.ViserServer` is created,
and refuses to go on if the hook was not reached (a viser that starts its server another way).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import http
import ipaddress
import os
import secrets
import sys
import threading
import time
from http.cookies import CookieError, SimpleCookie
from urllib.parse import parse_qs, urlsplit

from ...core.errors import AffordanceError
from ...core.files import write_atomically
from ..glue.throttle import Throttle

__all__ = [
    "StationAccess",
    "guarded",
    "disable_share",
    "forbid_outbound",
    "new_secret",
    "configured_secret",
    "MAX_FRAME_BYTES",
    "MAX_MESSAGES_PER_S",
    "MAX_BYTES_PER_S",
    "SECRET_ENV",
    "RUNTIME_ENV",
    "keep_url",
    "url_file",
]

#: largest websocket frame a client may send (1 MiB): the page sends clicks, camera poses, GUI
#: values and gizmo drags, all well under 10 kB; a bigger frame closes that connection (1009)
MAX_FRAME_BYTES = 1 << 20
#: sustained messages per second per connection (the page sends its camera at most at its
#: frame rate, about 60/s, while dragging); bursts of twice this are let through
MAX_MESSAGES_PER_S = 100.0
#: sustained bytes per second per connection; bursts of twice this
MAX_BYTES_PER_S = 4.0 * (1 << 20)
#: environment variable holding the secret when the access_secret parameter is ''
SECRET_ENV = "AFFORDANCE_STATION_SECRET"
#: environment variable naming the folder of the files keeping the stations' URLs (default:
#: ``$XDG_RUNTIME_DIR/affordance_registration``, else ``~/.local/share/affordance_registration/
#: runtime``, as Jupyter's runtime folder)
RUNTIME_ENV = "AFFORDANCE_RUNTIME_DIR"
#: shortest secret accepted when configured
MIN_SECRET = 16
_LOOPBACK_NAMES = ("localhost", "localhost.localdomain", "ip6-localhost", "ip6-loopback")


def new_secret() -> str:
    """A fresh random access secret (32 URL-safe characters, 192 bits)."""
    return secrets.token_urlsafe(24)


def _bounded(text: str, limit: int = 80) -> str:
    text = str(text)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


class StationAccess:
    """The checks of one station: ``secret``, the address it is bound to (``host``, ``port``)
    and the bounds. ``log(text)`` hears each refusal (throttled by the caller's logger)."""

    def __init__(
        self,
        secret: str,
        host: str,
        port: int,
        log=None,
        max_frame_bytes: int = MAX_FRAME_BYTES,
        max_messages_per_s: float = MAX_MESSAGES_PER_S,
        max_bytes_per_s: float = MAX_BYTES_PER_S,
    ):
        secret = str(secret)
        if (
            len(secret) < MIN_SECRET
            or not secret.isprintable()
            or any(c in secret for c in " ;,&=?#%\"'")
        ):
            raise AffordanceError(
                f"the station's access secret must be at least {MIN_SECRET} "
                f"printable characters without spaces, ; , & = ? # % or quotes"
            )
        self.secret = secret
        self.host, self.port = host, int(port)
        self.log = log or (lambda text: None)
        self.max_frame_bytes = int(max_frame_bytes)
        self.max_messages_per_s = float(max_messages_per_s)
        self.max_bytes_per_s = float(max_bytes_per_s)
        self.installed = False  # the websocket server was wrapped
        self.refused = 0  # requests refused so far
        self._refusals = Throttle(1.0)  # a refusal is logged at most once a second

    # ------------------------------------------------------------------ names
    @property
    def cookie_name(self) -> str:
        """Cookies are per host, not per port: the name carries the port."""
        return f"affordance_station_{self.port}"

    def url(self, host: str | None = None, secret: bool = True) -> str:
        """The URL an operator opens (with the secret; without it for a log line)."""
        host = host or self.host
        if host in ("0.0.0.0", "::", ""):
            host = "127.0.0.1"
        shown = f"[{host}]" if ":" in host else host
        return f"http://{shown}:{self.port}/" + (f"?token={self.secret}" if secret else "")

    def allowed_hosts(self) -> set[str] | None:
        """The Host header values accepted (None: any -- bound to every interface)."""
        if self.host in ("0.0.0.0", "::", ""):
            return None
        names = {self.host, f"[{self.host}]"} if ":" in self.host else {self.host}
        try:
            if ipaddress.ip_address(self.host).is_loopback:
                names |= {"127.0.0.1", "localhost", "[::1]"}
        except ValueError:
            pass
        return {f"{n}:{self.port}" for n in names}

    # ------------------------------------------------------------------ the checks
    def _presented(self, request) -> tuple[str | None, bool]:
        """(the secret the request presents or None, whether it came in the query)."""
        query = parse_qs(urlsplit(request.path).query)
        token = (query.get("token") or [None])[0]
        if token is not None:
            return token, True
        raw = request.headers.get("Cookie")
        if raw:
            jar = SimpleCookie()
            try:
                jar.load(raw)
            except CookieError:
                return None, False
            if self.cookie_name in jar:
                return jar[self.cookie_name].value, False
        return None, False

    def problem(self, request) -> str | None:
        """Why ``request`` (a websockets ``Request``: the page, an asset, a websocket upgrade)
        is refused, or None."""
        host = request.headers.get("Host", "")
        allowed = self.allowed_hosts()
        if allowed is not None and host not in allowed:
            return f"Host {_bounded(host)!r} is not this station's address"
        upgrade = (request.headers.get("Upgrade") or "").lower() == "websocket"
        origin = request.headers.get("Origin")
        if upgrade and origin is not None and origin != f"http://{host}":
            return f"a websocket from another origin ({_bounded(origin)!r})"
        token, _ = self._presented(request)
        if token is None:
            return "no access secret"
        if not hmac.compare_digest(token.encode("utf-8", "replace"), self.secret.encode("utf-8")):
            return "a wrong access secret"
        return None

    def refuse(self, connection, request, why: str):
        """The 403 answer (a line in the log, throttled to one a second)."""
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        self.refused += 1
        if self._refusals.due():
            peer = getattr(connection, "remote_address", None)
            self.log(
                f"station: refused {_bounded(request.path, 40)!r} from {peer}: {why} "
                f"({self.refused} refused so far)"
            )
        body = (
            b"403 Forbidden: this operator station needs its access secret. Open the URL "
            b"the station printed (http://HOST:PORT/?token=...).\n"
        )
        return Response(
            http.HTTPStatus.FORBIDDEN,
            "Forbidden",
            Headers(
                {"Content-Type": "text/plain; charset=utf-8", "Content-Length": str(len(body))}
            ),
            body,
        )

    def process_request(self, inner):
        """A websockets ``process_request`` hook: the checks, then ``inner`` (viser's page
        server); a page fetched with the secret in its query sets the cookie."""

        def hook(connection, request):
            why = self.problem(request)
            if why is not None:
                return self.refuse(connection, request, why)
            response = inner(connection, request) if inner is not None else None
            token, in_query = self._presented(request)
            if response is not None and in_query:
                response.headers["Set-Cookie"] = (
                    f"{self.cookie_name}={self.secret}; Path=/; HttpOnly; SameSite=Strict"
                )
            if response is not None:
                response.headers["Cache-Control"] = "no-store"
                response.headers["X-Frame-Options"] = "DENY"
            return response

        return hook

    def paced(self, handler):
        """A websockets connection handler whose reads are paced by the token buckets."""
        access = self

        async def guarded_handler(connection):
            recv = connection.recv
            bucket = _Bucket(access.max_messages_per_s, access.max_bytes_per_s)

            async def paced_recv(*args, **kwargs):
                message = await recv(*args, **kwargs)
                wait = bucket.take(len(message))
                if wait > 0:
                    await asyncio.sleep(wait)
                return message

            connection.recv = paced_recv
            return await handler(connection)

        return guarded_handler


class _Bucket:
    """Two token buckets (messages, bytes), bursts of two seconds' worth."""

    def __init__(self, messages_per_s: float, bytes_per_s: float, clock=time.monotonic):
        self.rates = (messages_per_s, bytes_per_s)
        self.tokens = [2 * messages_per_s, 2 * bytes_per_s]
        self.clock = clock
        self.at = clock()

    def take(self, size: int) -> float:
        """Spend one message of ``size`` bytes; returns how long to wait first (s)."""
        now = self.clock()
        dt, self.at = now - self.at, now
        wait = 0.0
        for i, cost in enumerate((1.0, float(size))):
            rate = self.rates[i]
            self.tokens[i] = min(2 * rate, self.tokens[i] + dt * rate) - cost
            if self.tokens[i] < 0:
                wait = max(wait, -self.tokens[i] / rate)
        return wait


_PATCH_LOCK = threading.Lock()


@contextlib.contextmanager
def guarded(access: StationAccess):
    """While the ``viser.ViserServer`` is created in this block, the websockets server it starts
    gets ``access``'s checks, frame bound and pacing. Raises :class:`AffordanceError` after the
    block when viser did not start its server through the hook (nothing would be checked)."""
    import websockets.asyncio.server as ws_server

    with _PATCH_LOCK:
        original = ws_server.serve

        def serve(handler, *args, **kwargs):
            kwargs["process_request"] = access.process_request(kwargs.get("process_request"))
            kwargs["max_size"] = access.max_frame_bytes
            kwargs["max_queue"] = 4  # frames buffered per connection before TCP waits
            access.installed = True
            return original(access.paced(handler), *args, **kwargs)

        ws_server.serve = serve
        try:
            yield access
        finally:
            ws_server.serve = original
    if not access.installed:
        raise AffordanceError(
            "this viser does not start its websocket server through "
            "websockets.asyncio.server.serve: the station cannot check who "
            "connects, so it does not serve the page"
        )


def disable_share(server, log) -> None:
    """viser's share tunnel (a public URL through viser's share server) never opens: its
    ``ShareUrlRequest`` handler looks ``request_share_url`` up on the server when a request
    comes, so the instance's own refusing version answers."""

    def refuse_share(*args, **kwargs):
        log(
            "station: a client asked for a public share URL: refused (the station makes no "
            "outbound connections)"
        )
        return None

    server.request_share_url = refuse_share
    server.disconnect_share_url = lambda *args, **kwargs: None
    server.get_share_url = lambda *args, **kwargs: None


# ---------------------------------------------------------------------------- outbound
_OUTBOUND = {"installed": False, "allowed": set(), "log": None}


def _is_local(host) -> bool:
    if host is None:
        return True
    if isinstance(host, bytes):
        host = host.decode("ascii", "replace")
    host = str(host).strip("[]").lower()
    if host in ("",) + _LOOPBACK_NAMES or host in _OUTBOUND["allowed"]:
        return True
    try:
        addr = ipaddress.ip_address(host.split("%")[0])
    except ValueError:
        return False
    return addr.is_loopback or addr.is_unspecified


def _address_host(address):
    """The host of a socket address (None for a Unix socket path, which stays local)."""
    if isinstance(address, tuple) and address:
        return address[0]
    return None


def _audit(event: str, args) -> None:
    if event == "socket.getaddrinfo":
        host = args[0]
    elif event in ("socket.connect", "socket.sendto"):
        host = _address_host(args[1])
    elif event == "socket.gethostbyname":
        host = args[0]
    else:
        return
    if _is_local(host):
        return
    log = _OUTBOUND["log"]
    if log is not None:
        with contextlib.suppress(Exception):
            log(
                f"station: refused an outbound connection to {_bounded(host)!r} ({event}): the "
                f"station talks to this machine only"
            )
    raise PermissionError(
        f"the operator station makes no outbound connections ({event} {_bounded(host)!r})"
    )


def forbid_outbound(allowed_hosts=(), log=None) -> None:
    """From now on, this process's Python code cannot resolve or connect to any host but this
    machine (and ``allowed_hosts``: the address the station is bound to). Audit hooks cannot be
    removed: call it in the station's own process only. DDS (C++) is not affected; it is
    confined to loopback by ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``."""
    _OUTBOUND["allowed"] |= {str(h).strip("[]").lower() for h in allowed_hosts}
    _OUTBOUND["log"] = log
    if not _OUTBOUND["installed"]:
        sys.addaudithook(_audit)
        _OUTBOUND["installed"] = True


def configured_secret(parameter: str) -> str:
    """The secret: the parameter, else the environment variable, else a new random one."""
    return parameter or os.environ.get(SECRET_ENV, "") or new_secret()


def url_file(port: int) -> str:
    """The file keeping the URL (with its secret) of the station on ``port``."""
    folder = os.environ.get(RUNTIME_ENV) or (
        os.path.join(os.environ["XDG_RUNTIME_DIR"], "affordance_registration")
        if os.environ.get("XDG_RUNTIME_DIR")
        else os.path.join(os.path.expanduser("~"), ".local/share/affordance_registration/runtime")
    )
    return os.path.join(folder, f"station-{int(port)}.url")


def keep_url(url: str, port: int) -> str:
    """Keep ``url`` in :func:`url_file` -- mode 0600, in a folder made 0700 -- for the operator's
    own tools to find; returns its path. Raises OSError when it cannot."""
    path = url_file(port)
    os.makedirs(os.path.dirname(path), mode=0o700, exist_ok=True)
    write_atomically({path: url + "\n"}, mode=0o600)
    return path
