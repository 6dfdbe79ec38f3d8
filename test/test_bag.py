# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""rosbag2 bags (record / play / info) and the replay of the bundled operator session into a live
engine node -- the regression test of a real recorded bag."""

import math
import os
import shutil
import subprocess
import sys
import threading
import time

import pytest
import yaml
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from affordance_registration.ros.standins import bag as bag_module
from affordance_registration.ros.standins.bag import (
    BagError,
    Player,
    Recorder,
    StatusPacer,
    bag_info,
)

SESSION = os.path.join(os.path.dirname(__file__), "data", "session")


@pytest.fixture
def node(ros_context):
    import rclpy

    n = rclpy.create_node("bag_tester")
    ex = SingleThreadedExecutor()
    ex.add_node(n)
    stop = threading.Event()
    t = threading.Thread(
        target=lambda: [ex.spin_once(timeout_sec=0.02) for _ in iter(stop.is_set, True)],
        daemon=True,
    )
    t.start()
    yield n
    stop.set()
    t.join(timeout=2)
    n.destroy_node()


def _wait(pred, timeout=60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.02)
    return False


def test_record_info_play_keeps_timing_and_latching(node, tmp_path):
    latched = QoSProfile(
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    pub_a = node.create_publisher(String, "/bagtest/a", 10)
    pub_l = node.create_publisher(String, "/bagtest/latched", latched)
    out = str(tmp_path / "bag")
    rec = Recorder(node, out, ["/bagtest/a", "/bagtest/latched"])
    assert _wait(lambda: len(rec.connections) == 2)
    assert _wait(
        lambda: pub_a.get_subscription_count() >= 1 and pub_l.get_subscription_count() >= 1
    )
    pub_l.publish(String(data="config"))
    for k in range(5):
        pub_a.publish(String(data=f"m{k}"))
        time.sleep(0.1)
    assert _wait(lambda: rec.counts["/bagtest/a"] == 5)
    rec.close()
    # the original publishers go: the late subscriber below must hear the player's latched
    # message, not the original one (it would get both, in either order)
    node.destroy_publisher(pub_a)
    node.destroy_publisher(pub_l)

    info = bag_info(out)
    counts = {t["topic"]: (t["type"], t["count"]) for t in info["topics"]}
    assert counts == {
        "/bagtest/a": ("std_msgs/msg/String", 5),
        "/bagtest/latched": ("std_msgs/msg/String", 1),
    }
    assert 0.35 < info["duration_s"] < 6.0  # published 0.1 s apart (a loaded machine
    #                                                 may stamp them later, never earlier)
    meta = yaml.safe_load(open(os.path.join(out, "metadata.yaml")))["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    topics = {
        t["topic_metadata"]["name"]: t["topic_metadata"] for t in meta["topics_with_message_count"]
    }
    assert topics["/bagtest/a"]["type_description_hash"].startswith("RIHS01_")
    assert topics["/bagtest/latched"]["offered_qos_profiles"][0]["durability"] == "transient_local"

    # play at half the speed; the latched topic stays latched for a late subscriber
    player = Player(node, out, rate=0.5)
    got, stamps = [], []
    node.create_subscription(
        String, "/bagtest/a", lambda m: (got.append(m.data), stamps.append(time.monotonic())), 10
    )
    assert _wait(lambda: player.publishers["/bagtest/a"].get_subscription_count() >= 1)
    t0 = time.monotonic()
    assert player.play() == 6
    assert _wait(lambda: len(got) == 5)
    assert got == [f"m{k}" for k in range(5)]
    # played at 0.5x, each message arrives no earlier than twice its time after the bag's
    # start (the player sleeps until it is due; a loaded machine may deliver any of them
    # later -- the first one late makes the span between them shorter -- so no arrival is held
    # to an upper bound but a loose one)
    from rosbags.rosbag2 import Reader

    with Reader(out) as reader:
        start = min(stamp for _, stamp, _ in reader.messages())
        conns = [c for c in reader.connections if c.topic == "/bagtest/a"]
        recorded = [stamp for _, stamp, _ in reader.messages(connections=conns)]
    assert (recorded[-1] - recorded[0]) / 1e9 > 0.35
    for k, (arrived, stamp) in enumerate(zip(stamps, recorded)):
        assert arrived - t0 >= 2 * (stamp - start) / 1e9 - 0.02, (k, arrived - t0, stamp - start)
    assert stamps[-1] - stamps[0] < 10.0
    late = []
    node.create_subscription(String, "/bagtest/latched", lambda m: late.append(m.data), latched)
    assert _wait(lambda: late == ["config"])
    assert time.monotonic() - t0 < 30


def test_truncated_and_corrupt_bags_give_clear_errors(tmp_path):
    src = os.path.join(SESSION, "bag")
    broken = tmp_path / "truncated"
    shutil.copytree(src, broken)
    mcap = broken / "bag.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 3])
    with pytest.raises(BagError, match="truncated|corrupt|not a readable"):
        bag_info(str(broken))
        # some truncations only show when the messages are read
        from affordance_registration.ros.standins.bag import read_messages

        for topic in ("/points", "/clicked_point", "/affordance_engine/status"):
            list(read_messages(str(broken), topic))
    garbage = tmp_path / "garbage"
    garbage.mkdir()
    (garbage / "metadata.yaml").write_text("rosbag2_bagfile_information: [not, a, bag]\n")
    with pytest.raises(BagError, match="not a readable rosbag2 bag"):
        bag_info(str(garbage))
    with pytest.raises(BagError, match="no such bag"):
        bag_info(str(tmp_path / "missing"))
    out = subprocess.run(
        [sys.executable, "-m", "affordance_registration.cli", "bag", "info", str(garbage)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and "garbage" in out.stderr


def _cli(*argv_lists, timeout=60):
    """Run ``affordance-registration ARGV`` for each argv at once; (exit code, stdout, stderr)
    of each, the exit code None for one still running after ``timeout`` s (then killed: a
    regression that hangs fails instead of hanging the suite)."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "affordance_registration.cli", *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for argv in argv_lists
    ]
    deadline, results = time.monotonic() + timeout, []
    for proc in procs:
        try:
            out, err = proc.communicate(timeout=max(0.1, deadline - time.monotonic()))
            results.append((proc.returncode, out, err))
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
            results.append((None, out, err))
    return results


