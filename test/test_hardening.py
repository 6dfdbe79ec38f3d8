# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""One regression test per kind of bad input: each bad input gets one clear
answer, the node keeps fitting a fresh click right afterwards, and nothing is written where it
must not be. Live nodes in their own processes; the CLI as a user runs it."""

import json
import math
import os
import resource
import shutil
import stat
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import PointStamped, Twist
from hypothesis import given, settings
from hypothesis import strategies as st
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from ros_helpers import engine_process, engine_session
from sensor_msgs.msg import PointCloud2, PointField
from std_srvs.srv import Trigger
from visualization_msgs.msg import InteractiveMarkerFeedback

from affordance_registration.core.transforms import pose_error
from affordance_registration.evaluation.simulation import simulate_taskboard
from affordance_registration.ros.glue.conversions import matrix_to_pose, xyz_to_pointcloud2

NS = "/affordance_engine"
FRAME = "camera_depth_optical_frame"
MODELS = os.path.join(os.path.dirname(__file__), "..", "models")


def run_cli(*args, limit_gb=2.0, timeout=30):
    """The CLI in its own process with at most ``limit_gb`` of memory; (code, stderr)."""

    def limit():
        size = int(limit_gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (size, size))

    res = subprocess.run(
        [sys.executable, "-m", "affordance_registration.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=limit,
    )
    return res.returncode, res.stderr


def run_cli_all(*commands, limit_gb=2.0, timeout=30, at_once=2):
    """Independent CLI commands, ``at_once`` at a time (the machine's two cores), each its own
    process with :func:`run_cli`'s memory limit and ``timeout`` from its own start;
    [(code, stderr, seconds it ran)] in order."""

    def limit():
        size = int(limit_gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (size, size))

    waiting = list(enumerate(commands))
    running, results = {}, [None] * len(commands)
    try:
        while waiting or running:
            while waiting and len(running) < at_once:
                k, args = waiting.pop(0)
                err = tempfile.TemporaryFile("w+")  # no pipe to fill up meanwhile
                running[k] = (
                    time.monotonic(),
                    err,
                    subprocess.Popen(
                        [sys.executable, "-m", "affordance_registration.cli", *args],
                        stdout=subprocess.DEVNULL,
                        stderr=err,
                        text=True,
                        preexec_fn=limit,
                    ),
                )
            for k, (t0, err, proc) in list(running.items()):
                if proc.poll() is not None:
                    err.seek(0)
                    results[k] = (proc.returncode, err.read(), time.monotonic() - t0)
                    err.close()
                    del running[k]
                elif time.monotonic() - t0 > timeout:
                    raise subprocess.TimeoutExpired(proc.args, timeout)
            time.sleep(0.02)
    finally:
        for _, err, proc in running.values():
            proc.kill()
            proc.wait()
            err.close()
    return results


def one_line(code, err):
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, (code, err)
    return lines[0]


# ---------------------------------------------------------------------------- a live node
@pytest.fixture(scope="module")
def node(ros_context, tmp_path_factory, library):
    tmp = tmp_path_factory.mktemp("hardening")
    with engine_session(
        tmp,
        {"refit_on_new_cloud": "false"},
        "hardening_tester",
        {
            "points": (PointCloud2, "/points", 1),
            "click": (PointStamped, "/clicked_point", 10),
            "twist": (Twist, "/spacenav/twist", 10),
            "feedback": (InteractiveMarkerFeedback, "/affordance_correction/feedback", 100),
        },
        sim=simulate_taskboard(library, 7),
    ) as s:
        yield s


def status(n):
    return n["client"].status(f"{NS}/status") or {}


def wait_error(n, text, timeout=30):
    return n["client"].wait_for(
        lambda: text in status(n).get("node", {}).get("last_error", "") and status(n),
        timeout,
        f"an error containing {text!r}",
    )


def has_the_cloud(n):
    """The node holds the simulated cloud: published here when it does not (a test run alone,
    or after one that dropped a bad cloud)."""

    def there():
        return (status(n).get("node", {}).get("cloud") or {}).get("frame_id") == FRAME

    if not there():
        n["pubs"]["points"].publish(xyz_to_pointcloud2(n["sim"].organized, FRAME))
        n["client"].wait_for(there, 30, "the good cloud")


def fit_fresh_click(n, library, k=0):
    """The node still fits a click right, whatever came before."""
    has_the_cloud(n)
    obj = n["sim"].objects[k]
    known = {o["id"] for o in status(n).get("objects", [])}
    msg = PointStamped()
    msg.header.frame_id = FRAME
    msg.point.x, msg.point.y, msg.point.z = map(float, obj.click)
    n["pubs"]["click"].publish(msg)
    st = n["client"].wait_for(
        lambda: [o for o in status(n).get("objects", []) if o["id"] not in known and o["active"]],
        60,
        "a fresh fit",
    )
    cand = st[0]["candidates"][0]
    dt, dr = pose_error(
        np.asarray(cand["pose"]), obj.T_scene_model, library[obj.template].symmetry
    )
    assert cand["template"] == obj.template and dt < 0.005 and dr < math.radians(5)
    return st[0]


def test_a_pointcloud2_with_two_x_fields_is_dropped_and_a_click_names_it(node, library):
    """Rows 'two fields named x' and 'a click after a dropped cloud'."""
    bad = xyz_to_pointcloud2(np.zeros((10, 3), np.float32), "broken_frame")
    bad.fields = list(bad.fields) + [PointField(name="x", offset=12, datatype=7, count=1)]
    node["pubs"]["points"].publish(bad)
    wait_error(node, "more than one field named 'x'")
    msg = PointStamped()
    msg.header.frame_id = FRAME
    node["pubs"]["click"].publish(msg)
    line = wait_error(node, "no usable point cloud yet")["node"]["last_error"]
    assert "'broken_frame'" in line and "more than one field named 'x'" in line
    fit_fresh_click(node, library, 0)


def test_a_storm_of_service_calls_is_answered_in_full(node):
    """Row '4 clients x 50 concurrent Trigger calls': 200 of 200 answered."""
    answers, lock = [], threading.Lock()

    def storm(k):
        # a client sending 50 calls at once needs room for 50 answers (the default keeps 10)
        from rclpy.qos import QoSProfile

        c = node["client"].node.create_client(
            Trigger,
            f"{NS}/next_model" if k % 2 else f"{NS}/previous_model",
            qos_profile=QoSProfile(depth=100),
        )
        assert c.wait_for_service(timeout_sec=30)
        futures = [c.call_async(Trigger.Request()) for _ in range(50)]
        deadline = time.monotonic() + 120
        while not all(f.done() for f in futures) and time.monotonic() < deadline:
            time.sleep(0.05)
        with lock:
            answers.extend(f.result() for f in futures if f.done())

    threads = [threading.Thread(target=storm, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    t0 = time.monotonic()
    for t in threads:
        t.join()
    print(f"200 calls answered in {time.monotonic() - t0:.1f} s")
    assert len(answers) == 200 and all(a.success for a in answers)


def test_bad_template_libraries_are_refused_with_a_reason(node, library, tmp_path):
    """Row 'templates_dir set to a library whose YAML nests 5000 deep, holds non-UTF-8 bytes,
    or mesh_scale: 1.0e+300': the SetParameters call answers, with the reason."""
    cases = {
        "deep": "name: a\nmesh: " + "[" * 5000 + "]" * 5000 + "\n",
        "bytes": b"name: \xff\xfe valve\nmesh: x.stl\n",
        "huge": "name: a\nmesh: m.stl\nmesh_scale: 1.0e+300\n",
    }
    reasons = {}
    for case, text in cases.items():
        lib = tmp_path / case
        lib.mkdir()
        shutil.copy(os.path.join(MODELS, "meshes", "grab_handle.stl"), lib / "m.stl")
        (lib / "t.yaml").write_bytes(text if isinstance(text, bytes) else text.encode())
        req = SetParameters.Request(
            parameters=[
                Parameter(
                    name="templates_dir",
                    value=ParameterValue(
                        type=ParameterType.PARAMETER_STRING, string_value=str(lib)
                    ),
                )
            ]
        )
        res = node["client"].call(SetParameters, f"{NS}/set_parameters", req, timeout=60)
        assert not res.results[0].successful
        reasons[case] = res.results[0].reason
    assert "nested too deeply" in reasons["deep"] and "not UTF-8" in reasons["bytes"]
    assert "mesh_scale" in reasons["huge"]
    assert all("t.yaml" in r for r in reasons.values()), reasons


def _set(node, name, value):
    """SetParameters of one string parameter on the node: its result."""
    req = SetParameters.Request(
        parameters=[
            Parameter(
                name=name,
                value=ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value),
            )
        ]
    )
    return node["client"].call(SetParameters, f"{NS}/set_parameters", req, timeout=60).results[0]


