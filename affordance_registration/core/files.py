"""Saved files are written atomically: to temporary files in the destination folder first, then
renamed into place, so a failure (a full disk, a crash) never leaves a half-written file behind.
"""
from __future__ import annotations

import os
import tempfile
from typing import Mapping

__all__ = ["write_atomically"]


def write_atomically(files: Mapping[str, bytes | str]) -> list[str]:
    """Write every ``path -> content`` of ``files`` (bytes, or text written as UTF-8): all of
    them to temporary files first, then each renamed over its path. A failure while writing
    (a full disk, a target that is a folder) leaves no file changed -- the temporary ones are
    removed -- and raises the ``OSError``. Creates missing folders. Returns the absolute paths,
    in the order given."""
    staged: list[tuple[str, str]] = []
    try:
        for path, content in files.items():
            final = os.path.abspath(path)
            if os.path.isdir(final):
                raise IsADirectoryError(21, "is a folder", final)
            folder = os.path.dirname(final)
            os.makedirs(folder, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(final)}.", dir=folder)
            staged.append((tmp, final))
            data = content.encode("utf-8") if isinstance(content, str) else content
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
                handle.flush()
                os.fsync(handle.fileno())
        for tmp, final in staged:
            os.replace(tmp, final)
    except BaseException:
        for tmp, _ in staged:
            if os.path.exists(tmp):
                os.unlink(tmp)
        raise
    return [final for _, final in staged]
