"""The registrations file of a session: resumed at start, rewritten atomically after every change,
and never replaced without a backup when it holds something this session did not write.

Pure Python (no ROS). The engine node keeps one :class:`RegistrationStore` for its
``registrations_file``; every accept, undo and discard that changes the registrations is written
through it *before* the action is acknowledged, so a crash (``kill -9``) loses nothing the
operator was told about. The file is the one ``~/save`` writes (format
``affordance_registration/registrations/1``); there is no second journal to merge -- the whole,
small file is rewritten each time (atomically: a temporary file renamed into place).

Backups: the first time the store replaces a file whose bytes differ from what it wrote itself
(the file found at start, or one another program wrote meanwhile), that file is first copied to
``<stem>.<UTC time>.bak<suffix>`` next to it (``registrations.20261201T213000Z.bak.yaml``), and
the backup's path is named in the reply.
"""
from __future__ import annotations

import os
import threading
import time

import yaml

from .engine import REGISTRATIONS_FORMAT, load_registrations
from .errors import AffordanceError
from .files import write_atomically

__all__ = ["RegistrationStore", "registrations_document", "backup_path"]


def registrations_document(registrations, frame_id: str = "") -> str:
    """The YAML text of a registrations file holding ``registrations``."""
    doc = {"format": REGISTRATIONS_FORMAT, "frame_id": frame_id,
           "saved_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
           "registrations": [r.to_dict() for r in registrations]}
    return yaml.safe_dump(doc, sort_keys=False)


def backup_path(path: str, now: float | None = None) -> str:
    """A path next to ``path`` for a backup of it that does not exist yet:
    ``<stem>.<YYYYmmddTHHMMSSZ>.bak<suffix>`` (``-2``, ``-3``... appended to the time when
    taken)."""
    folder, name = os.path.split(os.path.abspath(path))
    stem, suffix = os.path.splitext(name)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(time.time() if now is None else now))
    candidate, n = os.path.join(folder, f"{stem}.{stamp}.bak{suffix}"), 1
    while os.path.lexists(candidate):
        n += 1
        candidate = os.path.join(folder, f"{stem}.{stamp}-{n}.bak{suffix}")
    return candidate


def _read_bytes(path: str) -> bytes | None:
    """The bytes of the regular file at ``path`` (following a link), None when there is none."""
    try:
        with open(path, "rb") as handle:
            return handle.read()
    except FileNotFoundError:
        return None
    except IsADirectoryError:
        raise AffordanceError(f"{path} is a folder, not a registrations file") from None
    except OSError as exc:
        raise AffordanceError(f"cannot read {path}: {exc.strerror or exc}") from None


class RegistrationStore:
    """One registrations file. Thread-safe: :meth:`write` may be called from the stream worker
    and from the node's shutdown at once."""

    def __init__(self, path: str):
        self.path = os.path.abspath(os.path.expanduser(path))
        self._lock = threading.Lock()
        self._written: bytes | None = None     # what this store last wrote there
        self.count: int | None = None          # registrations in the file as last written
        self.last_backup: str | None = None

    def resume(self, library=None) -> tuple:
        """The registrations in the file (``()`` when there is none). A file that cannot be read
        as registrations raises :class:`AffordanceError` naming it -- it is never overwritten
        silently: start with ``resume`` off and it is kept as a backup when first replaced."""
        if not os.path.lexists(self.path):
            return ()
        regs = load_registrations(self.path, library)
        self.count = len(regs)
        return regs

    def write(self, registrations, frame_id: str = "") -> tuple[str, str | None]:
        """Write ``registrations`` atomically; returns (path written, backup made or None).
        A file there with bytes this store did not write is first kept as a backup. Raises
        :class:`AffordanceError` (nothing changed) when it cannot."""
        text = registrations_document(registrations, frame_id).encode("utf-8")
        with self._lock:
            old = _read_bytes(self.path)
            files: dict = {}
            backup = None
            if old is not None and old != self._written:
                backup = backup_path(self.path)
                files[backup] = old
            files[self.path] = text
            try:
                write_atomically(files)
            except OSError as exc:
                raise AffordanceError(f"cannot save registrations to {self.path}: "
                                      f"{exc.strerror or exc}") from None
            self._written = text
            self.count = len(registrations)
            if backup is not None:
                self.last_backup = backup
            return self.path, backup