def _registrations_path(node) -> str:
    return node["client"].wait_for(lambda: status(node).get("node"), 60, "the node's status")[
        "registrations_file"
    ]["path"]


def test_the_file_the_node_writes_cannot_be_changed_over_the_graph(node, tmp_path):
    """SetParameters registrations_file := another file, then ~/save: the parameter is read
    only, the other file stays as it was, the save writes the node's own file."""
    victim = tmp_path / "authorized_keys"
    victim.write_text("ssh-ed25519 AAAA... operator@station\n")
    own = _registrations_path(node)
    res = _set(node, "registrations_file", str(victim))
    assert not res.successful and "read-only" in res.reason.lower(), res.reason
    save = node["client"].call(Trigger, f"{NS}/save", timeout=60)
    assert save.success and own in save.message, save.message
    assert sorted(os.listdir(tmp_path)) == ["authorized_keys"]
    assert victim.read_text() == "ssh-ed25519 AAAA... operator@station\n"


def test_a_fifo_in_place_of_the_registrations_file_never_stops_the_node(node):
    """The registrations file replaced by a FIFO: ~/save is answered (refused, naming it), and
    so is every call after it; once the FIFO is gone the save works again."""
    path = _registrations_path(node)
    node["client"].call(Trigger, f"{NS}/save", timeout=60)
    os.unlink(path)
    os.mkfifo(path)
    try:
        res = node["client"].call(Trigger, f"{NS}/save", timeout=60)
        assert not res.success and "a FIFO" in res.message, res.message
        assert node["client"].call(Trigger, f"{NS}/next_model", timeout=60) is not None
    finally:
        os.unlink(path)
    res = node["client"].call(Trigger, f"{NS}/save", timeout=60)
    assert res.success and path in res.message


