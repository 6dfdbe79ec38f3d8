# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Property-based fuzzing of every input format the product reads: PointCloud2 layouts, template
YAML, launch YAML, bag metadata and the command line. Whatever arrives, the answer is a result or
one clear package error -- never another exception, a hang or a traceback."""

import os
import shutil
import tempfile

import numpy as np
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from sensor_msgs.msg import PointCloud2, PointField

from affordance_registration.core.errors import TemplateError
from affordance_registration.core.templates import load_template
from affordance_registration.ros.glue.conversions import (
    ConversionError,
    pointcloud2_to_xyz,
    xyz_to_pointcloud2,
)
from affordance_registration.ros.standins.bag import BagError, bag_info
from affordance_registration.ros.standins.launcher import LaunchError, parse_launch_file

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
MODELS = os.path.join(os.path.dirname(__file__), "..", "models")

# YAML-able values: scalars of every kind (huge, NaN, negative, text) and small nestings
scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**12), 10**12),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.sampled_from(
        [1e300, -1e300, 0, -1, "../x.stl", "/etc/passwd", "$(env HOME)", "$(var x)", "$(", ")"]
    ),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)


# ---------------------------------------------------------------------------- PointCloud2
@st.composite
def clouds(draw):
    """A PointCloud2 whose header may or may not fit its data."""
    names = draw(st.lists(st.sampled_from(["x", "y", "z", "rgb", "intensity", ""]), max_size=6))
    fields = [
        PointField(
            name=n,
            offset=draw(st.integers(0, 40)),
            datatype=draw(st.integers(0, 9)),
            count=draw(st.integers(0, 3)),
        )
        for n in names
    ]
    msg = PointCloud2(
        height=draw(st.integers(0, 4)),
        width=draw(st.integers(0, 6)),
        point_step=draw(st.integers(0, 48)),
        is_bigendian=draw(st.booleans()),
    )
    msg.fields = fields
    msg.row_step = draw(st.one_of(st.just(msg.width * msg.point_step), st.integers(0, 400)))
    size = draw(st.one_of(st.just(msg.row_step * msg.height), st.integers(0, 600)))
    msg.data = bytes(draw(st.binary(min_size=size, max_size=size)))
    return msg


@FUZZ
@given(clouds())
def test_any_pointcloud2_layout_converts_or_says_why(msg):
    try:
        pts, organized = pointcloud2_to_xyz(msg)
    except ConversionError as exc:
        assert str(exc) and "\n" not in str(exc)
        return
    assert pts.shape == (msg.height * msg.width, 3) and pts.dtype == np.float64


@FUZZ
@given(
    st.integers(1, 5),
    st.integers(1, 7),
    st.lists(st.floats(-1e6, 1e6, width=32), min_size=3, max_size=3),
)
def test_clouds_round_trip(h, w, xyz):
    points = np.tile(np.asarray(xyz, np.float32), (h, w, 1))
    back, organized = pointcloud2_to_xyz(xyz_to_pointcloud2(points, "f"))
    assert np.array_equal(back.reshape(h, w, 3), points.astype(np.float64))


# ---------------------------------------------------------------------------- templates
@FUZZ
@given(
    doc=st.dictionaries(
        st.sampled_from(
            [
                "name",
                "mesh",
                "mesh_scale",
                "symmetry",
                "joints",
                "states",
                "scale",
                "base_mesh",
                "description",
                "allow_external_files",
                "other",
            ]
        ),
        values,
        max_size=7,
    ),
    mesh=st.sampled_from(["meshes/ball_valve.stl", "meshes/grab_handle.stl", "x.ply"]),
    raw=st.one_of(st.none(), st.binary(max_size=64)),
)
# (found by this test: a NUL in the mesh's path was a ValueError from os.path, a traceback)
@example(doc={"mesh": "\x00", "name": "0"}, mesh="meshes/ball_valve.stl", raw=None)
@example(doc={"base_mesh": "a\x00b"}, mesh="meshes/ball_valve.stl", raw=None)
def test_any_template_file_loads_or_names_file_and_key(doc, mesh, raw):
    with tempfile.TemporaryDirectory() as d:
        shutil.copytree(os.path.join(MODELS, "meshes"), os.path.join(d, "meshes"))
        with open(os.path.join(d, "x.ply"), "wb") as handle:  # a random "point cloud"
            handle.write(
                b"ply\nformat ascii 1.0\nelement vertex 12\nproperty float x\n"
                b"property float y\nproperty float z\nend_header\n" + (raw or b"")
            )
        doc.setdefault("mesh", mesh)
        path = os.path.join(d, "t.yaml")
        with open(path, "wb") as handle:
            handle.write(
                raw if raw is not None and len(raw) % 3 == 0 else yaml.safe_dump(doc).encode()
            )
        try:
            tpl = load_template(path)
        except TemplateError as exc:
            assert str(exc).startswith(path) and "\n" not in str(exc)
            return
        assert np.isfinite(tpl.diameter) and 0 < tpl.diameter <= 100 * 1.8


# ---------------------------------------------------------------------------- launch files
@FUZZ
@given(
    st.one_of(
        values,
        st.fixed_dictionaries(
            {
                "launch": st.lists(
                    st.one_of(
                        values,
                        st.dictionaries(
                            st.sampled_from(["arg", "node", "include"]), values, max_size=2
                        ),
                    ),
                    max_size=4,
                )
            }
        ),
    ),
    st.dictionaries(st.text(max_size=5), st.text(max_size=5), max_size=2),
)
def test_any_launch_file_parses_or_says_why(doc, arguments):
    with tempfile.NamedTemporaryFile("w", suffix=".launch.yaml", delete=False) as handle:
        yaml.safe_dump(doc, handle)
    try:
        nodes = parse_launch_file(handle.name, arguments)
        for node in nodes:
            node.command()
    except LaunchError as exc:
        assert str(exc) and "\n" not in str(exc)
    finally:
        os.unlink(handle.name)


# ---------------------------------------------------------------------------- bags
@FUZZ
@given(
    st.one_of(values, st.fixed_dictionaries({"rosbag2_bagfile_information": values})),
    st.binary(max_size=200),
)
def test_any_bag_folder_reads_or_says_why(meta, storage):
    with tempfile.TemporaryDirectory() as d:
        with open(os.path.join(d, "metadata.yaml"), "w") as handle:
            yaml.safe_dump(meta, handle)
        with open(os.path.join(d, "bag.mcap"), "wb") as handle:
            handle.write(storage)
        try:
            info = bag_info(d)
        except BagError as exc:
            assert str(exc) and "\n" not in str(exc)
            return
        assert info["messages"] >= 0


# ---------------------------------------------------------------------------- command line
@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
@given(
    kind=st.sampled_from(["ply", "pcd", "npy"]),
    count=st.integers(-5, 10**10),
    body=st.binary(max_size=300),
    point=st.lists(
        st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=6)),
        min_size=3,
        max_size=3,
    ),
)
def test_fit_on_any_file_and_point_answers_in_one_line(kind, count, body, point, capsys):
    from affordance_registration.cli import main

    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, f"scene.{kind}")
        with open(path, "wb") as handle:
            if kind == "ply":
                handle.write(
                    f"ply\nformat binary_little_endian 1.0\nelement vertex {count}\n"
                    "property float x\nproperty float y\nproperty float z\n"
                    "end_header\n".encode()
                )
            elif kind == "pcd":
                handle.write(
                    f"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                    f"WIDTH {count}\nHEIGHT 1\nPOINTS {count}\nDATA binary\n".encode()
                )
            handle.write(body)
        try:
            code = main(["fit", "--scene", path, "--point", *map(str, point)])
        except SystemExit as exc:  # argparse refuses a point that is not 3 numbers
            code = exc.code
    err = capsys.readouterr().err
    assert code in (0, 2), (code, err)
    if code:
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1 and "Traceback" not in err, err
