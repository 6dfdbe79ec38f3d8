# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The station admits its operator only: a real station process, real websocket clients and a
real headless Chromium; the share tunnel and outbound connections in a network namespace."""

import os
import shutil
import subprocess
import sys
import textwrap
import threading
import urllib.error
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest
import viser
from browser_helpers import (
    ARGS,
    CHROMIUM,
    STATION_SECRET,
    chromium_missing,
    free_port,
    open_station,
    station_argv,
    station_url,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from ros_helpers import NodeProcess, ros_env, rss_mb
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.http11 import Request
from websockets.sync.client import connect

from affordance_registration.ros.station.access import (
    MAX_FRAME_BYTES,
    StationAccess,
    _Bucket,
    new_secret,
)

SUBPROTOCOL = f"viser-v{viser.__version__}"


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("station_access")
    port = free_port()
    proc = NodeProcess(station_argv(port), tmp / "station.log")
    try:
        assert proc.wait_output("operator station on", 120), proc.output()
        yield {"proc": proc, "port": port}
    finally:
        proc.interrupt(timeout=10)
        proc.kill()
        print(proc.output()[-3000:])


def _get(url, headers=None):
    try:
        with urllib.request.urlopen(
            urllib.request.Request(url, headers=headers or {}), timeout=30
        ) as res:
            return res.status, dict(res.headers), res.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers), exc.read()


def _ws(port, query="", **kwargs):
    return connect(
        f"ws://127.0.0.1:{port}/{query}", subprotocols=[SUBPROTOCOL], open_timeout=30, **kwargs
    )


def _first_message(ws):
    return ws.recv(timeout=30)


def test_the_page_needs_the_secret(station):
    port = station["port"]
    assert _get(f"http://127.0.0.1:{port}/")[0] == 403
    assert _get(f"http://127.0.0.1:{port}/?token=wrong-secret-0123456789")[0] == 403
    code, headers, body = _get(station_url(port))
    assert code == 200 and b"<html" in body.lower()
    cookie = headers["Set-Cookie"]
    assert f"affordance_station_{port}={STATION_SECRET}" in cookie and "HttpOnly" in cookie
    # the cookie alone opens the page (its assets, a reload)
    assert _get(f"http://127.0.0.1:{port}/", {"Cookie": cookie.split(";")[0]})[0] == 200
    # DNS rebinding: another name for this address is refused, secret or not
    assert _get(station_url(port), {"Host": f"evil.example:{port}"})[0] == 403
    assert "refused" in station["proc"].output()


def test_a_websocket_without_the_secret_or_from_another_origin_is_refused(station):
    port = station["port"]
    for query, kwargs in (
        ("", {}),
        ("?token=not-the-secret-at-all", {}),
        (f"?token={STATION_SECRET}", {"origin": "http://127.0.0.1:9"}),
        (f"?token={STATION_SECRET}", {"origin": "null"}),
    ):
        with pytest.raises(InvalidStatus) as info:
            _ws(port, query, **kwargs)
        assert info.value.response.status_code == 403, (query, kwargs)
    # the operator's own page: same origin, the cookie; a script: the token
    with _ws(
        port,
        additional_headers={"Cookie": f"affordance_station_{port}={STATION_SECRET}"},
        origin=f"http://127.0.0.1:{port}",
    ) as ws:
        assert _first_message(ws)
    with _ws(port, f"?token={STATION_SECRET}") as ws:
        assert _first_message(ws)


def test_a_45_mb_frame_closes_only_its_connection_and_memory_stays_bounded(station):
    port = station["port"]
    pid = station["proc"].proc.pid
    with _ws(port, f"?token={STATION_SECRET}") as other:
        _first_message(other)
        with _ws(port, f"?token={STATION_SECRET}", max_size=None) as big:
            _first_message(big)
            with pytest.raises(ConnectionClosed) as info:
                big.send(b"\x81" * (45 * 1024 * 1024))
                while True:
                    big.recv(timeout=60)
            assert info.value.rcvd is not None and info.value.rcvd.code == 1009
        assert rss_mb(pid) < 600
        # the other client is still served: a ping is answered, the page still loads
        other.ping().wait(30)
        assert _get(station_url(port))[0] == 200
    assert station["proc"].proc.poll() is None
    assert MAX_FRAME_BYTES <= 1 << 20


class _Foreign(BaseHTTPRequestHandler):
    """A page of another origin that tries the station's websocket from the operator's browser."""

    station_port = 0

    def do_GET(self):
        body = textwrap.dedent(f"""
            <html><body><pre id="out">pending</pre><script>
            const out = document.getElementById("out");
            const ws = new WebSocket("ws://127.0.0.1:{self.station_port}/", "{SUBPROTOCOL}");
            ws.onopen = () => {{ out.textContent = "opened"; }};
            ws.onmessage = () => {{ out.textContent = "message"; }};
            ws.onclose = (e) => {{ if (out.textContent === "pending")
                out.textContent = "refused " + e.code; }};
            </script></body></html>""").encode()
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


def test_a_page_of_another_origin_in_the_operators_browser_cannot_use_the_station(station):
    missing = chromium_missing()
    assert not missing, missing
    from playwright.sync_api import sync_playwright

    port = station["port"]
    _Foreign.station_port = port
    foreign = ThreadingHTTPServer(("127.0.0.1", 0), _Foreign)
    threading.Thread(target=foreign.serve_forever, daemon=True).start()
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
            try:
                ctx = browser.new_context()
                page = ctx.new_page()
                page.set_default_timeout(120_000)
                open_station(page, station_url(port))  # the operator, cookie in the jar
                assert any(c["name"] == f"affordance_station_{port}" for c in ctx.cookies())
                evil = ctx.new_page()
                evil.goto(f"http://127.0.0.1:{foreign.server_address[1]}/")
                evil.wait_for_function(
                    "document.getElementById('out').textContent !== 'pending'", timeout=60_000
                )
                assert evil.inner_text("#out").startswith("refused")
                # and a page without the secret never gets the station's panel
                fresh = browser.new_context().new_page()
                fresh.goto(f"http://127.0.0.1:{port}/")
                assert "access secret" in fresh.inner_text("body")
            finally:
                browser.close()
    finally:
        foreign.shutdown()


# ---------------------------------------------------------------------------- outbound
OBSERVER = """
import json, os, sys
_log = os.environ["AR_OUTBOUND_LOG"]
def _hook(event, args):
    if event in ("socket.getaddrinfo", "socket.gethostbyname"):
        host = args[0]
    elif event in ("socket.connect", "socket.sendto"):
        host = args[1][0] if isinstance(args[1], tuple) else None
    else:
        return
    if host is None:
        return
    host = host.decode() if isinstance(host, bytes) else str(host)
    if host.strip("[]") in ("127.0.0.1", "::1", "localhost", "0.0.0.0", "::", ""):
        return
    with open(_log, "a") as f:
        f.write(json.dumps([event, host]) + "\\n")
