# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""No registration is lost: real engine processes killed with SIGKILL, SIGINT and SIGTERM and
started again on the same registrations file, a real client here (topics and services)."""

import os
import re
import signal
import stat
import threading

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped
from ros_helpers import LATCHED, Client, engine_process
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from affordance_registration.core.engine import Registration, load_registrations
from affordance_registration.core.errors import AffordanceError
from affordance_registration.core.files import write_atomically
from affordance_registration.core.persistence import (
    RegistrationStore,
    lock_path,
    registrations_document,
)
from affordance_registration.evaluation.simulation import simulate_taskboard
from affordance_registration.ros.glue.conversions import xyz_to_pointcloud2

FRAME = "camera_depth_optical_frame"
NS = "/affordance_engine"


@pytest.fixture(scope="module")
def sim(library):
    return simulate_taskboard(library, 7)


class Engine:
    """An engine process on ``tmp/registrations.yaml`` and a client of it."""

    def __init__(self, tmp, name, params=None):
        self.tmp, self.file = tmp, tmp / "registrations.yaml"
        self.proc = engine_process(tmp, params, name=name)
        self.client = Client(f"durability_{name}")
        self.client.subscribe(String, f"{NS}/status", LATCHED)
        self.points = self.client.node.create_publisher(PointCloud2, "/points", 1)
        self.registered = None  # the registrations the last accept counted
        self.clicks = self.client.node.create_publisher(PointStamped, "/clicked_point", 10)

    def status(self):
        return self.client.status(f"{NS}/status")

    def started(self):
        return self.client.wait_for(lambda: self.status(), 60, "the engine's status")

    def cloud(self, sim):
        self.client.wait_for_subscribers(self.points, timeout=30)
        self.client.wait_for_subscribers(self.clicks, timeout=30)
        self.points.publish(xyz_to_pointcloud2(sim.organized, FRAME))
        self.client.wait_for(
            lambda: (self.status() or {}).get("node", {}).get("cloud"), 30, "the cloud"
        )

    def register(self, obj):
        """Click ``obj`` and accept it; returns the accept's reply."""
        msg = PointStamped()
        msg.header.frame_id = FRAME
        msg.point.x, msg.point.y, msg.point.z = map(float, obj.click)
        self.clicks.publish(msg)
        self.client.wait_for(lambda: self.status()["objects"], 60, "the fitted object")
        res = self.client.call(Trigger, f"{NS}/accept", timeout=30)
        assert res.success, res.message
        # the reply counts the registrations ("... (3 registered)"): one more than before, and
        # the (rate-limited) status catches up with it
        count = int(re.search(r"\((\d+) registered\)", res.message).group(1))
        if self.registered is not None:
            assert count == self.registered + 1, (count, self.registered)
        self.registered = count
        self.client.wait_for(
            lambda: len(self.status()["registered"]) == count,
            30,
            f"{count} registrations in the status",
        )
        return res

    def close(self):
        self.client.close()
        self.proc.interrupt()
        self.proc.kill()
        print(self.proc.output()[-2000:])


@pytest.fixture
def engines(ros_context, tmp_path):
    started = []

    def start(name, params=None):
        e = Engine(tmp_path, name, params)
        started.append(e)
        return e

    yield start
    for e in started:
        e.close()


def _templates(regs):
    return sorted(r["template"] if isinstance(r, dict) else r.template for r in regs)


def test_kill_9_right_after_three_accepts_loses_none(engines, sim):
    first = engines("first")
    first.started()
    first.cloud(sim)
    accepted = []
    for obj in sim.objects[:3]:
        res = first.register(obj)
        accepted.append(obj.template)
    # the third accept was answered: kill at once, no chance to clean up
    os.killpg(first.proc.proc.pid, signal.SIGKILL)
    first.proc.proc.wait(timeout=10)
    assert "saved to" in res.message
    assert _templates(load_registrations(str(first.file))) == sorted(accepted)
    second = engines("second")
    st = second.client.wait_for(
        lambda: (second.status() or {}).get("registered") and second.status(),
        60,
        "the resumed registrations",
    )
    assert _templates(st["registered"]) == sorted(accepted)
    assert "resumed 3 registration(s)" in second.proc.output()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_with_an_unsaved_accept_keeps_it(engines, sim, sig):
    first = engines("first", {"autosave": "false"})
    first.started()
    first.cloud(sim)
    obj = sim.objects[2]
    first.register(obj)
    assert not first.file.exists()  # autosave off: nothing written yet
    first.proc.proc.send_signal(sig)
    assert first.proc.proc.wait(timeout=30) == 0
    assert _templates(load_registrations(str(first.file))) == [obj.template]
    second = engines("second")
    st = second.client.wait_for(
        lambda: (second.status() or {}).get("registered") and second.status(),
        60,
        "the resumed registration",
    )
    assert _templates(st["registered"]) == [obj.template]


