# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Message <-> numpy conversions, vectorised, at the boundary of the ROS glue.

``pointcloud2_to_xyz`` reads x, y, z from any PointCloud2 layout that carries them as float32 or
float64 (any offsets, padding, point_step, row_step, organized or not, either endianness) with
one structured-dtype view of the buffer -- no per-point Python. None of this needs ``rclpy.init``.
"""

from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import Point, PointStamped, Pose, PoseStamped, Quaternion, Transform
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker

from ...core.errors import AffordanceError
from ...core.pointfiles import MAX_POINTS, unpack_rgb
from ...core.transforms import make_T, matrix_to_quat_xyzw, quat_xyzw_to_matrix

__all__ = [
    "ConversionError",
    "source_stamp_s",
    "header_stamp_s",
    "parse_dimension",
    "pointcloud2_layout",
    "pointcloud2_to_xyz",
    "pointcloud2_field",
    "pointcloud2_colors",
    "COLOR_FIELDS",
    "xyz_to_pointcloud2",
    "pose_to_matrix",
    "matrix_to_pose",
    "pose_stamped",
    "point_stamped",
    "stamped",
    "transform_to_matrix",
    "matrix_to_transform",
    "mesh_marker",
    "text_marker",
    "sphere_marker",
    "likelihood_color",
]

_FLOAT_TYPES = {PointField.FLOAT32: "f4", PointField.FLOAT64: "f8"}
_NUMERIC = {
    PointField.INT8: "i1",
    PointField.UINT8: "u1",
    PointField.INT16: "i2",
    PointField.UINT16: "u2",
    PointField.INT32: "i4",
    PointField.UINT32: "u4",
    PointField.FLOAT32: "f4",
    PointField.FLOAT64: "f8",
}
_SIZES = {
    PointField.INT8: 1,
    PointField.UINT8: 1,
    PointField.INT16: 2,
    PointField.UINT16: 2,
    PointField.INT32: 4,
    PointField.UINT32: 4,
    PointField.FLOAT32: 4,
    PointField.FLOAT64: 8,
}


class ConversionError(AffordanceError):
    """A message cannot be converted (the text says what is wrong with it)."""


def pointcloud2_layout(msg: PointCloud2) -> np.dtype:
    """Check a PointCloud2's header against its data without reading the points: x, y, z each
    once, as float32/float64 within ``point_step``, rows that fit ``row_step``, data of the size
    the header says. Returns the structured dtype of one point; raises ConversionError saying
    what is wrong."""
    names = [f.name for f in msg.fields]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ConversionError(
            f"PointCloud2 has more than one field named {', '.join(repr(n) for n in duplicates)}"
        )
    fields = {f.name: f for f in msg.fields}
    missing = [n for n in ("x", "y", "z") if n not in fields]
    if missing:
        raise ConversionError(
            f"PointCloud2 has no {'/'.join(missing)} field (fields: {', '.join(fields) or 'none'})"
        )
    h, w, step, row_step = int(msg.height), int(msg.width), int(msg.point_step), int(msg.row_step)
    endian = ">" if msg.is_bigendian else "<"
    formats, offsets = [], []
    for n in ("x", "y", "z"):
        f = fields[n]
        if f.datatype not in _FLOAT_TYPES:
            raise ConversionError(
                f"PointCloud2 field '{n}' has datatype {f.datatype}; "
                f"only FLOAT32 (7) and FLOAT64 (8) are supported"
            )
        if f.count not in (0, 1):
            raise ConversionError(f"PointCloud2 field '{n}' has count {f.count}, expected 1")
        if f.offset + _SIZES[f.datatype] > step:
            raise ConversionError(
                f"PointCloud2 field '{n}' (offset {f.offset}) does not fit in point_step {step}"
            )
        formats.append(endian + _FLOAT_TYPES[f.datatype])
        offsets.append(int(f.offset))
    if h * w > MAX_POINTS:
        raise ConversionError(
            f"PointCloud2 has {h * w:,} points, more than the {MAX_POINTS:,} "
            f"this node takes (downsample it)"
        )
    if h * w and row_step < w * step:
        raise ConversionError(
            f"PointCloud2 row_step {row_step} is smaller than width {w} x point_step {step}"
        )
    size = len(msg.data)
    if h * w and size != row_step * h:
        raise ConversionError(
            f"PointCloud2 data has {size} bytes but the header says "
            f"{h} rows x row_step {row_step} = {row_step * h}"
        )
    return np.dtype(
        {"names": ["x", "y", "z"], "formats": formats, "offsets": offsets, "itemsize": step}
    )


def pointcloud2_to_xyz(msg: PointCloud2) -> tuple[np.ndarray, tuple | None]:
    """(points (N, 3) float64 with NaN rows kept, (height, width) if organized else None)."""
    dtype = pointcloud2_layout(msg)
    h, w, step, row_step = int(msg.height), int(msg.width), int(msg.point_step), int(msg.row_step)
    if h * w == 0:
        return np.zeros((0, 3)), None
    data = msg.data
    buf = (
        np.frombuffer(data, dtype=np.uint8)
        if not isinstance(data, np.ndarray)
        else data.view(np.uint8)
    )
    rows = buf.reshape(h, row_step)[:, : w * step]
    if not rows.flags.c_contiguous:
        rows = np.ascontiguousarray(rows)
    rec = rows.reshape(-1).view(dtype)
    pts = np.empty((h * w, 3), dtype=np.float64)
    pts[:, 0], pts[:, 1], pts[:, 2] = rec["x"], rec["y"], rec["z"]
    return pts, ((h, w) if h > 1 else None)


def pointcloud2_field(msg: PointCloud2, name: str) -> np.ndarray | None:
    """A scalar field (``intensity``, ...) of every point as (N,) float64 in the order of
    :func:`pointcloud2_to_xyz`, or None when the cloud has no such field. Call it on a cloud that
    :func:`pointcloud2_to_xyz` accepted (the layout is checked there)."""
    field = next((f for f in msg.fields if f.name == name), None)
    if field is None or field.datatype not in _NUMERIC or field.count not in (0, 1):
        return None
    values = _field_values(msg, field, _NUMERIC[field.datatype])
    return None if values is None else values.astype(np.float64)


#: the fields that hold a point's colour, packed 0x??RRGGBB in 4 bytes (a float32 ``rgb`` as
#: PCL and RViz write it, or a uint32 ``rgba``)
COLOR_FIELDS = ("rgb", "rgba")


def pointcloud2_colors(msg: PointCloud2) -> np.ndarray | None:
    """The cloud's own colours (N, 3) uint8 RGB in the order of :func:`pointcloud2_to_xyz`, from
    its ``rgb`` or ``rgba`` field (4 bytes each, whatever type it is declared as), or None when
    it has neither. Call it on a cloud that :func:`pointcloud2_to_xyz` accepted."""
    field = next(
        (
            f
            for name in COLOR_FIELDS
            for f in msg.fields
            if f.name == name and _SIZES.get(f.datatype) == 4 and f.count in (0, 1)
        ),
        None,
    )
    packed = None if field is None else _field_values(msg, field, "u4")
    return None if packed is None else unpack_rgb(packed)


def _field_values(msg: PointCloud2, field, kind: str) -> np.ndarray | None:
    """The values of one field of every point, read as numpy ``kind`` in the cloud's byte order
    (None when the field does not fit in a point)."""
    name = field.name
    h, w, step, row_step = int(msg.height), int(msg.width), int(msg.point_step), int(msg.row_step)
    if field.offset + np.dtype(kind).itemsize > step or h * w == 0:
        return None if h * w else np.zeros(0, dtype=kind)
    endian = ">" if msg.is_bigendian else "<"
    dtype = np.dtype(
        {
            "names": [name],
            "formats": [endian + kind],
            "offsets": [int(field.offset)],
            "itemsize": step,
        }
    )
    buf = (
        np.frombuffer(msg.data, dtype=np.uint8)
        if not isinstance(msg.data, np.ndarray)
        else msg.data.view(np.uint8)
    )
    rows = np.ascontiguousarray(buf.reshape(h, row_step)[:, : w * step])
    return rows.reshape(-1).view(dtype)[name]


def xyz_to_pointcloud2(
    points: np.ndarray, frame_id: str, stamp=None, colors: np.ndarray | None = None
) -> PointCloud2:
    """PointCloud2 with float32 x, y, z (point_step 16: 4 bytes padding, or with ``colors``, (N,
    3) uint8 RGB one per point, an ``rgb`` field there packed as PCL and RViz read it). ``points``
    is (N, 3) or organized (H, W, 3); NaN rows are kept (organized clouds mark holes that
    way)."""
    pts = np.asarray(points, dtype=np.float32)
    if pts.ndim == 3:
        h, w = pts.shape[:2]
    elif pts.ndim == 2 and pts.shape[1] == 3:
        h, w = 1, pts.shape[0]
    else:
        raise ConversionError(f"points must be (N, 3) or (H, W, 3), got {pts.shape}")
    buf = np.zeros((h * w, 4), dtype="<f4")
    buf[:, :3] = pts.reshape(-1, 3)
    if colors is not None:
        rgb = np.asarray(colors, dtype=np.uint8).reshape(-1, 3)
        if len(rgb) != h * w:
            raise ConversionError(f"{len(rgb)} colours for {h * w} points")
        packed = (rgb[:, 0].astype("<u4") << 16) | (rgb[:, 1].astype("<u4") << 8) | rgb[:, 2]
        buf.view("<u4")[:, 3] = packed
    msg = PointCloud2()
    msg.header = Header(frame_id=frame_id)
    if stamp is not None:
        msg.header.stamp = stamp
    msg.height, msg.width = h, w
    msg.fields = [
        PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
        for i, n in enumerate(("x", "y", "z") + (() if colors is None else ("rgb",)))
    ]
    msg.is_bigendian = False
    msg.point_step = 16
    msg.row_step = 16 * w
    msg.is_dense = bool(np.all(np.isfinite(pts)))
    msg.data = buf.tobytes()
    return msg


def pose_to_matrix(pose: Pose) -> np.ndarray:
    """4x4 of a Pose. Raises ConversionError for non-finite values or a non-unit quaternion
    (more than 1% off)."""
    p, q = pose.position, pose.orientation
    t = np.array([p.x, p.y, p.z], dtype=float)
    quat = np.array([q.x, q.y, q.z, q.w], dtype=float)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(quat))):
        raise ConversionError("pose has NaN or infinite values")
    n = np.linalg.norm(quat)
    if abs(n - 1.0) > 0.01:
        raise ConversionError(f"pose orientation is not a unit quaternion (norm {n:.3f})")
    return make_T(quat_xyzw_to_matrix(quat / n), t)


def matrix_to_pose(T: np.ndarray) -> Pose:
    q = matrix_to_quat_xyzw(np.asarray(T)[:3, :3])
    pose = Pose()
    pose.position = Point(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3]))
    pose.orientation = Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))
    return pose


def transform_to_matrix(tf: Transform) -> np.ndarray:
    pose = Pose()
    pose.position = Point(x=tf.translation.x, y=tf.translation.y, z=tf.translation.z)
    pose.orientation = tf.rotation
    return pose_to_matrix(pose)


def matrix_to_transform(T: np.ndarray) -> Transform:
    q = matrix_to_quat_xyzw(np.asarray(T)[:3, :3])
    tf = Transform()
    tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in T[:3, 3])
    tf.rotation = Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))
    return tf


def stamped(msg, frame_id: str, stamp=None):
    """``msg`` with its header in ``frame_id`` at ``stamp`` (None: left unstamped)."""
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    return msg


def pose_stamped(T: np.ndarray, frame_id: str, stamp=None) -> PoseStamped:
    return stamped(PoseStamped(pose=matrix_to_pose(T)), frame_id, stamp)


def point_stamped(point, frame_id: str, stamp=None) -> PointStamped:
    x, y, z = (float(v) for v in point)
    return stamped(PointStamped(point=Point(x=x, y=y, z=z)), frame_id, stamp)


def likelihood_color(probability: float, alpha: float = 0.85) -> ColorRGBA:
    """Green for a confident candidate, through yellow, to red for an unlikely one."""
    p = float(np.clip(probability, 0.0, 1.0))
    confidence = np.clip((p - 0.2) / 0.4, 0.0, 1.0)  # 0.2 -> red, 0.6 and above -> green
    return ColorRGBA(
        r=float(min(1.0, 2 * (1 - confidence))), g=float(min(1.0, 2 * confidence)), b=0.1, a=alpha
    )


#: id(mesh) -> (mesh, its triangle corners as Points), the most recently made last
_TRIANGLE_CACHE: dict = {}
_TRIANGLE_CACHE_SIZE = 256


def _triangle_points(mesh) -> list:
    key = id(mesh)
    hit = _TRIANGLE_CACHE.get(key)
    if hit is None or hit[0] is not mesh:
        tri = np.asarray(mesh.vertices)[np.asarray(mesh.faces)].reshape(-1, 3)
        pts = [Point(x=float(a), y=float(b), z=float(c)) for a, b, c in tri]
        hit = (mesh, pts)
        _TRIANGLE_CACHE.pop(key, None)
        while len(_TRIANGLE_CACHE) >= _TRIANGLE_CACHE_SIZE:  # bounded: the oldest go
            del _TRIANGLE_CACHE[next(iter(_TRIANGLE_CACHE))]
        _TRIANGLE_CACHE[key] = hit
    return hit[1]


def new_marker(kind: int, frame_id: str, ns: str, marker_id: int, stamp, position=None) -> Marker:
    m = Marker()
    m.header.frame_id = frame_id
    if stamp is not None:
        m.header.stamp = stamp
    m.ns, m.id = ns, int(marker_id)
    m.type, m.action = kind, Marker.ADD
    m.pose.orientation.w = 1.0
    if position is not None:
        m.pose.position = Point(x=float(position[0]), y=float(position[1]), z=float(position[2]))
    return m


def mesh_marker(
    mesh, T: np.ndarray, frame_id: str, ns: str, marker_id: int, color: ColorRGBA, stamp=None
) -> Marker:
    """The mesh as a TRIANGLE_LIST marker posed at T (RViz needs no mesh file)."""
    m = new_marker(Marker.TRIANGLE_LIST, frame_id, ns, marker_id, stamp)
    m.pose = matrix_to_pose(T)
    m.scale.x = m.scale.y = m.scale.z = 1.0
    m.color = color
    m.points = _triangle_points(mesh)
    return m


def text_marker(
    text: str, position, frame_id: str, ns: str, marker_id: int, stamp=None, height: float = 0.025
) -> Marker:
    m = new_marker(Marker.TEXT_VIEW_FACING, frame_id, ns, marker_id, stamp, position)
    m.scale.z = height
    m.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
    m.text = text
    return m


def sphere_marker(
    position, frame_id: str, ns: str, marker_id: int, stamp=None, diameter: float = 0.012
) -> Marker:
    m = new_marker(Marker.SPHERE, frame_id, ns, marker_id, stamp, position)
    m.scale.x = m.scale.y = m.scale.z = diameter
    m.color = ColorRGBA(r=0.2, g=0.6, b=1.0, a=1.0)
    return m


# ---------------------------------------------------------------------- stamps, message text
def source_stamp_s(info) -> float | None:
    """The publisher's source time stamp (s) of a received message, if the middleware gave one."""
    try:
        ns = int(info["source_timestamp"])
    except (TypeError, KeyError, ValueError):
        return None
    return ns * 1e-9 if ns > 0 else None