sys.addaudithook(_hook)
"""

CLIENT = """
import json, sys, time, msgspec, urllib.request
from websockets.sync.client import connect
port, secret, subprotocol = sys.argv[1], sys.argv[2], sys.argv[3]
ws = connect(f"ws://127.0.0.1:{port}/?token={secret}", subprotocols=[subprotocol], open_timeout=60)
ws.recv(timeout=60)
for _ in range(4):
    ws.send(msgspec.msgpack.encode({"type": "ShareUrlRequest"}))
t0 = time.monotonic()
while time.monotonic() - t0 < 5:
    try:
        ws.recv(timeout=0.5)
    except TimeoutError:
        pass
ws.send(msgspec.msgpack.encode({"type": "ShareUrlDisconnect"}))
time.sleep(0.5)
ws.close()
print("CLIENT DONE")
"""


def _netns_ok() -> bool:
    return (
        shutil.which("unshare") is not None
        and subprocess.run(["unshare", "-rn", "true"], capture_output=True).returncode == 0
    )


def test_a_share_url_request_makes_no_outbound_connection_in_a_network_namespace(tmp_path):
    assert _netns_ok(), "unshare -rn (a user and network namespace) is not available here"
    (tmp_path / "sitecustomize.py").write_text(OBSERVER)
    (tmp_path / "client.py").write_text(CLIENT)
    log = tmp_path / "outbound.jsonl"
    port = free_port()
    station = " ".join(station_argv(port))
    script = (
        f"ip link set lo up && ({station} > {tmp_path}/station.log 2>&1 & echo $! > "
        f"{tmp_path}/pid) && for i in $(seq 600); do grep -q 'operator station on' "
        f"{tmp_path}/station.log && break; sleep 0.2; done && "
        f"{sys.executable} {tmp_path}/client.py {port} {STATION_SECRET} {SUBPROTOCOL}; "
        f"kill -INT $(cat {tmp_path}/pid); sleep 3; "
        f"kill -9 $(cat {tmp_path}/pid) 2>/dev/null; true"
    )
    env = ros_env(
        {
            "PYTHONPATH": f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
            "AR_OUTBOUND_LOG": str(log),
        }
    )
    out = subprocess.run(
        ["unshare", "-rn", "bash", "-c", script],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    station_log = (tmp_path / "station.log").read_text()
    assert "CLIENT DONE" in out.stdout, out.stdout + out.stderr + station_log
    assert "public share URL: refused" in station_log, station_log
    assert "Share URL requested" not in station_log
    attempts = log.read_text().splitlines() if log.exists() else []
    assert attempts == [], attempts


def test_outbound_connections_are_impossible_once_forbidden(tmp_path):
    code = textwrap.dedent("""
        import socket
        from affordance_registration.ros.station.access import forbid_outbound
        seen = []
        forbid_outbound(["127.0.0.1"], log=seen.append)
        for what, call in (("resolve", lambda: socket.getaddrinfo("viser.example", 443)),
                           ("connect", lambda: socket.create_connection(("192.0.2.1", 443), 1)),
                           ("udp", lambda: socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                                            .sendto(b"x", ("192.0.2.1", 53)))):
            try:
                call()
                print(what, "ALLOWED")
            except PermissionError:
                print(what, "refused")
        server = socket.socket(); server.bind(("127.0.0.1", 0)); server.listen()
        socket.create_connection(server.getsockname(), 5).close()
        print("loopback ok", len(seen))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.split("\n")[:4] == [
        "resolve refused",
        "connect refused",
        "udp refused",
        "loopback ok 3",
    ], out.stdout + out.stderr


