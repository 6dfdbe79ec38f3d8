# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Point-cloud and mesh files, read safely: a header is checked against the file's size before
anything is allocated (a PLY that claims a billion vertices and holds one is refused at once),
what a reader could not read is an error rather than a shorter cloud, a PCD's ``VIEWPOINT``
is kept (where the scan was taken from) and so are the scan's own colours (a PCD's ``rgb`` or
``rgba`` field, a PLY's ``red green blue``).

Formats: PLY and PCD (read by Open3D), organized ``.npy`` arrays (H, W, 3) of numbers. A
``binary_compressed`` PCD is unpacked (by Open3D, into a buffer of the size its header gives)
only when that size is its points' bytes and at most :data:`MAX_UNPACKED_BYTES`.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass

import numpy as np

from .errors import SceneError
from .files import unreadable

__all__ = [
    "PointFile",
    "read_points",
    "check_header",
    "unpack_rgb",
    "MAX_FILE_BYTES",
    "MAX_POINTS",
    "MAX_UNPACKED_BYTES",
]

#: the largest point or mesh file read (bytes) and the most points one may hold
MAX_FILE_BYTES = 2_000_000_000
MAX_POINTS = 10_000_000
#: the most bytes a ``binary_compressed`` PCD's data may unpack to (LZF packs up to about 90:1:
#: a 48.6 MB file within MAX_POINTS unpacked to 4.65 GB in 75 s); its header must also promise
#: exactly its points' bytes. A 10-million-point cloud of x y z rgb and normals is 320 MB
MAX_UNPACKED_BYTES = 1_000_000_000
#: the sizes (bytes) a PCD field of each TYPE may have
_PCD_SIZES = {"F": (4, 8), "I": (1, 2, 4, 8), "U": (1, 2, 4, 8)}
_HEADER_LIMIT = 65536  # bytes of header read before giving up on finding its end
_PLY_SIZES = {
    "char": 1,
    "uchar": 1,
    "int8": 1,
    "uint8": 1,
    "short": 2,
    "ushort": 2,
    "int16": 2,
    "uint16": 2,
    "int": 4,
    "uint": 4,
    "int32": 4,
    "uint32": 4,
    "float": 4,
    "float32": 4,
    "double": 8,
    "float64": 8,
}


@dataclass(frozen=True)
class PointFile:
    """What a point file holds: ``points`` (N, 3) float64 metres (NaN rows kept: holes of an
    organized cloud), ``organized`` (H, W) or None, ``viewpoint`` (3,) -- the sensor origin a
    PCD's VIEWPOINT gives -- or None, and ``faces`` (the PLY has faces: a mesh, not a cloud)."""

    points: np.ndarray
    organized: tuple | None = None
    viewpoint: np.ndarray | None = None
    faces: bool = False
    #: unit normals (N, 3) where a binary PLY / PCD holds them (nx ny nz, normal_x ...), or None
    normals: np.ndarray | None = None
    #: the scan's colours (N, 3) uint8 RGB where the file holds them, or None
    colors: np.ndarray | None = None


def _fail(path: str, why: str, error=SceneError) -> Exception:
    return error(f"{path}: {why}")


