# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Templates drawn by reference (MESH_RESOURCE naming the template's mesh files, CUBE and
CYLINDER for primitives) draw the same surface the triangles did: what the station rebuilds
from the markers, placed in the cloud frame, is the template's mesh at its pose, joint value and
scale -- for every bundled template, any pose, joint value and scale."""

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from affordance_registration.core.transforms import make_T
from affordance_registration.ros.glue.conversions import ConversionError
from affordance_registration.ros.glue.mesh_refs import mesh_uri, referenced_mesh, template_markers
from affordance_registration.ros.station.state import apply_markers

GREY = ColorRGBA(r=0.5, g=0.5, b=0.5, a=1.0)


def _world(drawings) -> np.ndarray:
    """Every drawn triangle corner in the cloud frame."""
    return np.vstack(
        [d.vertices.astype(float) @ d.T[:3, :3].T + d.T[:3, 3] for d in drawings.values()]
    )


def _same_surface(drawn: np.ndarray, mesh, T) -> None:
    """The same triangle corners: as many, and each one's nearest in the other set within
    20 um (float32 corners)."""
    from scipy.spatial import cKDTree

    truth = (
        np.asarray(mesh.vertices)[np.asarray(mesh.faces)].reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    )
    assert len(drawn) == len(truth)
    assert cKDTree(truth).query(drawn)[0].max() < 2e-5
    assert cKDTree(drawn).query(truth)[0].max() < 2e-5


def _pose(rotvec, t):
    from scipy.spatial.transform import Rotation

    return make_T(Rotation.from_rotvec(rotvec).as_matrix(), np.asarray(t))


vectors = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3)


@settings(max_examples=25, deadline=None)
@given(
    name=st.sampled_from(
        ["ball_valve", "quarter_turn_valve", "gate_valve", "emergency_stop", "grab_handle"]
    ),
    rotvec=vectors,
    t=vectors,
    u=st.floats(0.0, 1.0),
    scale=st.floats(0.8, 1.25),
)
def test_a_mesh_template_by_reference_draws_its_mesh(library, name, rotvec, t, u, scale):
    tpl = library[name]
    T = _pose(rotvec, t)
    q = 0.0 if tpl.joint is None else tpl.joint.lower + u * (tpl.joint.upper - tpl.joint.lower)
    markers = template_markers(tpl, T, q, scale, "cam", "candidate", 1, GREY, GREY, None)
    assert all(m.type == Marker.MESH_RESOURCE and not m.points for m in markers)
    assert all(m.mesh_resource.startswith("file://") for m in markers)  # no ament index here
    assert len(markers) == (1 if tpl.joint is None else 2)
    drawn = apply_markers({}, MarkerArray(markers=markers))
    # a jointed template: its fixed part and its moving part at q (what mesh_at(q) joins)
    truth = (
        tpl.mesh_at(q, scale)
        if tpl.joint is None
        else trimesh.util.concatenate(
            [tpl.base_mesh.copy().apply_scale(scale), tpl.moving_mesh_at(q, scale)]
        )
    )
    _same_surface(_world(drawn), truth, T)


@settings(max_examples=15, deadline=None)
@given(
    kind=st.sampled_from(["box", "cylinder"]),
    rotvec=vectors,
    t=vectors,
    a=st.floats(0.02, 0.3),
    b=st.floats(0.02, 0.3),
    c=st.floats(0.02, 0.3),
)
def test_a_primitive_is_drawn_as_its_shape_at_its_size(library, kind, rotvec, t, a, b, c):
    dims = (
        {"x": max(a, b), "y": min(a, b), "z": c}
        if kind == "box"
        else {"radius": a / 2, "length": c}
    )
    tpl = library[kind].sized(dims)
    T = _pose(rotvec, t)
    (m,) = template_markers(tpl, T, 0.0, 1.0, "cam", "candidate", 1, GREY, GREY, None)
    assert m.type == (Marker.CUBE if kind == "box" else Marker.CYLINDER)
    drawn = apply_markers({}, MarkerArray(markers=[m]))
    world = _world(drawn)
    mesh = tpl.mesh_at(0.0, 1.0)
    # the same solid in the template's frame: bounds, and for a cylinder the axis and radius
    local = (world - T[:3, 3]) @ T[:3, :3]
    np.testing.assert_allclose(local.min(axis=0), mesh.bounds[0], atol=1e-5)
    np.testing.assert_allclose(local.max(axis=0), mesh.bounds[1], atol=1e-5)
    if kind == "cylinder":
        np.testing.assert_allclose(
            np.linalg.norm(local[:, :2], axis=1).max(), tpl.dimensions["radius"], rtol=1e-5
        )


def test_geometry_not_read_from_files_keeps_its_triangles(library):
    """A template made in code (a stretched variant: its mesh is no file's) is drawn as
    triangles; a copy with a scale range has the same geometry, and the same files."""
    from affordance_registration.core.affordance_template import AffordanceTemplate

    tpl = library["grab_handle"]
    assert set(tpl.mesh_files) == {"mesh"} and set(library["ball_valve"].mesh_files) == {
        "mesh",
        "base_mesh",
        "moving_mesh",
    }
    assert tpl.with_scale_range((0.8, 1.2)).mesh_files == tpl.mesh_files
    stretched = AffordanceTemplate(tpl.name, tpl.path, tpl.mesh.copy().apply_scale(1.3))
    (m,) = template_markers(
        stretched, np.eye(4), 0.0, 1.0, "cam", "candidate", 1, GREY, GREY, None
    )
    assert m.type == Marker.TRIANGLE_LIST and len(m.points) == 3 * len(stretched.mesh.faces)


def test_a_marker_naming_a_missing_or_foreign_file_is_left_out(tmp_path):
    for uri in (
        f"file://{tmp_path}/gone.stl",
        "http://example.com/valve.stl",
        f"file://{tmp_path}/notes.txt",
        "package://no_such_package/x.stl",
    ):
        m = Marker(
            type=Marker.MESH_RESOURCE, action=Marker.ADD, ns="candidate", id=1, mesh_resource=uri
        )
        m.scale.x = m.scale.y = m.scale.z = 1.0
        with pytest.raises(ConversionError):
            referenced_mesh(m)
        assert apply_markers({}, MarkerArray(markers=[m])) == {}


def test_uris(tmp_path):
    assert mesh_uri(str(tmp_path / "a.stl")) == f"file://{tmp_path}/a.stl"