# ---------------------------------------------------------------------------- pure checks
def _request(path="/", **headers):
    return Request(path, Headers(headers))


def test_the_checks_on_requests():
    access = StationAccess("s" * 20, "127.0.0.1", 8080)
    ok = {"Host": "127.0.0.1:8080"}
    assert access.problem(_request("/?token=" + "s" * 20, **ok)) is None
    assert access.problem(_request("/?token=" + "s" * 20, Host="localhost:8080")) is None
    assert "Host" in access.problem(_request("/?token=" + "s" * 20, Host="127.0.0.1:8081"))
    assert "no access secret" in access.problem(_request("/", **ok))
    ws = dict(ok, Upgrade="websocket", Cookie=f"affordance_station_8080={'s' * 20}")
    assert access.problem(_request("/", **ws)) is None
    assert access.problem(_request("/", **dict(ws, Origin="http://127.0.0.1:8080"))) is None
    assert "another origin" in access.problem(_request("/", **dict(ws, Origin="http://a.b")))
    with pytest.raises(Exception, match="at least 16"):
        StationAccess("short", "127.0.0.1", 8080)
    assert len(new_secret()) >= 32 and new_secret() != new_secret()


@settings(max_examples=200, deadline=None)
@given(
    st.text(min_size=1, max_size=40).filter(
        lambda t: t != "s" * 20 and "&" not in t and "#" not in t
    )
)
def test_any_other_secret_is_refused(token):
    access = StationAccess("s" * 20, "127.0.0.1", 8080)
    from urllib.parse import quote

    assert access.problem(_request("/?token=" + quote(token), Host="127.0.0.1:8080")) is not None


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 0.05), st.integers(0, 50_000)), min_size=1, max_size=400))
def test_the_pacing_never_admits_more_than_the_rate_and_the_burst(arrivals):
    """Simulated time: each message is admitted after the wait the bucket asks for; by any time
    t, at most 2 s worth of messages and bytes more than rate * t have been admitted."""
    rate, byte_rate = 100.0, 1e6
    clock = [0.0]
    bucket = _Bucket(rate, byte_rate, clock=lambda: clock[0])
    count = size_sum = 0
    for gap, size in arrivals:
        clock[0] += gap
        clock[0] += bucket.take(size)
        count, size_sum = count + 1, size_sum + size
        assert count <= 2 * rate + rate * clock[0] + 1e-6
        assert size_sum <= 2 * byte_rate + byte_rate * clock[0] + 50_000 + 1e-6