def _five(library, path):
    names = list(library.specific())  # (a primitive would need its dimensions)
    regs = [
        Registration(
            id=i + 1,
            template=names[i % len(names)],
            T_scene_model=np.eye(4) + np.pad([[0, 0, 0, 0.1 * i]], ((0, 3), (0, 0))),
            likelihood=1.0,
            probability=0.5,
            residual=0.001,
            click=np.array([0.1 * i, 0, 1.0]),
            frame_id=FRAME,
        )
        for i in range(5)
    ]
    RegistrationStore(str(path)).write(regs, FRAME)
    return path.read_bytes()


def test_a_restart_then_accept_and_save_keeps_the_earlier_five(engines, sim, library, tmp_path):
    before = _five(library, tmp_path / "registrations.yaml")
    engine = engines("resumed")
    st = engine.client.wait_for(
        lambda: len((engine.status() or {}).get("registered", [])) == 5 and engine.status(),
        60,
        "the five resumed registrations",
    )
    assert [r["id"] for r in st["registered"]] == [1, 2, 3, 4, 5]
    engine.cloud(sim)
    res = engine.register(sim.objects[0])
    # the first write of this session replaced a file it did not write: kept, and named
    assert "kept as" in res.message
    backup = res.message.rsplit("kept as ", 1)[1].rstrip(")")
    assert open(backup, "rb").read() == before
    save = engine.client.call(Trigger, f"{NS}/save", timeout=30)
    assert save.success and "saved 6 registration(s)" in save.message
    assert "kept as" not in save.message  # it replaced only what it wrote itself
    regs = load_registrations(str(engine.file))
    assert len(regs) == 6 and [r.id for r in regs] == [1, 2, 3, 4, 5, 6]
    # undo cannot take the resumed ones away: it reverts the accept, then has nothing left
    assert engine.client.call(Trigger, f"{NS}/undo").success  # the accept
    assert engine.client.call(Trigger, f"{NS}/undo").success  # the click
    assert not engine.client.call(Trigger, f"{NS}/undo").success
    assert len(load_registrations(str(engine.file))) == 5


def test_a_fresh_session_keeps_the_old_file_as_a_backup(engines, sim, library, tmp_path):
    before = _five(library, tmp_path / "registrations.yaml")
    engine = engines("fresh", {"resume": "false"})
    st = engine.started()
    assert st["registered"] == []
    assert (tmp_path / "registrations.yaml").read_bytes() == before  # untouched until written
    engine.cloud(sim)
    res = engine.register(sim.objects[2])
    backup = res.message.rsplit("kept as ", 1)[1].rstrip(")")
    assert open(backup, "rb").read() == before
    assert len(load_registrations(str(engine.file))) == 1


def test_a_file_that_is_not_registrations_stops_the_start_in_one_line(tmp_path):
    path = tmp_path / "registrations.yaml"
    path.write_text("format: something else\n")
    proc = engine_process(tmp_path, name="bad")
    try:
        assert proc.proc.wait(timeout=60) == 2
        out = proc.output()
        assert "cannot resume the session" in out and "resume:=false" in out
        assert "Traceback" not in out
        assert path.read_text() == "format: something else\n"
    finally:
        proc.kill()


def test_the_store_backs_up_only_what_it_did_not_write(tmp_path, library):
    path = tmp_path / "r.yaml"
    store = RegistrationStore(str(path))
    assert store.write((), "f") == (str(path), None)
    assert store.write((), "f")[1] is None  # its own file: no backup
    theirs = registrations_document((), "other")  # another program wrote one meanwhile
    path.write_text(theirs)
    os.chmod(path, 0o640)
    _, backup = store.write((), "f")
    # the backup keeps what it holds and who may read it
    assert backup and open(backup).read() == theirs
    assert stat.S_IMODE(os.stat(backup).st_mode) == 0o640
    assert len(load_registrations(str(path))) == 0


def _folder(path) -> dict:
    """Every entry of a folder: name -> (mode, size, bytes of a regular file)."""
    out = {}
    for entry in sorted(os.listdir(path)):
        st = os.lstat(os.path.join(path, entry))
        data = open(os.path.join(path, entry), "rb").read() if stat.S_ISREG(st.st_mode) else None
        out[entry] = (st.st_mode, st.st_size, data)
    return out


