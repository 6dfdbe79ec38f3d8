# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The registrations file of a session: resumed at start, rewritten atomically after every change,
and never replaced without a backup when it holds something this session did not write.

:func:`save_registrations` and :func:`load_registrations` write and read (checked) the file's
format. Pure Python (no ROS). The engine node keeps one :class:`RegistrationStore` for its
``registrations_file``; every accept, undo and discard that changes the registrations is written
through it *before* the action is acknowledged, so a crash (``kill -9``) loses nothing the
operator was told about. The file is the one ``~/save`` writes (format
``affordance_registration/registrations/1``); there is no second journal to merge -- the whole,
small file is rewritten each time (atomically: a temporary file renamed into place).

Backups: the first time the store replaces a file whose bytes differ from what it wrote itself
(the file found at start, or one another program wrote meanwhile), that file is first copied to
``<stem>.<UTC time>.bak<suffix>`` next to it (``registrations.20261201T213000Z.bak.yaml``), with
the original's permission bits, and the backup's path is named in the reply.

What the store writes over is a registrations file or nothing: a file there that is not one
(empty aside) is refused, never replaced nor copied; so is a symbolic link (never followed: one
planted between two saves would have its target read into a backup and overwritten) and
anything that is not a regular file (a FIFO is never opened for reading, so it cannot block the
engine). One engine per file: the store holds an exclusive lock (``fcntl.flock``) on
``.<name>.lock`` next to the file while it lives; a second store on the same file is refused
in one line naming the holder (two engines would each acknowledge accepts that only one file
keeps). :meth:`RegistrationStore.close` removes the lock file (one left by a process that
died is unlocked, and taken over); a lock cannot be taken where the folder cannot be written,
and then nothing can be saved there either.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import math
import os
import socket
import stat
import sys
import threading
import time

import numpy as np
import yaml

from .errors import AffordanceError
from .files import open_regular, parse_yaml, read_yaml, write_atomically
from .templates import TemplateLibrary
from .tracked import Registration
from .transforms import is_rigid
from .waypoints import waypoints_dict

__all__ = [
    "RegistrationStore",
    "Autosave",
    "registrations_document",
    "backup_path",
    "save_registrations",
    "load_registrations",
    "REGISTRATIONS_FORMAT",
    "lock_path",
]

REGISTRATIONS_FORMAT = "affordance_registration/registrations/1"


#: PyYAML's safe dumper with libyaml's emitter where the wheel has it (the same text as
#: ``yaml.safe_dump``, four times faster: the node writes the whole file after every change)
SAFE_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
#: a registrations file larger than this is not read (bytes; a thousand objects with their
#: waypoints take about 2 MB)
MAX_REGISTRATIONS_BYTES = 20_000_000


def registrations_document(registrations, frame_id: str = "", library=None) -> str:
    """The YAML text of a registrations file holding ``registrations``; with the template
    ``library``, each carries its ``waypoints`` (in its frame). They are for the file's readers
    (a planner): loading recomputes them from the template and the registration."""
    entries = [r.to_dict() for r in registrations]
    if library is not None:
        for entry, reg in zip(entries, registrations):
            entry["waypoints"] = waypoints_dict(library, reg)
    doc = {
        "format": REGISTRATIONS_FORMAT,
        "frame_id": frame_id,
        "saved_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "registrations": entries,
    }
    return yaml.dump(doc, Dumper=SAFE_DUMPER, sort_keys=False)


def save_registrations(path: str, registrations, frame_id: str = "", library=None) -> str:
    """Write registrations to a YAML file atomically (with their waypoints when the template
    ``library`` is given); returns the absolute path."""
    try:
        write_atomically({path: registrations_document(registrations, frame_id, library)})
    except OSError as exc:
        raise AffordanceError(
            f"cannot save registrations to {path}: {exc.strerror or exc}"
        ) from None
    return os.path.abspath(path)


def load_registrations(path: str, library: TemplateLibrary | None = None) -> tuple:
    """Read a registrations file; each entry is checked (template known, pose a rigid 4x4)."""
    doc = read_yaml(
        path,
        AffordanceError,
        label=f"registrations {path}",
        max_bytes=MAX_REGISTRATIONS_BYTES,
        kind="registrations file",
    )
    if not isinstance(doc, dict) or doc.get("format") != REGISTRATIONS_FORMAT:
        raise AffordanceError(f"{path}: not a registrations file (format {REGISTRATIONS_FORMAT})")
    entries = doc.get("registrations") or []
    if not isinstance(entries, list):
        raise AffordanceError(f"{path}: 'registrations' must be a list")
    out = []
    for i, entry in enumerate(entries):
        where = f"{path}: registrations[{i}]"
        if not isinstance(entry, dict):
            raise AffordanceError(f"{where}: must be a mapping")
        try:
            out.append(_registration(entry, where, doc, i, library))
        except (TypeError, ValueError, AttributeError, OverflowError):
            raise AffordanceError(
                f"{where}: a value of the wrong kind (numbers for id, "
                f"likelihood, scale, joints ...; text for template, state)"
            ) from None
    return tuple(out)