def test_the_secret_never_reaches_rosout_the_ros_log_a_parameter_or_a_shared_file(
    tmp_path, ros_context
):
    """Jupyter's rule: the URL with the access secret is printed to the terminal that started
    the station and kept in a file only its user reads (0600, in a 0700 folder); it never goes
    out on /rosout (``ros2 topic echo /rosout`` or a bag recording at start-up), into the ROS
    log folder, or through GetParameters -- even when given as the ``access_secret``
    parameter."""
    from rcl_interfaces.msg import Log, ParameterType
    from rcl_interfaces.srv import GetParameters
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from ros_helpers import Client

    from affordance_registration.ros.station.access import url_file

    secret = "a-secret-given-as-a-parameter-4242"
    port = free_port()
    runtime, logs = tmp_path / "runtime", tmp_path / "roslog"
    client = Client("rosout_listener")
    heard: list[str] = []
    # /rosout keeps a node's last 1000 lines for late joiners: a depth of 1 would hear only the
    # line after "operator station on" when discovery comes late (a loaded machine)
    rosout_qos = QoSProfile(
        depth=1000,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    client.node.create_subscription(Log, "/rosout", lambda m: heard.append(m.msg), rosout_qos)
    # a name of its own: another test's station on this domain must not answer for it
    proc = NodeProcess(
        station_argv(port, access_secret=secret) + ["-r", "__node:=station_secret_probe"],
        tmp_path / "station.out",
        env={"AFFORDANCE_RUNTIME_DIR": str(runtime), "ROS_LOG_DIR": str(logs)},
    )
    try:
        client.wait_for(
            lambda: any("operator station on" in m and f":{port}" in m for m in heard),
            120,
            "the station on /rosout",
        )
        answers = {
            name: client.call(
                GetParameters,
                "/station_secret_probe/get_parameters",
                GetParameters.Request(names=[name]),
            ).values
            for name in ("access_secret", "port")
        }
        assert [v.integer_value for v in answers["port"]] == [port]
        assert [v.type for v in answers["access_secret"]] in (
            [],
            [ParameterType.PARAMETER_NOT_SET],
        )
        assert not [m for m in heard if secret in m], heard
        # the terminal that started it has the URL; the 0600 file keeps it
        assert proc.wait_output(f"operator station: http://127.0.0.1:{port}/?token={secret}")
        kept = runtime / os.path.basename(url_file(port))
        assert open(kept).read().strip() == f"http://127.0.0.1:{port}/?token={secret}"
        assert os.stat(kept).st_mode & 0o777 == 0o600
        assert os.stat(runtime).st_mode & 0o777 == 0o700
        # nothing in the ROS log folder has it
        ros_logs = [p for p in logs.rglob("*") if p.is_file()]
        assert ros_logs and not [p for p in ros_logs if secret in p.read_text(errors="replace")]
    finally:
        client.close()
        proc.interrupt(timeout=10)
        proc.kill()
    assert not kept.exists(), "the URL file outlived its station"