def _one_line_error(result, *words):
    """Exit 2 and exactly one line on stderr, naming each of ``words`` (no traceback, no
    internal error)."""
    code, out, err = result
    assert code == 2, (code, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err and "internal error" not in err, err
    for word in words:
        assert word in lines[0], (word, lines[0])
    return lines[0]


def test_a_fifo_or_device_in_a_bag_is_refused_not_read(tmp_path):
    """A bag whose metadata.yaml or storage file is a FIFO (or a device, or a folder), or a bag
    file that is a FIFO: one line naming it, exit 2 -- reading it would block for ever."""
    src = os.path.join(SESSION, "bag")
    fifo_meta = tmp_path / "fifo_meta"
    fifo_meta.mkdir()
    os.mkfifo(fifo_meta / "metadata.yaml")
    shutil.copy(os.path.join(src, "bag.mcap"), fifo_meta)
    fifo_mcap = tmp_path / "fifo_mcap"
    fifo_mcap.mkdir()
    shutil.copy(os.path.join(src, "metadata.yaml"), fifo_mcap)
    os.mkfifo(fifo_mcap / "bag.mcap")
    device = tmp_path / "device"
    device.mkdir()
    shutil.copy(os.path.join(src, "metadata.yaml"), device)
    os.symlink("/dev/zero", device / "bag.mcap")
    folder = tmp_path / "folder"
    folder.mkdir()
    (folder / "metadata.yaml").mkdir()
    fifo_file = tmp_path / "fifo.mcap"
    os.mkfifo(fifo_file)
    cases = [
        (fifo_meta, fifo_meta / "metadata.yaml", "FIFO"),
        (fifo_mcap, fifo_mcap / "bag.mcap", "FIFO"),
        (device, device / "bag.mcap", "device"),
        (folder, folder / "metadata.yaml", "folder"),
        (fifo_file, fifo_file, "FIFO"),
    ]
    commands = ("info", "play")
    results = iter(
        _cli(*[["bag", command, str(bag)] for bag, _, _ in cases for command in commands])
    )
    for bag, path, kind in cases:
        for command in commands:
            result = next(results)
            assert result[0] is not None, f"bag {command} {bag.name}: still running after 60 s"
            _one_line_error(result, str(path), kind, "not a regular file")
    with pytest.raises(BagError, match="not a regular file"):
        bag_info(str(fifo_mcap))


#: the numeric options of `bag record` / `bag play`, and whether 0 is refused too
NUMBERS = [
    ("record", "--duration", True),
    ("play", "--rate", True),
    ("play", "--start-offset", False),
    ("play", "--wait-for-subscribers", False),
    ("play", "--pace-timeout", True),
]


def _bag_argv(command, option, value, out):
    if command == "record":
        return ["bag", "record", str(out), "/bagtest/numbers", option, value]
    return ["bag", "play", os.path.join(SESSION, "bag"), "--paced", option, value]


@settings(
    max_examples=8,
    deadline=None,
    phases=(Phase.explicit, Phase.reuse, Phase.generate),
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    which=st.sampled_from(NUMBERS),
    value=st.one_of(
        st.sampled_from([math.nan, math.inf, -math.inf]),
        st.floats(max_value=-1e-6, allow_nan=False, allow_infinity=False),
        st.just(0.0),
    ),
)
@example(which=NUMBERS[4], value=math.nan)  # it waited for ever
@example(which=NUMBERS[2], value=math.nan)  # it blamed the bag
@example(which=NUMBERS[0], value=-1.0)  # it was accepted
@example(which=NUMBERS[3], value=math.nan)  # it was accepted
def test_bad_numeric_options_give_one_line(tmp_path, which, value):
    """nan, inf or a negative number (or 0 where 0 makes no sense) for any numeric option of
    `bag record` / `bag play`: one line naming the option, exit 2, nothing created."""
    command, option, positive = which
    if value == 0 and not positive:
        return  # 0 s into the bag, no wait: fine
    out = tmp_path / f"rec_{option.strip('-')}_{value}"
    (result,) = _cli(_bag_argv(command, option, repr(value), out))
    assert result[0] is not None, f"{option} {value!r}: still running after 60 s"
    _one_line_error(result, option)
    assert not out.exists()


def test_a_start_offset_past_the_end_says_so(tmp_path):
    """An offset past the end of a healthy bag names the offset, not the bag as corrupt."""
    (result,) = _cli(["bag", "play", os.path.join(SESSION, "bag"), "--start-offset", "1e300"])
    line = _one_line_error(result, "past the end")
    assert "corrupt" not in line and "truncated" not in line


def test_a_bad_topic_name_is_refused_before_any_file(node, tmp_path):
    """`bag record` with a name that breaks the ROS 2 topic name rules: one line saying so,
    exit 2, and neither the bag folder nor any file of it made."""
    out = tmp_path / "nb"
    results = _cli(
        ["bag", "record", str(out), "bad topic!!", "--duration", "1"],
        ["bag", "record", str(tmp_path / "nb2" / "deeper"), "/fine", "a//b", "--duration", "1"],
        ["bag", "play", os.path.join(SESSION, "bag"), "--paced", "--status-topic", "not ok"],
    )
    _one_line_error(results[0], "'bad topic!!'", "topic name")
    _one_line_error(results[1], "'a//b'", "topic name")
    _one_line_error(results[2], "'not ok'", "topic name")
    assert sorted(os.listdir(tmp_path)) == []
    with pytest.raises(BagError, match="not a valid ROS 2 topic name"):
        Recorder(node, str(out), ["/fine", "{no such}/topic"])
    assert not out.exists()
    # a relative name is recorded under its full name, once
    rec = Recorder(node, str(out), ["bagtest/rel", "/bagtest/rel"])
    assert rec.topics == ["/bagtest/rel"]
    rec.close()
    assert rec.kept and (out / "metadata.yaml").exists()


def test_a_failed_recording_leaves_no_partial_bag(node, tmp_path, monkeypatch):
    """A recording that fails after its folder was made removes what it made: when it starts
    (here: no typestore), when a write fails (a full disk), and when a topic's type cannot be
    recorded -- then the bag is kept only if it holds what was recorded before."""
    out = tmp_path / "new" / "bag"

    def broken():
        raise OSError(28, "No space left on device")

    with monkeypatch.context() as m:
        m.setattr(bag_module, "_typestore", broken)
        with pytest.raises(OSError):
            Recorder(node, str(out), ["/bagtest/fail"])
    assert not (tmp_path / "new").exists()

    pub = node.create_publisher(String, "/bagtest/full", 10)
    rec = Recorder(node, str(out), ["/bagtest/full"])
    assert _wait(lambda: "/bagtest/full" in rec.connections)
    assert _wait(lambda: pub.get_subscription_count() >= 1)

    def full(*args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(rec.writer, "write", full)
    pub.publish(String(data="lost"))
    assert _wait(lambda: rec.error is not None)
    assert "No space left" in rec.error and "\n" not in rec.error
    rec.close()
    assert not rec.kept and not (tmp_path / "new").exists()
    node.destroy_publisher(pub)

    # a topic whose type cannot be recorded (rosbags does not know it), found while recording:
    # the timer's failure is kept in .error (not raised in the node's spin thread); with nothing
    # recorded yet there is no bag, else the bag keeps what was recorded before
    from rosbags.typesys import Stores, get_typestore

    rec = Recorder(node, str(out), ["/bagtest/odd"])
    rec.typestore = get_typestore(Stores.EMPTY)
    pub = node.create_publisher(String, "/bagtest/odd", 10)
    assert _wait(lambda: rec.error is not None)
    assert "/bagtest/odd" in rec.error and "is unknown" in rec.error and "\n" not in rec.error
    rec.close()
    assert not rec.kept and not (tmp_path / "new").exists()
    node.destroy_publisher(pub)

    pub = node.create_publisher(String, "/bagtest/keep", 10)
    rec = Recorder(node, str(out), ["/bagtest/keep", "/bagtest/odd2"])
    assert _wait(lambda: "/bagtest/keep" in rec.connections)
    assert _wait(lambda: pub.get_subscription_count() >= 1)
    pub.publish(String(data="kept"))
    assert _wait(lambda: rec.counts["/bagtest/keep"] == 1)
    rec.typestore = get_typestore(Stores.EMPTY)
    odd = node.create_publisher(String, "/bagtest/odd2", 10)
    assert _wait(lambda: rec.error is not None)
    assert rec.close() == {"/bagtest/keep": 1, "/bagtest/odd2": 0}
    assert rec.kept and bag_info(str(out))["messages"] == 1
    node.destroy_publisher(pub)
    node.destroy_publisher(odd)


def test_a_loop_over_nothing_ends_and_a_wait_can_be_stopped(node, tmp_path):
    """`--loop` over a bag with no messages returns instead of reopening it for ever; a wait
    for subscribers ends when told to stop; bad numbers are refused by the classes too."""
    out = str(tmp_path / "empty")
    Recorder(node, out, ["/bagtest/nobody"]).close()
    assert bag_info(out)["messages"] == 0
    player = Player(node, out, loop=True)
    stop, done = threading.Event(), []
    t = threading.Thread(target=lambda: done.append(player.play(stop)), daemon=True)
    t.start()
    t.join(timeout=30)
    stop.set()
    assert done == [0], "a loop over an empty bag did not end"
    stop = threading.Event()
    stop.set()
    t0 = time.monotonic()
    assert not Player(node, os.path.join(SESSION, "bag")).wait_for_subscribers(60, stop)
    assert time.monotonic() - t0 < 10
    for bad in (math.nan, math.inf, -1.0):
        with pytest.raises(BagError, match="start offset"):
            Player(node, os.path.join(SESSION, "bag"), start_offset=bad)
        with pytest.raises(BagError, match="rate"):
            Player(node, os.path.join(SESSION, "bag"), rate=bad)
        with pytest.raises(BagError, match="timeout"):
            StatusPacer(node, timeout=bad)


def test_bundled_session_replays_into_a_live_node(ros_context, tmp_path, library):
    """The recorded operator session, played into a fresh engine node started from the YAML
    launch file while two other processes keep both cores busy: paced by the node, the
    registered objects match the truth and what the node reported when the session was
    recorded."""
    from affordance_registration.evaluation.session import replay_session

    info = bag_info(os.path.join(SESSION, "bag"))
    assert {t["topic"] for t in info["topics"]} >= {
        "/points",
        "/clicked_point",
        "/spacenav/joy",
        "/spacenav/twist",
        "/affordance_engine/status",
    }
    assert os.path.getsize(os.path.join(SESSION, "bag", "bag.mcap")) < 8e6
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        result = replay_session(SESSION, str(tmp_path / "out"))
    finally:
        for p in busy:
            p.kill()
            p.wait()
    assert result["mismatches"] == [], result["mismatches"]
    rows = result["rows"]
    assert len(rows) == 5
    for r in rows:
        assert r["shown"] == r["template"] and r["ok"] and r["why"] == "", r
        assert r["error_mm"] < 5 and r["error_deg"] < 5, r
    # the session needed the operator: a SpaceMouse correction (model changes are covered live
    # in test_engine_node: every object of this scene is ranked right at the first click)
    assert sum(r["corrections"] for r in rows) >= 1
    assert result["ok"]
    saved = yaml.safe_load(open(tmp_path / "out" / "registrations.yaml"))
    assert len(saved["registrations"]) == 5
    png = open(result["picture"], "rb").read()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20000


def test_demo_verdict_names_what_failed(library):
    """A replayed registration off the truth (or off the recording) fails with why, in the
    table, the last line and the picture; a missing one is a failing row too."""
    import json

    import numpy as np

    from affordance_registration.cli import print_session_table, verdict_line
    from affordance_registration.evaluation.render import FAIL_COLOUR, PASS_COLOUR, render_verdict
    from affordance_registration.evaluation.session import compare_with_recording, session_rows
    from affordance_registration.evaluation.simulation import CameraIntrinsics, load_truth
    from affordance_registration.ros.standins.bag import read_messages

    truth = load_truth(os.path.join(SESSION, "truth.yaml"))
    recorded = [
        json.loads(m.data)
        for m in read_messages(os.path.join(SESSION, "bag"), "/affordance_engine/status")
    ][-1]
    good = compare_with_recording(
        session_rows(recorded, truth, library),
        recorded["registered"],
        recorded["registered"],
        library,
    )
    assert [r["ok"] for r in good] == [True] * 5 and verdict_line(good) == "DEMO OK"
    live = json.loads(json.dumps(recorded))
    live["registered"][2]["pose"][0][3] += 0.007  # 7 mm off along x
    moved = live["registered"][2]["template"]
    live["registered"] = live["registered"][:4]  # the last one missing
    rows = compare_with_recording(
        session_rows(live, truth, library), recorded["registered"], live["registered"], library
    )
    assert [r["ok"] for r in rows] == [True, True, False, True, False]
    assert "mm > 5 mm" in rows[2]["why"] and "from the recorded registration" in rows[2]["why"]
    assert rows[4]["why"] == "not registered in the replay"
    lines = []
    print_session_table(rows, out=lines.append)
    assert lines[3].endswith(f"FAIL ({rows[2]['why']})") and lines[1].endswith("PASS")
    last = verdict_line(rows)
    assert last.startswith("DEMO FAILED: ") and moved in last and rows[4]["template"] in last
    picture = render_verdict(
        np.zeros((0, 3)),
        [{**r, "ok": v["ok"], "why": v["why"]} for r, v in zip(live["registered"], rows)],
        [],
        library,
        CameraIntrinsics(**truth["intrinsics"]),
    )
    colours = {tuple(c) for c in picture.reshape(-1, 3)}
    assert FAIL_COLOUR in colours and PASS_COLOUR in colours


def test_a_session_folder_names_the_bag_inside_it():
    """The README's session (test/data/session) is a folder holding the bag and its truth:
    given to `bag info`, the one line names the bag to give."""
    result = _cli(["bag", "info", SESSION], ["bag", "info", os.path.join(SESSION, "bag")])
    line = _one_line_error(result[0], SESSION, "not a bag but a folder holding one")
    assert line.endswith(os.path.join(SESSION, "bag")), line
    assert result[1][0] == 0 and "messages" in result[1][1], result[1]


def _bomb_bag(folder, unpacked: int, promised: int | None = None) -> int:
    """A bag (MCAP, zstd chunks) of one String message whose chunk is a zstd bomb: the chunk's
    data unpacks to ``unpacked`` bytes of zeros; its record promises ``promised`` (default:
    the true size of the message's chunk). Returns the bag file's size."""
    from rosbags.rosbag2 import Writer, storage_mcap
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    zstd = storage_mcap.zstd
    bomb = zstd.ZstdCompressor()
    block = bytes(1 << 26)
    packed = [bomb.compress(block) for _ in range(unpacked >> 26)]
    packed.append(
        bomb.compress(bytes(unpacked & ((1 << 26) - 1)), zstd.ZstdCompressor.FLUSH_FRAME)
    )
    packed = b"".join(packed)
    store = get_typestore(Stores.ROS2_JAZZY)
    writer = Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    writer.open()
    mcap = writer.storage
    conn = writer.add_connection("/status", "std_msgs/msg/String", typestore=store)
    msg = store.types["std_msgs/msg/String"](data="x")
    writer.write(conn, 1, store.serialize_cdr(msg, conn.msgtype))
    mcap.compressor = lambda data: packed  # the chunk's data: the bomb
    if promised is not None:
        real_tell = mcap.chunk.bio.tell
        mcap.chunk.bio.tell = lambda: promised if real_tell() else 0
    writer.close()
    # without its summary (as a bag cut short has none): a reader scans the chunks
    (mcap,) = folder.glob("*.mcap")
    data, at = mcap.read_bytes(), 8
    while data[at] != 0x0F:  # up to the DataEnd record
        at += 9 + int.from_bytes(data[at + 1 : at + 9], "little")
    at += 9 + int.from_bytes(data[at + 1 : at + 9], "little")
    footer = b"\x02" + (20).to_bytes(8, "little") + bytes(20)
    mcap.write_bytes(data[:at] + footer + b"\x89MCAP0\r\n")
    return sum(p.stat().st_size for p in folder.iterdir())


def test_a_compressed_bag_bomb_is_refused_in_one_line_within_its_bound(tmp_path):
    """`bag info` on a bag of a few hundred kB whose MCAP chunk is a zstd bomb (2.6 GB of zeros;
    rosbags unpacked it whole): refused in one line, within a 1 GB memory limit, whether the
    chunk's record promises its true size (the data unpacks to more) or the bomb's (more than
    MAX_UNPACKED_BYTES)."""
    from test_hardening import one_line, run_cli_all

    from affordance_registration.ros.standins.bag import MAX_UNPACKED_BYTES

    honest, claims = tmp_path / "honest", tmp_path / "claims"
    size = _bomb_bag(honest, 2_600_000_000)
    assert size < 400_000, size
    _bomb_bag(claims, 2_600_000_000, promised=2_600_000_000)
    results = run_cli_all(
        ("bag", "info", str(honest)), ("bag", "info", str(claims)), limit_gb=1.0, timeout=120
    )
    lines = [one_line(code, err) for code, err, _ in results]
    assert str(honest) in lines[0] and "unpacks to more than the" in lines[0], lines[0]
    assert f"more than the {MAX_UNPACKED_BYTES:,}" in lines[1], lines[1]
