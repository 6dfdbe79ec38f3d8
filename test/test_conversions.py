# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Message conversions, without rclpy.init: PointCloud2 layouts, poses, frame graphs."""

import math
import struct

import numpy as np
import pytest
from geometry_msgs.msg import Pose
from sensor_msgs.msg import PointCloud2, PointField

from affordance_registration.core.transforms import make_T, random_rotations
from affordance_registration.ros.glue.conversions import (
    ConversionError,
    matrix_to_pose,
    pointcloud2_to_xyz,
    pose_to_matrix,
    xyz_to_pointcloud2,
)
from affordance_registration.ros.glue.frames import FrameError, FrameGraph, StaticFrames


def _pack(points, layout, point_step, big_endian=False, row_pad=0, width=None):
    """Build a PointCloud2 the slow, obvious way (struct per point) as an independent reference.
    ``layout``: list of (name, offset, datatype, value_fn)."""
    fmt_char = {
        PointField.FLOAT32: "f",
        PointField.FLOAT64: "d",
        PointField.UINT8: "B",
        PointField.UINT32: "I",
    }
    size = {
        PointField.FLOAT32: 4,
        PointField.FLOAT64: 8,
        PointField.UINT8: 1,
        PointField.UINT32: 4,
    }
    order = ">" if big_endian else "<"
    n = len(points)
    width = width or n
    height = n // width
    row_step = width * point_step + row_pad
    data = bytearray(row_step * height)
    for i, p in enumerate(points):
        r, c = divmod(i, width)
        base = r * row_step + c * point_step
        for name, offset, dtype, fn in layout:
            struct.pack_into(order + fmt_char[dtype], data, base + offset, fn(p, i))
    msg = PointCloud2()
    msg.height, msg.width = height, width
    msg.fields = [
        PointField(name=name, offset=off, datatype=dt, count=1) for name, off, dt, _ in layout
    ]
    msg.is_bigendian = big_endian
    msg.point_step, msg.row_step = point_step, row_step
    msg.data = bytes(data)
    assert all(off + size[dt] <= point_step for _, off, dt, _ in layout)
    return msg


XYZ = lambda k: lambda p, i: float(p[k])  # noqa: E731


@pytest.mark.parametrize("big_endian", [False, True])
@pytest.mark.parametrize("dtype", [PointField.FLOAT32, PointField.FLOAT64])
def test_any_layout_with_float_xyz(big_endian, dtype):
    rng = np.random.default_rng(1)
    pts = rng.uniform(-2, 2, (24, 3))
    pts[5] = np.nan
    w = 8 if dtype == PointField.FLOAT64 else 4
    # z before x, an intensity and an rgb field in between, padding at the end of points and rows
    layout = [
        ("rgb", 0, PointField.UINT32, lambda p, i: i),
        ("z", 4, dtype, XYZ(2)),
        ("intensity", 4 + w, PointField.FLOAT32, lambda p, i: 0.5),
        ("x", 8 + w, dtype, XYZ(0)),
        ("y", 8 + 2 * w, dtype, XYZ(1)),
    ]
    msg = _pack(pts, layout, point_step=8 + 3 * w + 5, big_endian=big_endian, row_pad=7, width=6)
    out, shape = pointcloud2_to_xyz(msg)
    assert shape == (4, 6)
    ref = pts.astype(np.float32).astype(float) if dtype == PointField.FLOAT32 else pts
    assert np.array_equal(np.isnan(out), np.isnan(ref))
    assert np.allclose(out[~np.isnan(out)], ref[~np.isnan(ref)], atol=0, rtol=0)


def test_round_trip_organized_with_holes():
    rng = np.random.default_rng(2)
    org = rng.uniform(-1, 1, (5, 7, 3)).astype(np.float32)
    org[1, 2] = np.nan
    msg = xyz_to_pointcloud2(org, "cam")
    assert msg.header.frame_id == "cam" and not msg.is_dense
    out, shape = pointcloud2_to_xyz(msg)
    assert shape == (5, 7)
    assert np.array_equal(out.reshape(5, 7, 3), org.astype(float), equal_nan=True)
    flat = xyz_to_pointcloud2(org.reshape(-1, 3), "cam")
    assert pointcloud2_to_xyz(flat)[1] is None


def test_malformed_clouds_raise_clear_errors():
    good = xyz_to_pointcloud2(np.zeros((4, 3)), "cam")
    short = xyz_to_pointcloud2(np.zeros((4, 3)), "cam")
    short.data = bytes(len(good.data) - 1)
    with pytest.raises(ConversionError, match="disagree|header says"):
        pointcloud2_to_xyz(short)
    no_z = xyz_to_pointcloud2(np.zeros((4, 3)), "cam")
    no_z.fields = no_z.fields[:2]
    with pytest.raises(ConversionError, match="no z field"):
        pointcloud2_to_xyz(no_z)
    ints = xyz_to_pointcloud2(np.zeros((4, 3)), "cam")
    ints.fields = [
        PointField(name=n, offset=4 * i, datatype=PointField.INT32, count=1)
        for i, n in enumerate("xyz")
    ]
    with pytest.raises(ConversionError, match="FLOAT32"):
        pointcloud2_to_xyz(ints)
    narrow = xyz_to_pointcloud2(np.zeros((4, 3)), "cam")
    narrow.row_step = 8
    with pytest.raises(ConversionError, match="row_step"):
        pointcloud2_to_xyz(narrow)


def test_pose_round_trip_and_bad_poses():
    rng = np.random.default_rng(3)
    for R in random_rotations(20, rng):
        T = make_T(R, rng.normal(size=3))
        assert np.allclose(pose_to_matrix(matrix_to_pose(T)), T, atol=1e-12)
    p = Pose()
    p.orientation.w = 2.0
    with pytest.raises(ConversionError, match="unit quaternion"):
        pose_to_matrix(p)
    p.orientation.w = 1.0
    p.position.x = math.nan
    with pytest.raises(ConversionError, match="NaN"):
        pose_to_matrix(p)


def test_static_frames_follow_chains_both_ways():
    frames = StaticFrames(
        ["map cam 1 0 0 0 0 0 1", "cam tool 0 0 0.5 0 0 0.7071068 0.7071068", ""]
    )
    T = frames.lookup("map", "tool")  # T_map_tool
    assert np.allclose(T[:3, 3], [1, 0, 0.5])
    assert np.allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-6)
    assert np.allclose(frames.lookup("tool", "map") @ T, np.eye(4), atol=1e-9)
    with pytest.raises(FrameError, match="'elsewhere'"):
        frames.lookup("map", "elsewhere")


def test_frame_graph_keeps_one_parent_per_child_and_merges():
    tf = FrameGraph()
    tf.set("map", "cam", make_T(np.eye(3), [1.0, 0.0, 0.0]))
    tf.set("/map", "/cam", make_T(np.eye(3), [2.0, 0.0, 0.0]))  # the newer transform wins
    assert len(tf) == 1 and np.allclose(tf.lookup("map", "cam")[:3, 3], [2, 0, 0])
    param = StaticFrames(["map cam 5 0 0 0 0 0 1", "cam tool 0 0 1 0 0 0 1"])
    both = param.merged(tf)  # TF wins over the parameter
    assert np.allclose(both.lookup("map", "tool")[:3, 3], [2, 0, 1])
    assert np.allclose(both.lookup("tool", "map")[:3, 3], [-2, 0, -1])
    with pytest.raises(FrameError):
        tf.lookup("map", "tool")