def test_an_alias_bomb_template_library_is_refused_and_the_node_answers(node, tmp_path):
    """templates_dir set to a folder holding a 1 kB alias-bomb template: refused with the
    reason, at once, and the node answers the next call."""
    lib = tmp_path / "bomb"
    lib.mkdir()
    shutil.copy(os.path.join(MODELS, "meshes", "grab_handle.stl"), lib / "m.stl")
    (lib / "t.yaml").write_text(alias_bomb("name: a\nmesh: m.stl\nscale:", levels=12))
    res = _set(node, "templates_dir", str(lib))
    assert not res.successful and "t.yaml" in res.reason and "aliases" in res.reason, res.reason
    assert node["client"].call(Trigger, f"{NS}/next_model", timeout=60) is not None


def alias_bomb(prefix: str, levels: int = 9) -> str:
    """YAML whose last key (``prefix`` ends with it) holds a "billion laughs": a list of
    ``levels`` lists, each of nine aliases of the one before, 9**levels strings when expanded,
    in under 1 kB."""
    items = ['&x0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]'] + [
        f"&x{k} [" + ",".join([f"*x{k - 1}"] * 9) + "]" for k in range(1, levels)
    ]
    return f"{prefix} [{', '.join(items)}]\n"


def test_a_huge_twist_and_a_far_marker_pose_are_refused(node, library):
    """Rows 'one Twist of 1e300' and 'marker feedback with a pose at 1e30': refused with one
    line; the object stays put, accept and save write a sane pose."""
    obj = fit_fresh_click(node, library, 2)
    T0 = np.asarray(obj["candidates"][0]["pose"])
    huge = Twist()
    huge.linear.x = 1e300
    node["pubs"]["twist"].publish(huge)
    wait_error(node, "ignored a twist of")
    far = T0.copy()
    far[:3, 3] = [1e30, 0.0, 0.0]
    for event in (
        InteractiveMarkerFeedback.MOUSE_DOWN,
        InteractiveMarkerFeedback.POSE_UPDATE,
        InteractiveMarkerFeedback.MOUSE_UP,
    ):
        fb = InteractiveMarkerFeedback(
            client_id="/fuzzer",
            marker_name="affordance_fit",
            event_type=event,
            pose=matrix_to_pose(far),
        )
        fb.header.frame_id = FRAME
        node["pubs"]["feedback"].publish(fb)
    wait_error(node, "from where it was clicked")
    assert node["client"].call(Trigger, f"{NS}/accept").success
    saved = node["client"].call(Trigger, f"{NS}/save")
    assert saved.success
    doc = yaml.safe_load((node["tmp"] / "registrations.yaml").read_text())
    reg = doc["registrations"][-1]
    assert np.allclose(reg["pose"], T0, atol=1e-6), reg["pose"]


def test_another_node_of_the_same_name_is_reported(node, tmp_path):
    """Row 'two nodes started with the same name': the newcomer says so."""
    twin = engine_process(tmp_path, name="twin")
    try:
        assert twin.wait_output("another node named /affordance_engine is running", 60), (
            twin.output()[-2000:]
        )
    finally:
        twin.interrupt()
        twin.kill()


# ---------------------------------------------------------------------------- the command line
def test_fit_refuses_unreadable_arrays_and_oversized_files_in_one_line(tmp_path):
    """Rows '.npy of strings or a structured dtype', 'a PLY whose header claims 1e9 vertices
    and holds one' (under a 2 GB limit, within 30 s) and 'a PLY holding nan'."""
    np.save(tmp_path / "text.npy", np.full((2, 2, 3), "a"))
    np.save(tmp_path / "rec.npy", np.zeros((2, 2), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]))
    (tmp_path / "liar.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\nproperty float x\n"
        b"property float y\nproperty float z\nend_header\n" + np.zeros(3, "<f4").tobytes()
    )
    (tmp_path / "nan.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n0 0 1\nnot-a-number 0 1\n0 1 1\n"
    )
    cases = (
        ("text.npy", "expected numbers"),
        ("rec.npy", "expected numbers"),
        ("liar.ply", "1,000,000,000 points"),
        ("nan.ply", "does not hold x, y, z as numbers"),
    )
    results = run_cli_all(
        *(("fit", "--scene", str(tmp_path / name), "--point", "0", "0", "1") for name, _ in cases)
    )
    for (name, expected), (code, err, _) in zip(cases, results):
        line = one_line(code, err)
        assert name in line and expected in line, line


def _binary_ply(count: int, pts: np.ndarray, props=("x", "y", "z"), element="") -> bytes:
    head = "".join(
        f"property float {p}\n" if p != "list" else "property list uchar int z\n" for p in props
    )
    return (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {count}{element}\n{head}"
        f"end_header\n"
    ).encode() + pts.astype("<f4").tobytes()


def _binary_pcd(
    points: int, pts: np.ndarray, width=None, height=1, types="F F F", sizes="4 4 4"
) -> bytes:
    width = points if width is None else width
    return (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE {sizes}\nTYPE {types}\n"
        f"COUNT 1 1 1\nWIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {points}\nDATA binary\n"
    ).encode() + pts.astype("<f4").tobytes()