def _registration(entry: dict, where: str, doc: dict, i: int, library) -> Registration:
    """One entry of a registrations file, checked (a value of the wrong kind raises TypeError,
    ValueError or AttributeError, which the caller words)."""
    try:
        T = np.asarray(entry["pose"], dtype=float)
        template = str(entry["template"])
    except (KeyError, TypeError, ValueError):
        raise AffordanceError(f"{where}: needs 'template' and a 4x4 'pose'") from None
    if not is_rigid(T):
        raise AffordanceError(f"{where}: 'pose' is not a rigid 4x4 transform")
    if library is not None and template not in library:
        raise AffordanceError(f"{where}: unknown template '{template}'")
    primitive, dims = _primitive_of(
        entry, where, library[template] if library is not None else None
    )
    # (without a click: where the pose puts the object's centroid, wherever its origin lies)
    at = library[template].centroid if library is not None else np.zeros(3)
    click = np.asarray(entry.get("click", T[:3, :3] @ at + T[:3, 3]), dtype=float)
    if click.shape != (3,):
        raise AffordanceError(f"{where}: 'click' must be three numbers")
    state = entry.get("state")
    if state is not None and not isinstance(state, str):
        raise AffordanceError(f"{where}: 'state' must be text")
    return Registration(
        id=int(entry.get("id", i + 1)),
        template=template,
        T_scene_model=T,
        likelihood=float(entry.get("likelihood", 0.0)),
        probability=float(entry.get("probability", 0.0)),
        residual=float(entry.get("residual", 0.0)),
        click=click,
        frame_id=str(entry.get("frame_id", doc.get("frame_id", ""))),
        joints={str(k): float(v) for k, v in (entry.get("joints") or {}).items()},
        state=state,
        scale=float(entry.get("scale", 1.0)),
        primitive=primitive,
        dimensions=dims,
        ranked_first=str(entry.get("ranked_first", "")),
        model_changes=int(entry.get("model_changes", 0)),
        corrections=int(entry.get("corrections", 0)),
        fit_s=float(entry.get("fit_s", 0.0)),
        override=entry.get("override") is True,
    )


def _primitive_of(entry: dict, where: str, template) -> tuple:
    """A saved registration's primitive kind and dimensions, checked (positive, finite; within
    the template's ranges when the library is known)."""
    dims = entry.get("dimensions")
    if template is not None and template.primitive is None:
        return None, {}
    if not dims:
        if template is not None:
            raise AffordanceError(
                f"{where}: the primitive '{template.name}' needs its 'dimensions'"
            )
        return None, {}
    try:
        dims = {str(k): float(v) for k, v in dict(dims).items()}
    except (TypeError, ValueError):
        raise AffordanceError(f"{where}: 'dimensions' must map names to metres") from None
    if not all(math.isfinite(v) and v > 0 for v in dims.values()):
        raise AffordanceError(f"{where}: 'dimensions' must be positive finite metres")
    kind = entry.get("primitive") if template is None else template.primitive
    if template is not None:
        if set(dims) != set(template.dimension_ranges):
            raise AffordanceError(
                f"{where}: a {kind} has dimensions {', '.join(template.dimension_ranges)}"
            )
        dims = template.clip_dimensions(dims)
    return (str(kind) if kind else None), dims


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


def _read_bytes(path: str) -> tuple[bytes, int] | None:
    """(the bytes, the permission bits) of the regular file at ``path``, None when there is
    none. A symbolic link is not followed and a FIFO not waited on: each, and anything else
    that is not a regular file, raises :class:`AffordanceError`."""
    try:
        with open_regular(path, follow=False) as handle:
            return handle.read(), stat.S_IMODE(os.fstat(handle.fileno()).st_mode)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise AffordanceError(
            f"cannot save registrations to {path}: {exc.strerror or exc} (not replaced)"
        ) from None


def _is_registrations(data: bytes) -> bool:
    """Whether ``data`` is empty or the YAML of a registrations file (any version's format)."""
    if not data.strip():
        return True
    try:
        doc = parse_yaml(data, AffordanceError, "registrations")
    except AffordanceError:
        return False
    return isinstance(doc, dict) and str(doc.get("format", "")).startswith(
        REGISTRATIONS_FORMAT.rsplit("/", 1)[0] + "/"
    )


def lock_path(path: str) -> str:
    """The lock file of the registrations file ``path``: ``.<name>.lock`` next to it."""
    folder, name = os.path.split(os.path.abspath(path))
    return os.path.join(folder, f".{name}.lock")