def header_lines(path: str, error) -> tuple[list[str], int]:
    """The text lines of a PLY/PCD header and its length in bytes."""
    with open(path, "rb") as handle:
        head = handle.read(_HEADER_LIMIT)
    lines, pos = [], 0
    while True:
        end = head.find(b"\n", pos)
        if end < 0:
            raise _fail(path, "no end of the header in its first 64 KB", error)
        line = head[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        lines.append(line)
        if line == "end_header" or line.upper().startswith("DATA"):
            return lines, pos


def _check_ply(path: str, size: int, error) -> dict:
    lines, header_bytes = header_lines(path, error)
    if not lines or lines[0] != "ply":
        raise _fail(path, "not a PLY file (no 'ply' magic)", error)
    fmt = ""
    elements = []  # [name, count, least bytes of one element, properties]
    for line in lines[1:]:
        words = line.split()
        if words[:1] == ["format"] and len(words) >= 2:
            fmt = words[1]
        elif words[:1] == ["element"]:
            try:
                if len(words) != 3:
                    raise ValueError
                count = int(words[2])
            except ValueError:
                raise _fail(
                    path, f"bad element line {line!r} (element <name> <count>)", error
                ) from None
            if count < 0:
                raise _fail(path, f"negative element count in {line!r}", error)
            elements.append([words[1], count, 0, 0, [], []])
        elif words[:1] == ["property"] and elements:
            kind = (
                words[2]
                if len(words) >= 5 and words[1] == "list"
                else (words[1] if len(words) >= 3 else "")
            )
            if kind not in _PLY_SIZES:
                raise _fail(path, f"unknown property type in {line!r}", error)
            elements[-1][2] += _PLY_SIZES[kind]  # a list holds at least its length
            elements[-1][3] += 1
            elements[-1][4].append(words[-1] if words[1] != "list" else None)
            elements[-1][5].append("F" if kind.startswith(("float", "double")) else "U")
            if words[1] == "list" and elements[-1][0] == "vertex":
                raise _fail(
                    path,
                    f"a list property on the vertices ({line!r}): not a point cloud this reads",
                    error,
                )
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise _fail(path, f"unknown PLY format {fmt!r}", error)
    # an ASCII value takes at least two bytes (a digit and a separator)
    needed = sum(
        count * (2 * props if fmt == "ascii" else least)
        for _, count, least, props, _, _ in elements
    )
    counts = {name: count for name, count, _, _, _, _ in elements}
    names = [e[0] for e in elements]
    vertex = elements[names.index("vertex")] if "vertex" in names else None
    if vertex is not None and not all(c in vertex[4] for c in "xyz"):
        raise _fail(
            path,
            f"its vertices have no x, y, z among their properties "
            f"({', '.join(map(str, vertex[4]))})",
            error,
        )
    # a binary file of fixed-size elements holds exactly what its header announces
    exact = fmt != "ascii" and all(None not in e[4] for e in elements)
    return {
        "points": counts.get("vertex", 0),
        "faces": counts.get("face", 0) > 0,
        "needed": needed,
        "available": size - header_bytes,
        "ascii": fmt == "ascii",
        "exact": exact,
        "rows": sum(counts.values()),
        "header_bytes": header_bytes,
        "columns": vertex[4] if vertex else [],
        "types": vertex[5] if vertex else [],
        "skip": sum(e[1] for e in elements[: names.index("vertex")]) if vertex else 0,
    }


def _check_pcd(path: str, size: int, error) -> dict:
    lines, header_bytes = header_lines(path, error)
    fields: dict[str, list[str]] = {}
    for line in lines:
        words = line.split()
        if words and not words[0].startswith("#"):
            fields[words[0].upper()] = words[1:]
    try:
        points = int(fields.get("POINTS", ["0"])[0])
        sizes = [int(v) for v in fields.get("SIZE", [])]
        counts = [int(v) for v in fields.get("COUNT", ["1"] * len(sizes))]
        viewpoint = [float(v) for v in fields["VIEWPOINT"]] if "VIEWPOINT" in fields else None
    except (ValueError, IndexError):
        raise _fail(
            path, "malformed PCD header (POINTS, SIZE, COUNT or VIEWPOINT)", error
        ) from None
    if points < 0 or len(sizes) != len(counts) or not sizes or min(counts) < 1:
        raise _fail(path, "malformed PCD header (POINTS, SIZE or COUNT)", error)
    names, types = fields.get("FIELDS", []), [t.upper() for t in fields.get("TYPE", [])]
    if len(names) != len(sizes) or len(types) != len(sizes):
        raise _fail(path, "malformed PCD header (FIELDS, SIZE and TYPE differ in length)", error)
    for name, kind, nbytes in zip(names, types, sizes):
        if nbytes not in _PCD_SIZES.get(kind, ()):
            raise _fail(
                path,
                f"field {name!r}: TYPE {kind} SIZE {nbytes} is not a PCD type "
                f"(F 4 or 8, I or U 1, 2, 4 or 8)",
                error,
            )
    if not all(c in names for c in "xyz"):
        raise _fail(path, f"no x, y, z among its fields ({', '.join(names)})", error)
    try:
        width = int(fields.get("WIDTH", [str(points)])[0])
        height = int(fields.get("HEIGHT", ["1"])[0])
    except (ValueError, IndexError):
        raise _fail(path, "malformed PCD header (WIDTH or HEIGHT)", error) from None
    if width < 0 or height < 0 or width * height != points:
        raise _fail(path, f"WIDTH {width} x HEIGHT {height} is not its POINTS {points:,}", error)
    data = (fields.get("DATA") or [""])[0].lower()
    point_bytes = sum(s * c for s, c in zip(sizes, counts))
    needed = {
        "binary": points * point_bytes,
        "ascii": points * 2 * len(sizes),
        "binary_compressed": 8,
    }.get(data)
    if needed is None:
        raise _fail(path, f"unknown PCD DATA {data!r}", error)
    if data == "binary_compressed" and size - header_bytes >= 8:
        # its payload: the compressed and the uncompressed size (uint32 each), then the data
        with open(path, "rb") as handle:
            handle.seek(header_bytes)
            packed, unpacked = np.frombuffer(handle.read(8), dtype="<u4")
        if int(unpacked) != points * point_bytes:
            raise _fail(
                path,
                f"its compressed data unpacks to {int(unpacked):,} bytes, not the "
                f"{points * point_bytes:,} of its {points:,} points (corrupt)",
                error,
            )
        if int(unpacked) > MAX_UNPACKED_BYTES:
            raise _fail(
                path,
                f"its compressed data unpacks to {int(unpacked):,} bytes, more than the "
                f"{MAX_UNPACKED_BYTES:,} this reads (MAX_UNPACKED_BYTES)",
                error,
            )
        needed = 8 + int(packed)
    if viewpoint is not None and (len(viewpoint) != 7 or not np.all(np.isfinite(viewpoint))):
        raise _fail(path, "VIEWPOINT must be 7 finite numbers (tx ty tz qw qx qy qz)", error)
    columns, kinds = [], []
    for name, kind, count in zip(fields.get("FIELDS", []), types, counts):
        columns += [name] + [None] * (count - 1)
        kinds += [kind] * count
    return {
        "types": kinds,
        "points": points,
        "faces": False,
        "needed": needed,
        "available": size - header_bytes,
        "viewpoint": viewpoint,
        "ascii": data == "ascii",
        "header_bytes": header_bytes,
        "columns": columns,
        "skip": 0,
        "exact": data == "binary",
        "rows": points,
    }


def check_header(path: str, error=SceneError) -> dict:
    """Check a PLY or PCD file's header against its size: ``points`` it claims, whether it has
    ``faces``, and (PCD) the ``viewpoint`` list. Raises ``error`` naming the file."""
    path = str(path)
    try:
        size = os.path.getsize(path)
    except OSError as exc:
        raise _fail(path, f"cannot read: {exc.strerror}", error) from None
    if size > MAX_FILE_BYTES:
        raise _fail(
            path,
            f"{size / 1e9:.1f} GB is more than the {MAX_FILE_BYTES / 1e9:.0f} GB this reads",
            error,
        )
    ext = os.path.splitext(path)[1].lower()
    try:
        info = (_check_ply if ext == ".ply" else _check_pcd)(path, size, error)
    except OSError as exc:
        raise _fail(path, f"cannot read: {exc.strerror}", error) from None
    if info["points"] > MAX_POINTS:
        raise _fail(
            path,
            f"its header claims {info['points']:,} points, more than the "
            f"{MAX_POINTS:,} this reads",
            error,
        )
    if info["needed"] > info["available"]:
        raise _fail(
            path,
            f"its header claims {info['points']:,} points but the file holds "
            f"only {max(info['available'], 0):,} bytes of data (truncated or "
            f"corrupt)",
            error,
        )
    if info.get("exact") and info["needed"] != info["available"]:
        raise _fail(
            path,
            f"its header claims {info['points']:,} points in "
            f"{info['needed']:,} bytes but the file holds {info['available']:,} "
            f"bytes of data (the header does not match the data)",
            error,
        )
    return info


@contextlib.contextmanager
def _quiet_open3d():
    """Open3D's own console warnings off while it reads (failures become our errors)."""
    import open3d as o3d

    level = o3d.utility.get_verbosity_level()
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    try:
        yield o3d
    finally:
        o3d.utility.set_verbosity_level(level)


def _viewpoint_origin(viewpoint) -> np.ndarray | None:
    """The sensor origin of a PCD VIEWPOINT (tx ty tz qw qx qy qz): its translation."""
    return None if viewpoint is None else np.asarray(viewpoint[:3], dtype=float)


def read_points(path: str, error=SceneError) -> PointFile:
    """Read a PLY, PCD or organized ``.npy`` file. Raises ``error`` (one line naming the file)
    for anything unreadable, oversized or incomplete."""
    path = str(path)
    why = unreadable(path)
    if why is not None:
        raise _fail(path, why, error)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".npy":
        return _read_npy(path, error)
    if ext not in (".ply", ".pcd"):
        raise _fail(path, f"unsupported point file format '{ext}' (PLY, PCD or .npy)", error)
    info = check_header(path, error)
    normals = colors = None
    if info["ascii"]:
        pts, colors = _read_ascii(path, info, error)
    else:
        with _quiet_open3d() as o3d:
            cloud = o3d.io.read_point_cloud(path)
        pts = np.asarray(cloud.points, dtype=float)
        if cloud.has_colors() and len(cloud.colors) == len(pts):
            colors = np.round(np.clip(np.asarray(cloud.colors), 0.0, 1.0) * 255).astype(np.uint8)
        if cloud.has_normals():
            normals = np.asarray(cloud.normals, dtype=float)
            length = np.linalg.norm(normals, axis=1)
            normals = (
                normals / np.maximum(length, 1e-12)[:, None]
                if len(normals) == len(pts)
                and np.all(np.isfinite(normals))
                and np.all(length > 1e-6)
                else None
            )
    if len(pts) == 0:
        raise _fail(path, "no points could be read (empty or not a point cloud)", error)
    if info["points"] and len(pts) != info["points"]:
        raise _fail(
            path,
            f"only {len(pts):,} of the {info['points']:,} points its header "
            f"announces could be read (a value that is not a number?)",
            error,
        )
    return PointFile(
        points=pts,
        viewpoint=_viewpoint_origin(info.get("viewpoint")),
        faces=bool(info["faces"]),
        normals=normals,
        colors=colors,
    )


#: the colour columns of an ASCII file: a PLY's three, a PCD's one packed field (0x00RRGGBB in
#: the bits of a float for ``rgb``, of an unsigned integer for ``rgba``, as PCL writes them)
_PLY_COLORS = ("red", "green", "blue")
_PCD_COLORS = ("rgb", "rgba")


def unpack_rgb(packed: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 RGB of PCL's packed colours: uint32 values 0x??RRGGBB."""
    v = np.asarray(packed, dtype=np.uint32)
    return np.stack([(v >> 16) & 255, (v >> 8) & 255, v & 255], axis=1).astype(np.uint8)


def _ascii_colors(rows: list, info: dict) -> np.ndarray | None:
    """The colours of an ASCII file's rows, or None (no colour columns, or values that are not
    colours: the points are still read)."""
    columns = info["columns"]
    try:
        if all(c in columns for c in _PLY_COLORS):
            use = [columns.index(c) for c in _PLY_COLORS]
            values = np.loadtxt(rows, usecols=use, dtype=float, ndmin=2, comments=None)
            if info["types"][use[0]] == "F":
                values = values * 255  # float colours are in [0, 1]
            return np.round(np.clip(values, 0, 255)).astype(np.uint8)
        name = next((c for c in _PCD_COLORS if c in columns), None)
        if name is None:
            return None
        i = columns.index(name)
        values = np.loadtxt(rows, usecols=[i], dtype=float, ndmin=1, comments=None)
        if info.get("types", [""] * len(columns))[i] == "F":
            packed = values.astype(np.float32).view(np.uint32)
        else:
            packed = np.clip(values, 0, 2**32 - 1).astype(np.uint32)
        return unpack_rgb(packed)
    except (ValueError, IndexError):
        return None


def _read_ascii(path: str, info: dict, error) -> tuple[np.ndarray, np.ndarray | None]:
    """x, y, z of an ASCII PLY's vertices or an ASCII PCD's points, every value checked (Open3D
    reads a value that is not a number as whatever memory held, or as 0), and their colours
    (None without)."""
    columns = info["columns"]
    if not all(c in columns for c in "xyz"):
        raise _fail(path, f"no x, y, z among its fields ({', '.join(map(str, columns))})", error)
    use = [columns.index(c) for c in "xyz"]
    with open(path, "rb") as handle:
        handle.seek(info["header_bytes"])
        text = handle.read().decode("ascii", errors="replace").splitlines()
    held = sum(1 for line in text if line.strip())
    if held != info["rows"]:  # (an element a line: more rows were dropped unread)
        raise _fail(
            path,
            f"its header announces {info['rows']:,} rows of data but it holds "
            f"{held:,} (the header does not match the data)",
            error,
        )
    rows = text[info["skip"] : info["skip"] + info["points"]]
    if not rows:
        return np.zeros((0, 3)), None
    try:  # numpy's parser; on failure find the row that broke it
        xyz = np.loadtxt(rows, usecols=use, dtype=float, ndmin=2, comments=None)
        return xyz, _ascii_colors(rows, info)
    except ValueError:
        pass
    out = np.empty((len(rows), 3))
    for i, row in enumerate(rows):
        words = row.split()
        try:
            out[i] = [float(words[k]) for k in use]
        except (ValueError, IndexError):
            raise _fail(
                path, f"point {i}: {row.strip()[:60]!r} does not hold x, y, z as numbers", error
            ) from None
    return out, _ascii_colors(rows, info)


def _read_npy(path: str, error) -> PointFile:
    try:
        with open(path, "rb") as handle:
            version = np.lib.format.read_magic(handle)
            shape, _, dtype = (
                np.lib.format.read_array_header_1_0(handle)
                if version == (1, 0)
                else np.lib.format.read_array_header_2_0(handle)
            )
    except Exception as exc:  # numpy raises several types for a broken header
        raise _fail(path, f"not a readable .npy array ({exc.__class__.__name__})", error) from None
    if dtype.kind not in "fiu" or dtype.fields is not None:
        raise _fail(path, f"holds {dtype} values; expected numbers (float or int)", error)
    if len(shape) != 3 or shape[-1] != 3:
        raise _fail(path, f"expected an organized (H, W, 3) array, got {shape}", error)
    if shape[0] * shape[1] > MAX_POINTS:
        raise _fail(
            path,
            f"{shape[0] * shape[1]:,} points is more than the {MAX_POINTS:,} this reads",
            error,
        )
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as exc:
        raise _fail(path, f"not a readable .npy array ({exc.__class__.__name__})", error) from None
    return PointFile(points=arr.reshape(-1, 3).astype(float), organized=tuple(shape[:2]))
