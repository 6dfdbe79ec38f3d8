# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Saved files are written atomically: to temporary files in the destination folder first, then
renamed into place, so a failure (a full disk, a crash) never leaves a half-written file behind.

Only regular files are ever replaced: a path that is a device, a FIFO, a socket or a folder is
refused (as root, a rename over ``/dev/something`` would replace the device node). A symbolic
link is never followed: a link where a file is to be written is refused (one planted between
two saves would have its target overwritten); a rename replaces the directory entry, never
what a link points to. A file that existed keeps its permission bits (and, for root, its
owner); a new one gets the process's umask like any file it creates, or the ``mode`` asked for.
Once renamed, the folder is fsynced too, so that a write that returned survives a power loss
(the rule of SQLite and rosbag2). Temporary files are named ``.<name>.tmp-<pid>-<random>``; those
of processes that no longer run (killed while saving) are removed by the next write to that
folder.

Files are read with :func:`open_regular`: only a regular file (a FIFO would block the reader for
good, a device never end), opened without blocking and, where asked, without following a link.
:func:`read_yaml` reads a YAML file that way and turns whatever makes it unreadable into one
line: a missing file, not UTF-8, not YAML, nested too deeply, a number PyYAML cannot convert,
too large, a key written twice in one mapping (PyYAML would keep the last one silently; a
settings, template or launch file with a key twice is a mistake), or aliases that would expand
past :data:`MAX_ALIAS_NODES` (a "billion laughs" bomb: refused before anything is built).
"""

from __future__ import annotations

import errno
import os
import re
import stat
import tempfile
import threading
from typing import Mapping

import yaml

__all__ = [
    "write_atomically",
    "sync_folder",
    "open_regular",
    "not_regular",
    "read_yaml",
    "parse_yaml",
    "unreadable",
    "MAX_ALIAS_NODES",
]

_UMASK_LOCK = threading.Lock()
_TEMP = re.compile(r"^\.(?P<name>.+)\.tmp-(?P<pid>\d+)-[^.]+$")


def _umask() -> int:
    """The process's umask (from /proc where it can be read without changing it)."""
    try:
        with open("/proc/self/status", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _UMASK_LOCK:  # os.umask can only be read by setting it
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def _remove_stale(folder: str, name: str) -> None:
    """Remove temporary files of ``name`` left in ``folder`` by processes that died saving."""
    try:
        entries = os.listdir(folder)
    except OSError:
        return
    for entry in entries:
        m = _TEMP.match(entry)
        if m and m["name"] == name and int(m["pid"]) != os.getpid() and not _alive(int(m["pid"])):
            try:
                path = os.path.join(folder, entry)
                if stat.S_ISREG(os.lstat(path).st_mode):
                    os.unlink(path)
            except OSError:
                pass


def _target(path: str) -> tuple[str, os.stat_result | None]:
    """The file to write for ``path`` (absolute) and its stat (None if new). Raises OSError
    for anything that is not a regular file: a symbolic link is not followed."""
    final = os.path.abspath(path)
    try:
        st = os.lstat(final)
    except FileNotFoundError:
        return final, None
    if stat.S_ISLNK(st.st_mode):
        raise OSError(errno.ELOOP, "is a symbolic link: not followed, not replaced", final)
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(21, "is a folder, not a file", final)
    if not stat.S_ISREG(st.st_mode):
        raise OSError(1, f"is not a regular file ({not_regular(st.st_mode)}): not replaced", final)
    return final, st


def write_atomically(
    files: Mapping[str, bytes | str], mode: int | Mapping[str, int] | None = None
) -> list[str]:
    """Write every ``path -> content`` of ``files`` (bytes, or text written as UTF-8): all of
    them to temporary files first, then each renamed over its path, then their folders fsynced.
    A failure while writing (a full disk, a target that is not a regular file, a symbolic link)
    leaves no file changed -- the temporary ones are removed -- and raises the ``OSError``.
    Creates missing folders. Returns the absolute paths written, in the order given. ``mode``
    (such as 0o600 for a secret; or path -> mode for some of the files): the permission bits of
    a file written, whatever they were."""
    staged: list[tuple[str, str]] = []
    modes = mode if isinstance(mode, Mapping) else {path: mode for path in files}
    targets: dict[str, tuple] = {}  # final path -> (the path given, its stat)
    for path in files:  # every target checked before anything is written
        final, st = _target(path)
        if final in targets:
            raise OSError(
                errno.EINVAL, f"{path} and {targets[final][0]} are one file: neither written", path
            )
        targets[final] = (path, st)
    try:
        for (final, (given, st)), content in zip(targets.items(), files.values()):
            asked = modes.get(given)
            mode_new = 0o666 & ~_umask() if asked is None else asked
            folder, name = os.path.split(final)
            os.makedirs(folder, exist_ok=True)
            _remove_stale(folder, name)
            fd, tmp = tempfile.mkstemp(prefix=f".{name}.tmp-{os.getpid()}-", dir=folder)
            staged.append((tmp, final))
            data = content.encode("utf-8") if isinstance(content, str) else content
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
                handle.flush()
                os.fchmod(
                    handle.fileno(),
                    stat.S_IMODE(st.st_mode) if st and asked is None else mode_new,
                )
                if st is not None and os.geteuid() == 0:
                    os.fchown(handle.fileno(), st.st_uid, st.st_gid)
                os.fsync(handle.fileno())
        for tmp, final in staged:
            _target(final)  # still a regular file (or absent) right before the rename
            os.replace(tmp, final)
    except BaseException:
        for tmp, _ in staged:
            if os.path.lexists(tmp):
                os.unlink(tmp)
        raise
    for folder in dict.fromkeys(os.path.dirname(final) for _, final in staged):
        sync_folder(folder)
    return [final for _, final in staged]


def sync_folder(folder: str) -> None:
    """fsync ``folder``: the names renamed or created in it survive a power loss."""
    fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def open_regular(path: str, encoding: str | None = None, follow: bool = True):
    """Open ``path`` for reading -- text in ``encoding``, else binary -- when it is a regular
    file (a symbolic link to one included, unless not ``follow``). A folder, FIFO, device or
    socket raises ``OSError`` (its ``strerror`` says which) without blocking: the file is
    opened non-blocking, checked, then read as usual; so does a symbolic link when not
    ``follow`` (it is opened with ``O_NOFOLLOW``)."""
    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags if follow else flags | os.O_NOFOLLOW)
    except OSError as exc:
        if exc.errno == errno.ELOOP and not follow:
            raise OSError(errno.ELOOP, "is a symbolic link: not followed", path) from None
        raise
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(errno.EISDIR, "is a folder, not a file", path)
        if not stat.S_ISREG(mode):
            raise OSError(errno.EINVAL, f"is not a regular file ({not_regular(mode)})", path)
        os.set_blocking(fd, True)
        return os.fdopen(fd, "r" if encoding else "rb", encoding=encoding)
    except BaseException:
        os.close(fd)
        raise