def _lock(path: str, holder: str):
    """An exclusive lock on ``path``'s lock file (the open file: closing it, or its garbage
    collection, releases the lock), None where the folder cannot be written. Raises
    :class:`AffordanceError` naming the holder when another has it. A lock file its holder
    removed meanwhile (:meth:`RegistrationStore.close`) is not taken: the lock is on the file
    at that name, checked after locking, else tried again."""
    lock = lock_path(path)
    for _ in range(10):
        try:
            os.makedirs(os.path.dirname(lock), exist_ok=True)
            fd = os.open(
                lock,
                os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC,
                0o600,
            )
        except OSError as exc:
            if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
                return None  # nothing can be saved there either: each save says so
            raise AffordanceError(
                f"cannot lock the registrations file {path}: {lock} {exc.strerror or exc}"
            ) from None
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise AffordanceError(
                    f"cannot lock the registrations file {path}: {lock} is not a file"
                )
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                who = os.pread(fd, 300, 0).decode("utf-8", "replace").strip() or "another process"
                raise AffordanceError(
                    f"the registrations file {path} is in use by {who}: two engines on one "
                    f"file would each acknowledge accepts only one keeps (stop it, or give this "
                    f"one another registrations_file)"
                ) from None
            try:
                same = os.lstat(lock).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if not same:  # removed by its holder between our open and our lock
                os.close(fd)
                continue
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{holder} (pid {os.getpid()} on {socket.gethostname()})\n".encode(), 0)
            return os.fdopen(fd, "r+b", buffering=0)
        except BaseException:
            os.close(fd)
            raise
    raise AffordanceError(f"cannot lock the registrations file {path}: {lock} keeps changing")


class RegistrationStore:
    """One registrations file. Thread-safe: :meth:`write` may be called from the stream worker
    and from the node's shutdown at once."""

    def __init__(self, path: str, holder: str | None = None):
        self.path = os.path.abspath(os.path.expanduser(path))
        #: the lock on the file (released by :meth:`close` or at the process's end)
        self._lock_file = _lock(self.path, holder or os.path.basename(sys.argv[0]) or "python")
        self._lock = threading.Lock()
        self._written: bytes | None = None  # what this store last wrote there
        self.count: int | None = None  # registrations in the file as last written
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

    def write(self, registrations, frame_id: str = "", library=None) -> tuple[str, str | None]:
        """Write ``registrations`` atomically (with their waypoints when the template
        ``library`` is given); returns (path written, backup made or None).
        A file there with bytes this store did not write is first kept as a backup. Raises
        :class:`AffordanceError` (nothing changed) when it cannot."""
        text = registrations_document(registrations, frame_id, library).encode("utf-8")
        with self._lock:
            found = _read_bytes(self.path)
            files: dict = {}
            backup, modes = None, {}
            if found is not None and found[0] != self._written:
                if not _is_registrations(found[0]):
                    raise AffordanceError(
                        f"cannot save registrations to {self.path}: it holds something that is "
                        f"not a registrations file (not replaced; move it away or name another "
                        f"registrations_file)"
                    )
                backup = backup_path(self.path)
                files[backup], modes[backup] = found
            files[self.path] = text
            try:
                write_atomically(files, modes)
            except OSError as exc:
                raise AffordanceError(
                    f"cannot save registrations to {self.path}: {exc.strerror or exc}"
                ) from None
            self._written = text
            self.count = len(registrations)
            if backup is not None:
                self.last_backup = backup
            return self.path, backup

    def close(self) -> None:
        """Release the file's lock and remove the lock file (another store may then take it)."""
        with self._lock:
            if self._lock_file is not None:
                with contextlib.suppress(OSError):
                    os.unlink(lock_path(self.path))
                self._lock_file.close()
                self._lock_file = None


class Autosave:
    """When a session's registrations are written to its ``store``: on ``save``
    (:meth:`persist` with ``explicit``), and after every change of them when ``enabled``
    (autosave) -- otherwise the change is remembered as ``unsaved`` until the next save. The
    operator stream calls :meth:`persist` before it answers the input that changed them, so
    what is acknowledged is durable."""

    def __init__(self, store: RegistrationStore | str, enabled: bool = True):
        #: the store, or the path of one made (and locked) on the first write: a session that
        #: never saves takes no lock
        self.store, self.enabled = store, bool(enabled)
        self.unsaved = False  #: registrations changed and not written (autosave off)

    def _store(self) -> RegistrationStore:
        if isinstance(self.store, str):
            self.store = RegistrationStore(self.store)
        return self.store

    def persist(self, engine, explicit: bool) -> str:
        """Write ``engine``'s registrations (in its frame, with their waypoints) when
        ``explicit`` or enabled; returns the reply's words ("" for none). Raises
        :class:`AffordanceError` when the file cannot be written (they stay in memory)."""
        if not explicit and not self.enabled:
            self.unsaved = True
            return ""
        regs = engine.state.registered
        path, backup = self._store().write(regs, engine.frame_id, engine.library)
        self.unsaved = False
        text = f"saved {len(regs)} registration(s) to {path}" if explicit else f"saved to {path}"
        return text + (f" (the file it replaced is kept as {backup})" if backup else "")

    def status(self) -> dict:
        """The status' ``registrations_file``: its path, how many it holds as last written,
        whether changes are unsaved and the last backup made."""
        if isinstance(self.store, str):
            return {
                "path": os.path.abspath(os.path.expanduser(self.store)),
                "saved": None,
                "unsaved": self.unsaved,
                "backup": None,
            }
        return {
            "path": self.store.path,
            "saved": self.store.count,
            "unsaved": self.unsaved,
            "backup": self.store.last_backup,
        }