#: the longest ``~/set_dimension`` message read (longer ones are refused unread)
MAX_DIMENSION_TEXT = 64


def parse_dimension(text: str) -> tuple:
    """(name, value in m or None, steps or None) of a ``~/set_dimension`` message:
    "radius=0.045", "x+", "x-". AffordanceError (one line) for anything else."""
    text = str(text)
    if len(text) > MAX_DIMENSION_TEXT:
        raise AffordanceError(
            f"a message of {len(text)} characters; expected NAME=METRES, NAME+ or NAME-"
        )
    text = text.strip()
    if text.endswith(("+", "-")) and text[:-1].strip().isidentifier():
        return text[:-1].strip(), None, 1.0 if text.endswith("+") else -1.0
    name, eq, value = text.partition("=")
    try:
        metres = float(value)
    except ValueError:
        metres = math.nan
    if not eq or not name.strip().isidentifier() or not math.isfinite(metres):
        raise AffordanceError(
            f"expected NAME=METRES, NAME+ or NAME- (e.g. radius=0.045), got {text!r}"
        )
    return name.strip(), metres, None


def header_stamp_s(header) -> float | None:
    """A header's stamp in seconds, None when it has none (zero)."""
    s = header.stamp.sec + header.stamp.nanosec * 1e-9
    return s if s > 0 else None