def unreadable(path: str, missing_ok: bool = False) -> str | None:
    """Why ``path`` cannot be read as a regular file -- "no such file" (None with
    ``missing_ok``), "is not a regular file (a FIFO)" (a folder, a device, a socket), or the
    system's reason ("too many levels of symbolic links", "permission denied") -- or None where
    it can (a symbolic link to a regular file included)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return None if missing_ok else "no such file"
    except (OSError, ValueError) as exc:  # (ValueError: a NUL byte in the path)
        return str(getattr(exc, "strerror", None) or exc).lower()
    kind = not_regular(mode)
    return None if kind is None else f"is not a regular file ({kind})"


def not_regular(mode: int) -> str | None:
    """What a file of ``mode`` (``os.stat``'s ``st_mode``) is when it is not a regular file --
    "a folder", "a FIFO", "a device", "a socket" -- else None."""
    if stat.S_ISREG(mode):
        return None
    return (
        "a folder"
        if stat.S_ISDIR(mode)
        else "a FIFO"
        if stat.S_ISFIFO(mode)
        else "a device"
        if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
        else "a socket"
        if stat.S_ISSOCK(mode)
        else "not a file"
    )


#: the most nodes a YAML document's aliases (``*name``, merge keys ``<<: *name``) may add to it
#: when expanded: a settings or template file merging a few shared blocks adds tens; a
#: 455-byte "billion laughs" adds billions (refused before anything is built)
MAX_ALIAS_NODES = 10_000


def _children(node) -> list:
    if isinstance(node, yaml.SequenceNode):
        return node.value
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def _check_aliases(root) -> None:
    """Raise a YAML error when the node graph ``root`` (aliases share nodes) refers to itself
    or would expand to more than :data:`MAX_ALIAS_NODES` nodes beyond its own: sizes are
    summed over shared nodes once each, without expanding anything."""
    expanded: dict[int, int] = {}  # id(node) -> nodes in it, expanded
    on_path: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            on_path.discard(key)
            expanded[key] = 1 + sum(expanded[id(c)] for c in _children(node))
            continue
        if key in expanded:
            continue
        if key in on_path:
            raise yaml.composer.ComposerError(
                None, None, "an alias refers to a node that holds it (a cycle)", node.start_mark
            )
        on_path.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in _children(node) if id(c) not in expanded)
    extra = expanded[id(root)] - len(expanded)
    if extra > MAX_ALIAS_NODES:
        raise yaml.composer.ComposerError(
            None,
            None,
            f"its aliases would add {extra:,} nodes to it, more than the "
            f"{MAX_ALIAS_NODES:,} allowed",
            root.start_mark,
        )


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a mapping that has one key twice (merge keys ``<<`` aside:
    a merged key may be overridden, as YAML intends), and a document whose aliases refer to
    themselves or would expand it past :data:`MAX_ALIAS_NODES` (checked on the composed nodes,
    before anything is constructed)."""

    def compose_document(self):
        node = super().compose_document()
        _check_aliases(node)
        return node

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    twice = key in seen
                    seen.add(key)
                except TypeError:  # unhashable: PyYAML says so itself
                    continue
                if twice:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"the key {key!r} is written twice", key_node.start_mark
                    )
        return super().construct_mapping(node, deep)