def test_a_write_target_that_is_not_a_registrations_file_is_refused_and_kept(tmp_path):
    """What the store writes over is registrations or nothing: another file there (a secret,
    a config) is neither replaced nor copied into a backup."""
    path = tmp_path / "r.yaml"
    store = RegistrationStore(str(path))
    for text in ("password: hunter2\n", "#!/bin/sh\nrm -rf /\n", "\x00\x01binary"):
        path.write_text(text)
        os.chmod(path, 0o600)
        before = _folder(tmp_path)
        with pytest.raises(AffordanceError, match="not a registrations file.*not replaced"):
            store.write((), "f")
        assert _folder(tmp_path) == before


def test_a_link_planted_between_saves_is_never_followed(tmp_path):
    """A symbolic link put where the registrations file was, pointing at a 0600 file
    elsewhere: the save is refused, the file it points to is neither overwritten nor copied
    into a backup, and the link stays."""
    path, elsewhere = tmp_path / "r.yaml", tmp_path / "private"
    elsewhere.mkdir()
    secret = elsewhere / "id_ed25519"
    secret.write_text(registrations_document((), "a file the engine may read and write"))
    os.chmod(secret, 0o600)
    store = RegistrationStore(str(path))
    store.write((), "f")
    path.unlink()
    path.symlink_to(secret)
    before, kept = _folder(tmp_path), secret.read_bytes()
    with pytest.raises(AffordanceError, match="symbolic link"):
        store.write((), "f")
    assert _folder(tmp_path) == before and secret.read_bytes() == kept
    # and through the one function every saved file goes through
    with pytest.raises(OSError, match="symbolic link"):
        write_atomically({str(path): "x"})
    assert secret.read_bytes() == kept and path.is_symlink()


def test_a_fifo_where_the_file_was_is_refused_without_blocking(tmp_path):
    """The file replaced by a FIFO: the save answers (refused, naming it) instead of waiting
    for ever for a writer on the FIFO."""
    path = tmp_path / "r.yaml"
    store = RegistrationStore(str(path))
    store.write((), "f")
    path.unlink()
    os.mkfifo(path)
    outcome = []

    def save():
        try:
            store.write((), "f")
            outcome.append("written")
        except AffordanceError as exc:
            outcome.append(str(exc))

    worker = threading.Thread(target=save, daemon=True)
    worker.start()
    worker.join(timeout=60)  # a guard against hanging the suite, not a speed bound
    assert outcome and "a FIFO" in outcome[0], outcome or "the save blocked on the FIFO"
    assert stat.S_ISFIFO(os.lstat(path).st_mode)


def test_one_store_per_file_the_second_is_refused_naming_the_holder(tmp_path):
    path = tmp_path / "r.yaml"
    first = RegistrationStore(str(path), holder="the engine /left")
    with pytest.raises(AffordanceError, match=r"in use by the engine /left \(pid \d+"):
        RegistrationStore(str(path), holder="the engine /right")
    first.write((), "f")
    assert stat.S_IMODE(os.stat(lock_path(str(path))).st_mode) == 0o600
    first.close()  # a clean end removes the lock file
    assert not os.path.exists(lock_path(str(path)))
    second = RegistrationStore(str(path), holder="the engine /right")
    second.write((), "g")
    del second  # a store that dies without closing leaves its file unlocked: taken over
    RegistrationStore(str(path), holder="the engine /third").write((), "h")


def test_a_second_engine_on_a_locked_file_refuses_to_start_in_one_line(engines, sim):
    """Two engines on one registrations file would each acknowledge accepts that only one file
    keeps: the second refuses to start, in one line naming the first."""
    first = engines("first")
    first.started()
    second = engine_process(first.tmp, name="second")
    try:
        assert second.proc.wait(timeout=120) == 2
        out = second.output()
        lines = [line for line in out.splitlines() if "in use by" in line]
        assert len(lines) == 1 and "the engine /affordance_engine (pid" in lines[0], out
        assert "Traceback" not in out
    finally:
        second.kill()
    first.cloud(sim)
    assert "saved to" in first.register(sim.objects[0]).message


def test_a_save_fsyncs_the_folder_after_the_rename(tmp_path, monkeypatch):
    """Acknowledged is durable: after the rename the folder itself is fsynced (its new entry
    would be lost on power loss otherwise)."""
    synced = []
    real_fsync = os.fsync

    def fsync(fd):
        st = os.fstat(fd)
        synced.append((stat.S_ISDIR(st.st_mode), st.st_ino, os.listdir(tmp_path)))
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    RegistrationStore(str(tmp_path / "r.yaml")).write((), "f")
    folder = os.stat(tmp_path).st_ino
    assert any(is_dir and ino == folder and "r.yaml" in names for is_dir, ino, names in synced)