def test_point_file_headers_that_do_not_match_their_data_are_one_line(tmp_path):
    """A PLY or PCD whose header does not describe its data -- more or fewer points than it
    holds, WIDTH x HEIGHT not its POINTS, a type that is not one, no z, a list property on the
    vertices, a malformed element line, a compressed payload whose sizes disagree with the
    header (Open3D read past its buffer there: a segfault) -- is refused in one line before
    any reader touches it; nothing is read short or padded with garbage."""
    pts = np.random.default_rng(0).uniform(-1, 1, (1000, 3))
    files = {
        "fewer.ply": _binary_ply(900, pts),
        "more.ply": _binary_ply(1100, pts),
        "element.ply": _binary_ply(1000, pts, element=" 7"),
        "noz.ply": _binary_ply(1000, pts, props=("x", "y", "w")),
        "list.ply": _binary_ply(1000, pts, props=("x", "y", "list")),
        "fewer.pcd": _binary_pcd(900, pts),
        "grid.pcd": _binary_pcd(1000, pts, 100, 7),
        "type.pcd": _binary_pcd(1000, pts, types="Q Q Q"),
        "size.pcd": _binary_pcd(1000, pts, sizes="3 3 3"),
        "extra.ply": b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n"
        b"property float y\nproperty float z\nend_header\n0 0 1\n0 1 1\n1 1 1\n",
    }
    cases = [
        ("fewer.ply", "does not match the data"),
        ("more.ply", "only 12,000 bytes"),
        ("element.ply", "bad element line"),
        ("noz.ply", "no x, y, z"),
        ("list.ply", "a list property"),
        ("fewer.pcd", "does not match the data"),
        ("grid.pcd", "WIDTH 100 x HEIGHT 7"),
        ("type.pcd", "not a PCD type"),
        ("size.pcd", "not a PCD type"),
        ("extra.ply", "announces 2 rows of data"),
    ]
    from affordance_registration.evaluation.realdata import shared_data_dir

    milk = os.path.join(shared_data_dir() or "", "pcl", "milk.pcd")
    if os.path.isfile(milk):  # binary_compressed (the shared data): the segfault
        data = open(milk, "rb").read()
        files["packed.pcd"] = data.replace(b"POINTS 13704", b"POINTS 100000", 1).replace(
            b"WIDTH 13704", b"WIDTH 100000", 1
        )
        cases.append(("packed.pcd", "unpacks to 164,448 bytes"))
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    results = run_cli_all(
        *(("fit", "--scene", str(tmp_path / name), "--point", "0", "0", "1") for name, _ in cases)
    )
    for (name, expected), (code, err, _) in zip(cases, results):
        line = one_line(code, err)
        assert name in line and expected in line, line


def _lzf_zeros(size: int) -> bytes:
    """An LZF stream (liblzf's format, as PCD's binary_compressed holds) that unpacks to
    ``size`` zero bytes: a literal zero or three, then back references of 264 bytes at
    distance 1, three bytes each (about 88:1)."""
    literal = next(n for n in (1, 2, 3) if (size - n) % 264 not in (1, 2))
    rest, last = divmod(size - literal, 264)
    out = bytearray([literal - 1]) + bytes(literal) + b"\xe0\xff\x00" * rest
    if last:
        out += bytes([(last - 2) << 5, 0]) if last - 2 < 7 else bytes([0xE0, last - 9, 0])
    return bytes(out)


def test_a_binary_compressed_pcd_bomb_is_refused_in_one_line(tmp_path):
    """A binary_compressed PCD within the point limit whose LZF data unpacks to over 1 GB
    (9 million points of 112 bytes: an 11 MB file; one of 48.6 MB took 4.65 GB and 75 s):
    refused in one line from its header, before anything is unpacked."""
    from affordance_registration.core.pointfiles import MAX_POINTS, MAX_UNPACKED_BYTES

    points = 9_000_000
    point_bytes = 3 * 4 + 100
    assert points <= MAX_POINTS and points * point_bytes > MAX_UNPACKED_BYTES
    packed = _lzf_zeros(points * point_bytes)
    header = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z _\nSIZE 4 4 4 1\nTYPE F F F U\n"
        f"COUNT 1 1 1 100\nWIDTH {points}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {points}\nDATA binary_compressed\n"
    ).encode()
    sizes = np.array([len(packed), points * point_bytes], dtype="<u4").tobytes()
    (tmp_path / "bomb.pcd").write_bytes(header + sizes + packed)
    assert (tmp_path / "bomb.pcd").stat().st_size < 12_000_000
    ((code, err, _),) = run_cli_all(
        ("fit", "--scene", str(tmp_path / "bomb.pcd"), "--point", "0", "0", "1"), timeout=300
    )
    line = one_line(code, err)
    assert "bomb.pcd" in line and f"more than the {MAX_UNPACKED_BYTES:,}" in line, line