def read_yaml(
    path: str,
    error: type[Exception],
    label: str | None = None,
    max_bytes: int | None = None,
    kind: str = "YAML file",
):
    """The YAML document of the regular file ``path`` (None for an empty one). Anything that
    keeps it from being read raises ``error`` with one line starting with ``label`` (default:
    the path): it cannot be read (missing, a folder, a FIFO ...), is larger than ``max_bytes``
    ("not a ``kind``"), is not UTF-8, is not YAML (with the line), nests too deeply, holds a
    number PyYAML cannot convert, or writes a key twice in one mapping."""
    label = str(path) if label is None else label
    try:
        with open_regular(path, encoding="utf-8") as handle:
            if max_bytes is not None and os.fstat(handle.fileno()).st_size > max_bytes:
                raise error(f"{label}: larger than {max_bytes // 1000} kB: not a {kind}")
            text = handle.read()
    except OSError as exc:
        raise error(f"{label}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise error(f"{label}: not UTF-8 text") from None
    return parse_yaml(text, error, label)


def parse_yaml(text: str | bytes, error: type[Exception], label: str):
    """The YAML document in ``text`` (None for an empty one), by :func:`read_yaml`'s rules
    (aliases bounded, no key twice); what keeps it from being read raises ``error`` with one
    line starting with ``label``."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except UnicodeDecodeError:
        raise error(f"{label}: not UTF-8 text") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" (line {mark.line + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise error(f"{label}: not valid YAML{at}: {str(problem).splitlines()[0][:120]}") from None
    except RecursionError:
        raise error(f"{label}: YAML nested too deeply") from None
    except ValueError as exc:  # PyYAML's int() of a number of thousands of digits
        raise error(f"{label}: not YAML this reads ({str(exc).splitlines()[0][:80]})") from None