@settings(max_examples=25, deadline=None)
@given(count=st.integers(0, 5000), kind=st.sampled_from(["ply", "pcd"]))
def test_any_point_count_but_the_true_one_is_refused(tmp_path_factory, count, kind):
    """A binary cloud of 1000 points whose header announces ``count``: read whole when it is
    1000, else refused with one line naming the file -- never read short or past its end."""
    from affordance_registration.core.errors import SceneError
    from affordance_registration.core.pointfiles import read_points

    pts = np.random.default_rng(1).uniform(-1, 1, (1000, 3))
    path = tmp_path_factory.mktemp("count") / f"c.{kind}"
    path.write_bytes(_binary_ply(count, pts) if kind == "ply" else _binary_pcd(count, pts))
    if count == 1000:
        np.testing.assert_allclose(read_points(str(path)).points, pts, atol=1e-6)
        return
    with pytest.raises(SceneError) as err:
        read_points(str(path))
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_files_that_are_not_regular_files_and_paths_that_are_one_file_are_one_line(tmp_path):
    """A FIFO where a settings, template or launch file is read (each blocked its reader for
    good), /dev/null as a settings file, a FIFO where a session writes its truth; an empty
    --out (it wrote into the current folder); two outputs of one save that are one file (a
    symbolic link from one to the other: the scene was lost under the truth; a link is never
    followed now); a folder where
    one template of the library is written (the ones before it were written): one line each,
    exit 2, nothing written."""
    for name in ("settings.yaml", "launch.yaml"):
        os.mkfifo(tmp_path / name)
    lib = tmp_path / "lib"
    shutil.copytree(MODELS, lib)
    os.mkfifo(lib / "zz.yaml")
    session = tmp_path / "session"
    session.mkdir()
    os.mkfifo(session / "truth.yaml")
    linked = tmp_path / "linked"
    linked.mkdir()
    os.symlink("truth.yaml", linked / "scene.ply")
    models = tmp_path / "models"
    (models / "quarter_turn_valve.yaml").mkdir(parents=True)
    cloud = tmp_path / "cloud.ply"
    cloud.write_bytes(_binary_ply(1000, np.random.default_rng(2).uniform(-1, 1, (1000, 3))))
    deep = tmp_path / "deep.yaml"
    deep.write_text("coarse: " + "[" * 2000 + "]" * 2000 + "\n")
    far = tmp_path / "far.yaml"
    far.write_text("viewpoint: {min_distance: 2000}\n")
    # a recorded session to replay whose truth is a FIFO (the replay blocked) or not a truth
    # (a KeyError); the bag is never reached
    replays = {}
    for name in ("fifo_truth", "bad_truth"):
        replays[name] = tmp_path / name
        replays[name].mkdir()
    os.mkfifo(replays["fifo_truth"] / "truth.yaml")
    (replays["bad_truth"] / "truth.yaml").write_text("objects: [{T_scene_model: [1, 2]}]\n")
    # two symbolic links to each other as the scan: it read "no such file"
    os.symlink("loop_b.ply", tmp_path / "loop_a.ply")
    os.symlink("loop_a.ply", tmp_path / "loop_b.ply")
    cases = [
        (
            ("fit", "--scene", str(tmp_path / "loop_a.ply"), "--point", "0", "0", "1"),
            "loop_a.ply: too many levels of symbolic links",
        ),
        (
            ("demo", "--session", str(replays["fifo_truth"]), "--out", str(tmp_path / "d1")),
            "not a regular file (a FIFO)",
        ),
        (
            ("demo", "--session", str(replays["bad_truth"]), "--out", str(tmp_path / "d2")),
            "not a truth file",
        ),
        (("settings", str(tmp_path / "settings.yaml")), "not a regular file"),
        (("settings", "/dev/null"), "not a regular file"),
        (
            ("simulate", "--out", str(tmp_path / "o1"), "--templates", str(lib)),
            "not a regular file",
        ),
        (("launch", str(tmp_path / "launch.yaml")), "not a regular file"),
        (("session", "--out", str(session)), "not a regular file"),
        (("simulate", "--out", ""), "is not a path"),
        (("simulate", "--out", str(linked)), "is a symbolic link: not followed"),
        (("generate-models", "--out", str(models)), "is a folder"),
        # and options: a sensor 1e300 m away (numpy's overflow warnings made it three
        # lines), settings nested 2000 deep, two exclusive views of the settings
        (
            (
                "fit",
                "--scene",
                str(cloud),
                "--point",
                "0",
                "0",
                "1",
                "--sensor-origin",
                "1e300",
                "0",
                "0",
            ),
            "more than 1e+09 m",
        ),
        (("settings", str(deep)), "nested too deeply"),
        (("settings", "--node-params", "--markdown"), "not allowed with"),
        # a click 1e308 m away (a line of 1070 characters with a 300-digit number), views
        # suggested from 2 km (out of memory; 1e12 m: an internal OverflowError)
        (
            ("fit", "--scene", str(cloud), "--point", "1e308", "0", "1"),
            "the click (1e+308, 0, 1) lies more than 1e+09 m",
        ),
        (
            ("settings", str(far)),
            "viewpoint.min_distance must be a positive number in [0.05, 50.0], got 2000",
        ),
    ]
    results = run_cli_all(*(args for args, _ in cases), timeout=60)
    for (args, expected), (code, err, _) in zip(cases, results):
        line = one_line(code, err)
        assert expected in line, (args, line)
    assert not (tmp_path / "o1").exists() and os.listdir(linked) == ["scene.ply"]
    assert os.path.islink(linked / "scene.ply") and sorted(os.listdir(models)) == [
        "quarter_turn_valve.yaml"
    ]
    assert os.listdir(session) == ["truth.yaml"]


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_huge_numbers_strings_newlines_and_odd_options_are_one_line(tmp_path):
    """From a second probe: integers of hundreds or thousands of digits in a settings or
    template file (an OverflowError, a ValueError: internal errors), a range written as text
    ("19" read as [1, 9]), an axis of 1e200 (numpy's warnings, then a LinAlgError), a mesh
    scale of 1e-10, a knob name holding a newline (two lines), a settings file of megabytes
    (a minute to refuse, a 9 MB line), a bag rate of 1e-300 (a play that never ends), a node
    whose 'pkg' is a number, --shm with --fastdds-profile, and a closed stdout: one line, exit
    2, each."""
    big = "1" * 400
    files = {
        "big.yaml": f"scoring: {{cap: {big}}}\n",
        "huge.yaml": f"seed: {'9' * 5000}\n",
        "newline.yaml": 'coarse: {"sam\\nples": 3}\n',
        "megabytes.yaml": "# " + "x" * 1_100_000 + "\n",
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    handle = "name: h\nmesh: meshes/grab_handle.stl\n"
    libs = {
        "text_scale": handle + 'scale: "19"\n',
        "big_scale": handle + f"mesh_scale: {big}\n",
        "tiny_scale": handle.replace("stl\n", "stl\nmesh_scale: 1.0e-10\n"),
        "axis": handle + "symmetry: {axis: [1.0e+200, 0, 0], order: 2}\n",
        "box_text": 'name: b\nprimitive: box\nsize: {x: "59", y: [0.1, 0.2], z: [0.1, 0.2]}\n',
    }
    for name, text in libs.items():
        _library(tmp_path, name, text)
    (tmp_path / "pkg.launch.yaml").write_text("launch:\n- node: {pkg: 5, exec: x}\n")
    cases = [
        (("settings", str(tmp_path / "big.yaml")), "must be a positive number"),
        (("settings", str(tmp_path / "huge.yaml")), "not YAML this reads"),
        (("settings", str(tmp_path / "newline.yaml")), "sam\\nples"),
        (("settings", str(tmp_path / "megabytes.yaml")), "larger than 1000 kB"),
        (("bag", "play", str(tmp_path), "--rate", "1e-300"), "must be in [0.001, 1000]"),
        (("launch", str(tmp_path / "pkg.launch.yaml")), "'pkg' must be text"),
        (
            ("launch", str(tmp_path / "pkg.launch.yaml"), "--shm", "--fastdds-profile", "x"),
            "not allowed with",
        ),
        # a seed no node parameter holds (the nodes started, then failed), checked before
        # --out is made
        (
            (
                "station",
                "--demo",
                "--seed",
                "9" * 23,
                "--port",
                str(_free_port()),
                "--out",
                str(tmp_path / "station"),
            ),
            "--seed must be an integer in",
        ),
    ]
    cases += [
        (
            (
                "simulate",
                "--out",
                str(tmp_path / f"o_{name}"),
                "--templates",
                str(tmp_path / name),
            ),
            expected,
        )
        for name, expected in (
            ("text_scale", "expected [min, max]"),
            ("big_scale", "too large for a float"),
            ("tiny_scale", "expected a number in"),
            ("axis", "within +-1e+06"),
            ("box_text", "expected [min, max] in metres"),
        )
    ]
    results = run_cli_all(*(args for args, _ in cases), timeout=60)
    for (args, expected), (code, err, _) in zip(cases, results):
        line = one_line(code, err)
        assert expected in line, (args, line)
    assert not (tmp_path / "station").exists()
    closed = subprocess.run(
        ["sh", "-c", f"{sys.executable} -m affordance_registration.cli settings >&-"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert "standard output is closed" in one_line(closed.returncode, closed.stderr)


def _library(tmp_path, name, text):
    lib = tmp_path / name
    lib.mkdir()
    shutil.copytree(os.path.join(MODELS, "meshes"), lib / "meshes")
    (lib / "t.yaml").write_bytes(text if isinstance(text, bytes) else text.encode())
    return lib


def test_bad_template_files_are_one_line(tmp_path):
    """Rows 'a library with joint limits +-1e300 or non-UTF-8 bytes', 'symmetry: {order:
    1000000000}' (answered at once) and 'mesh: ../../elsewhere/x.stl or an absolute path'."""
    base = (
        "name: v\nmesh: meshes/ball_valve.stl\nbase_mesh: meshes/ball_valve_base.stl\n"
        "joints:\n- {name: lever, type: revolute, axis: [0, 0, 1], lower: -1e300, "
        "upper: 1e300, moving_mesh: meshes/ball_valve_lever.stl}\n"
    )
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    shutil.copy(os.path.join(MODELS, "meshes", "grab_handle.stl"), outside / "x.stl")
    cases = [
        ("limits", base, "limits beyond"),
        ("bytes", b"name: v\xff\nmesh: meshes/ball_valve.stl\n", "not UTF-8"),
        (
            "order",
            "name: v\nmesh: meshes/ball_valve.stl\nsymmetry: {order: 1000000000}\n",
            "continuous: true",
        ),
        ("relative", "name: v\nmesh: ../elsewhere/x.stl\n", "outside the template's folder"),
        ("absolute", f"name: v\nmesh: {outside / 'x.stl'}\n", "outside the template's folder"),
    ]
    libs = [_library(tmp_path, name, text) for name, text, _ in cases]
    results = run_cli_all(
        *(
            ("simulate", "--out", str(tmp_path / f"out_{name}"), "--templates", str(lib))
            for (name, _, _), lib in zip(cases, libs)
        )
    )
    for (name, _, expected), (code, err, seconds) in zip(cases, results):
        line = one_line(code, err)
        assert "t.yaml" in line and expected in line, line
        assert seconds < 30
        assert not (tmp_path / f"out_{name}").exists()
    # the YAML may opt out of the folder rule explicitly
    lib = _library(
        tmp_path, "opted", f"name: v\nmesh: {outside / 'x.stl'}\nallow_external_files: true\n"
    )
    from affordance_registration.core.templates import TemplateLibrary

    assert TemplateLibrary.load(str(lib))["v"].diameter > 0.05


def test_alias_bombs_in_every_yaml_the_product_reads_are_one_line(tmp_path):
    """A "billion laughs" (under 1 kB, billions of nodes expanded) in a settings file (as the
    455-byte one whose seed ran 30 s at 1 GB), a template, a launch file, a parameter file a
    launch file names, a bag's metadata.yaml, a registrations file: refused in one line before
    anything is built (the one loader, core/files.read_yaml), within a 2 GB memory limit; a
    merge of a few shared keys still reads."""
    from affordance_registration.core.errors import AffordanceError
    from affordance_registration.core.files import MAX_ALIAS_NODES, read_yaml
    from affordance_registration.core.persistence import load_registrations

    (tmp_path / "settings.yaml").write_text(alias_bomb("seed:"))
    assert len((tmp_path / "settings.yaml").read_bytes()) < 1000
    lib = _library(tmp_path, "lib", alias_bomb("name: v\nmesh: meshes/ball_valve.stl\nscale:"))
    (tmp_path / "bomb.launch.yaml").write_text(alias_bomb("launch:"))
    (tmp_path / "params.yaml").write_text(alias_bomb("affordance_engine:"))
    (tmp_path / "params.launch.yaml").write_text(
        "launch:\n- node:\n    pkg: affordance_registration\n    exec: affordance_engine\n"
        f"    param:\n    - from: {tmp_path / 'params.yaml'}\n"
    )
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text(alias_bomb("rosbag2_bagfile_information:"))
    cases = [
        (("settings", str(tmp_path / "settings.yaml")), "settings.yaml"),
        (("simulate", "--out", str(tmp_path / "out"), "--templates", str(lib)), "t.yaml"),
        (("launch", str(tmp_path / "bomb.launch.yaml")), "bomb.launch.yaml"),
        (("launch", str(tmp_path / "params.launch.yaml")), "params.yaml"),
        (("bag", "info", str(bag)), "metadata.yaml"),
    ]
    results = run_cli_all(*(args for args, _ in cases), timeout=120)
    for (args, where), (code, err, _) in zip(cases, results):
        line = one_line(code, err)
        assert where in line and "aliases would add" in line, (args, line)
    (tmp_path / "registrations.yaml").write_text(alias_bomb("registrations:"))
    with pytest.raises(AffordanceError, match="aliases would add"):
        load_registrations(str(tmp_path / "registrations.yaml"))
    # a few merged keys are well within the bound; a cycle is refused
    (tmp_path / "merge.yaml").write_text("base: &b {x: 1}\nuse: {<<: *b, y: 2}\n")
    assert read_yaml(str(tmp_path / "merge.yaml"), AffordanceError)["use"] == {"x": 1, "y": 2}
    (tmp_path / "wide.yaml").write_text(
        "a: &a [" + ",".join(["1"] * MAX_ALIAS_NODES) + "]\nb: *a\nc: *a\n"
    )
    with pytest.raises(AffordanceError, match=f"{2 * MAX_ALIAS_NODES + 2:,} nodes"):
        read_yaml(str(tmp_path / "wide.yaml"), AffordanceError)
    (tmp_path / "cycle.yaml").write_text("a: &a [1, *a]\n")
    with pytest.raises(AffordanceError, match="cycle"):
        read_yaml(str(tmp_path / "cycle.yaml"), AffordanceError)


def test_bad_launch_files_are_one_line(tmp_path):
    """Rows 'launch with a param entry - 5, - arg: 5 or non-UTF-8 bytes' and 'an arg default
    $(env X) where X contains $(env X) (or a $(var) self-reference)': one line, no hang."""
    node = "- node: {pkg: affordance_registration, exec: affordance_engine, param: [5]}\n"
    cases = {
        "param": "launch:\n" + node,
        "arg": "launch:\n- arg: 5\n",
        "bytes": b"launch:\n- arg: {name: \xff}\n",
        "self_var": "launch:\n- arg: {name: a, default: $(var a)}\n",
        "env": "launch:\n- arg: {name: a, default: $(env AR_LOOP)}\n"
        "- node: {pkg: affordance_registration, exec: affordance_engine, "
        "namespace: $(var a)}\n",
    }
    env = dict(os.environ, AR_LOOP="$(env AR_LOOP)")
    for name, text in cases.items():
        f = tmp_path / f"{name}.launch.yaml"
        f.write_bytes(text if isinstance(text, bytes) else text.encode())
        if name == "env":  # resolved once: the node gets the text literally
            from affordance_registration.ros.standins.launcher import parse_launch_file

            os.environ["AR_LOOP"] = "$(env AR_LOOP)"
            try:
                (action,) = parse_launch_file(str(f))
            finally:
                del os.environ["AR_LOOP"]
            assert action.namespace == "$(env AR_LOOP)"
            continue
        res = subprocess.run(
            [sys.executable, "-m", "affordance_registration.cli", "launch", str(f)],
            capture_output=True,
            text=True,
            timeout=30,
            env=env,
        )
        line = one_line(res.returncode, res.stderr)
        assert f.name in line, line


def test_the_spacemouse_fifo_skips_lines_that_are_not_commands(tmp_path):
    """Row 'the SpaceMouse fifo: backend fed the JSON line 5': the reader keeps going."""
    from affordance_registration.ros.devices.spacemouse import FifoBackend

    fifo = tmp_path / "hid"
    os.mkfifo(fifo)
    backend = FifoBackend(str(fifo))
    with open(fifo, "w") as handle:
        handle.write('5\n"text"\n[1, 2]\n{"plug": 7}\n{"report": "x"}\nnot json\n')
        handle.write(
            json.dumps({"plug": {"path": "fake0", "vendor_id": 9583, "product_id": 50741}}) + "\n"
        )
    deadline = time.monotonic() + 30
    while not backend.enumerate() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert [d["path"] for d in backend.enumerate()] == [b"fake0"]


# ---------------------------------------------------------------------------- saving
def _registrations():
    from affordance_registration.core.engine import Registration

    T = np.eye(4)
    T[:3, 3] = [0.1, 0.2, 0.9]
    return [
        Registration(
            id=1,
            template="ball_valve",
            T_scene_model=T,
            likelihood=1.0,
            probability=0.5,
            residual=0.002,
            click=T[:3, 3],
        )
    ]


def test_saving_never_replaces_what_is_not_a_regular_file(tmp_path):
    """Row 'registrations_file pointing at a character device, as root': refused, the device
    intact; likewise a FIFO (without blocking on it) and a folder."""
    from affordance_registration.core.engine import save_registrations
    from affordance_registration.core.errors import AffordanceError

    targets = {"fifo": tmp_path / "fifo", "folder": tmp_path / "folder"}
    os.mkfifo(targets["fifo"])
    targets["folder"].mkdir()
    if os.geteuid() == 0:  # a character device like /dev/null, made here
        targets["device"] = tmp_path / "null"
        os.mknod(targets["device"], 0o600 | stat.S_IFCHR, os.makedev(1, 3))
    for kind, path in targets.items():
        before = os.lstat(path)
        with pytest.raises(AffordanceError, match="not a regular file|is a folder"):
            save_registrations(str(path), _registrations())
        after = os.lstat(path)
        assert (after.st_mode, after.st_ino, after.st_rdev) == (
            before.st_mode,
            before.st_ino,
            before.st_rdev,
        ), kind
    assert sorted(os.listdir(tmp_path)) == sorted(p.name for p in targets.values())
    # a link to a regular file is never followed: refused, the link and its file as they were
    real = tmp_path / "real.yaml"
    real.write_text("old")
    (tmp_path / "link.yaml").symlink_to(real)
    with pytest.raises(AffordanceError, match="symbolic link"):
        save_registrations(str(tmp_path / "link.yaml"), _registrations())
    assert (tmp_path / "link.yaml").is_symlink() and real.read_text() == "old"


def test_saving_keeps_a_files_mode_and_honours_the_umask(tmp_path):
    """Row 'a successful ~/save': mode 0600 whatever the umask -- now a new file gets the umask
    and an existing one keeps its mode."""
    from affordance_registration.core.engine import save_registrations

    old = os.umask(0o022)
    try:
        save_registrations(str(tmp_path / "new.yaml"), _registrations())
        assert stat.S_IMODE(os.stat(tmp_path / "new.yaml").st_mode) == 0o644
        os.umask(0o077)
        kept = tmp_path / "kept.yaml"
        kept.write_text("x")
        os.chmod(kept, 0o640)
        save_registrations(str(kept), _registrations())
        assert stat.S_IMODE(os.stat(kept).st_mode) == 0o640
    finally:
        os.umask(old)


def test_a_save_killed_midway_leaves_nothing_the_next_save_does_not_clean(tmp_path):
    """Row 'SIGKILL during ~/save': the process is killed while it writes a large file; the
    old file is intact, and the next save removes the dead process's temporary file."""
    import signal

    from affordance_registration.core.engine import save_registrations

    target = tmp_path / "registrations.yaml"
    save_registrations(str(target), _registrations())
    before = target.read_bytes()
    # the writer stops for good right before its rename (its fsync never returns): a kill then
    # is a kill in the middle of a save, whatever the machine's speed
    writer = subprocess.Popen(
        [
            sys.executable,
            "-c",
            (
                "import os, sys, time\nos.fsync = lambda fd: time.sleep(3600)\n"
                "from affordance_registration.core.files import write_atomically\n"
                "write_atomically({sys.argv[1]: b'x' * 2**20})"
            ),
            str(target),
        ]
    )
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not [
            p
            for p in os.listdir(tmp_path)
            if ".tmp-" in p and os.path.getsize(tmp_path / p) == 2**20
        ]:
            time.sleep(0.01)
        writer.send_signal(signal.SIGKILL)
    finally:
        writer.wait()
    leftovers = [p for p in os.listdir(tmp_path) if ".tmp-" in p]
    assert leftovers and target.read_bytes() == before
    save_registrations(str(target), _registrations())
    assert sorted(os.listdir(tmp_path)) == ["registrations.yaml"]
