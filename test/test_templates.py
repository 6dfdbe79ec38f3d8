# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Template files: loading, validation errors that name file and key, samples, diameter,
symmetry."""

import math
import os
import shutil

import numpy as np
import pytest
import trimesh
import yaml
from scipy.spatial import cKDTree

from affordance_registration.core.errors import TemplateError
from affordance_registration.core.templates import TemplateLibrary, load_template
from affordance_registration.evaluation.simulation import mesh_distance

TASKBOARD = {"gate_valve", "ball_valve", "quarter_turn_valve", "emergency_stop", "grab_handle"}


@pytest.fixture(scope="module")
def library():
    """The taskboard templates of the package library (its primitives have tests of their own,
    test_primitives.py)."""
    return TemplateLibrary.load().specific()


def test_package_library_has_the_five_taskboard_objects(library):
    assert set(library) == TASKBOARD
    assert set(TemplateLibrary.load()) == TASKBOARD | {"box", "cylinder"}
    for tpl in library.values():
        assert tpl.mesh.is_watertight, tpl.name
        assert 0.05 <= tpl.diameter <= 0.35, (tpl.name, tpl.diameter)
        z = tpl.mesh.vertices[:, 2]
        assert abs(z.min()) < 1e-6, f"{tpl.name}: base not at z=0"
        # origin at the centre of the mounting base
        base = tpl.mesh.vertices[z < 1e-6]
        assert np.linalg.norm(base[:, :2].mean(axis=0)) < 0.01, tpl.name
        assert tpl.description


def test_articulated_templates_declare_joints_and_states(library):
    for name in ("gate_valve", "ball_valve", "quarter_turn_valve", "emergency_stop"):
        tpl = library[name]
        assert len(tpl.joints) == 1 and tpl.states, name
        j = tpl.joints[0]
        assert j.lower < j.upper and j.torque_limit > 0
        assert j.moving_mesh.is_watertight
    assert set(library["ball_valve"].states) == {"open", "closed"}
    assert set(library["emergency_stop"].states) == {"pressed", "released"}
    assert library["ball_valve"].nearest_state({"lever": 1.4}) == "closed"
    assert library["ball_valve"].nearest_state({"lever": 0.1}) == "open"


def test_samples_lie_on_the_surface_and_are_cached(library):
    for tpl in library.values():
        pts, nrm = tpl.samples(500, seed=3)
        assert pts.shape == (500, 3) and nrm.shape == (500, 3)
        d = mesh_distance(tpl.mesh, pts)  # float32 inside Open3D
        assert np.median(d) < 1e-6 and d.max() < 2e-4
        assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0)
        # normals point outwards: a step along them leaves the solid
        assert np.all(mesh_distance(tpl.mesh, pts + 1e-3 * nrm, signed=True) > 0)
        again, _ = tpl.samples(500, seed=3)
        assert again is pts
        other, _ = tpl.samples(500, seed=4)
        assert not np.allclose(other, pts)


def test_diameter_matches_the_mesh(library):
    for tpl in library.values():
        v = tpl.mesh.vertices
        brute = np.sqrt(((v[:, None] - v[None]) ** 2).sum(-1)).max()  # all vertex pairs
        assert tpl.diameter == pytest.approx(brute, rel=1e-9)


def test_symmetry_rotations_map_the_mesh_onto_itself(library):
    """Surface samples turned by a symmetry rotation stay on the surface (up to the mesh's
    polygonal approximation of round parts); turned by a non-symmetry they leave it."""
    for tpl in library.values():
        pts = tpl.samples(3000, seed=5)[0]
        if tpl.symmetry is None:
            # no symmetry claimed: a half turn about z visibly changes the shape
            R = trimesh.transformations.rotation_matrix(math.pi, [0, 0, 1])[:3, :3]
            assert np.percentile(mesh_distance(tpl.mesh, pts @ R.T), 95) > 0.004, tpl.name
            continue
        for R in tpl.symmetry.rotations[1:]:
            d = mesh_distance(tpl.mesh, pts @ R.T)
            assert np.percentile(d, 99) < 5e-4 and d.max() < 2e-3, tpl.name
        half_step = 2 * math.pi / tpl.symmetry.order / 2
        R = trimesh.transformations.rotation_matrix(half_step / 2, [0, 0, 1])[:3, :3]
        assert np.percentile(mesh_distance(tpl.mesh, pts @ R.T), 95) > 0.002, tpl.name


def test_symmetry_residual_angle():
    from affordance_registration.core.templates import Symmetry
    from affordance_registration.core.transforms import axis_angle_matrix

    four = Symmetry(axis=(0.0, 0.0, 1.0), order=4)
    assert four.residual_angle(axis_angle_matrix([0, 0, 1], math.pi / 2)) == pytest.approx(
        0, abs=1e-7
    )
    assert four.residual_angle(axis_angle_matrix([0, 0, 1], math.radians(50))) == pytest.approx(
        math.radians(40), abs=1e-7
    )
    cont = Symmetry(axis=(0.0, 0.0, 1.0), continuous=True)
    assert cont.residual_angle(axis_angle_matrix([0, 0, 1], 1.234)) == pytest.approx(0, abs=1e-7)
    tilt = axis_angle_matrix([1, 0, 0], 0.2) @ axis_angle_matrix([0, 0, 1], 2.0)
    assert cont.residual_angle(tilt) == pytest.approx(0.2, abs=1e-7)


def test_a_symmetry_axis_passes_through_its_declared_point(tmp_path, library):
    """The grab handle written in millimetres with its origin moved off the handle (by 300, -200,
    100 mm) declares its symmetry's point there: its symmetry motions map the handle onto
    itself, and a pose composed with one of them is the same pose to ``pose_error``; declared
    through the origin (the default), the same half turn moves the handle off itself."""
    from affordance_registration.core.transforms import make_T, pose_error

    shift = np.array([300.0, -200.0, 100.0])  # mm
    mesh = library["grab_handle"].mesh.copy()
    mesh.apply_scale(1000.0)
    mesh.apply_translation(shift)
    mesh.export(tmp_path / "handle.stl")
    doc = {"name": "h", "mesh": "handle.stl", "mesh_scale": 0.001}
    sym = {"axis": [0, 0, 1], "order": 2}
    on = load_template(
        _write(tmp_path, {**doc, "symmetry": {**sym, "point": shift.tolist()}}, mesh=False)
    )
    off = load_template(_write(tmp_path, {**doc, "symmetry": sym}, "off.yaml", mesh=False))
    assert np.allclose(on.symmetry.point, shift / 1000.0)
    pts = on.samples(2000, seed=5)[0]
    S = on.symmetry.transforms[1]
    assert np.percentile(mesh_distance(on.mesh, pts @ S[:3, :3].T + S[:3, 3]), 99) < 5e-4
    S_off = off.symmetry.transforms[1]
    assert np.median(mesh_distance(off.mesh, pts @ S_off[:3, :3].T + S_off[:3, 3])) > 0.3
    T = make_T(trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])[:3, :3], [1.0, 2.0, 3.0])
    dt, dr = pose_error(T @ S, T, on.symmetry)
    assert dt < 1e-12 and dr < 1e-7
    assert pose_error(T @ S, T)[0] > 0.7  # the origins: 2 x 0.37 m apart


def test_a_mount_is_the_files_frame_unless_declared(tmp_path, library):
    """A mesh's mount is its file's frame by default, a point cloud has none, ``mount: none``
    takes it away and a declared one is where the file says; the axes orientations are drawn in
    are the mount's, else the surface's own -- and the resting facets turn with the file: the
    grab handle written turned by R (and moved 5 m) with its mount declared rests in
    R_rest @ R^T."""
    from affordance_registration.core.transforms import make_T
    from affordance_registration.evaluation.simulation import ply_bytes

    handle = library["grab_handle"]
    assert np.array_equal(handle.mount, np.eye(4)) and np.array_equal(handle.axes, np.eye(3))
    (tmp_path / "scan.ply").write_bytes(ply_bytes(handle.samples(3000, seed=2)[0]))
    scan = load_template(_write(tmp_path, {"name": "s", "mesh": "scan.ply"}, "s.yaml", False))
    assert scan.mount is None and scan.axes is scan.own_axes
    R = trimesh.transformations.rotation_matrix(2.0, [1.0, -2.0, 0.5])[:3, :3]
    B = make_T(R, [3.0, -4.0, 0.0])
    handle.mesh.copy().apply_transform(B).export(tmp_path / "moved.stl")
    rpy = trimesh.transformations.euler_from_matrix(B, "sxyz")
    mount = {"position": B[:3, 3].tolist(), "rpy": [float(a) for a in rpy]}
    moved = load_template(
        _write(tmp_path, {"name": "m", "mesh": "moved.stl", "mount": mount}, "m.yaml", False)
    )
    assert np.allclose(moved.mount, B, atol=1e-9) and np.allclose(moved.axes, R, atol=1e-9)
    rests, rests_moved = handle.resting_rotations(), moved.resting_rotations()
    assert len(rests) == len(rests_moved) >= 2
    for (Ra, wa), (Rb, wb) in zip(rests, rests_moved):
        assert np.allclose(Rb, Ra @ R.T, atol=1e-5) and wb == pytest.approx(wa, abs=1e-6)
    bare = load_template(
        _write(tmp_path, {"name": "b", "mesh": "moved.stl", "mount": "none"}, "b.yaml", False)
    )
    assert bare.mount is None
    assert np.allclose(bare.axes, R @ handle.own_axes, atol=1e-6)  # the surface's own, turned


def test_resting_rotations_put_a_facet_down(library):
    for tpl in library.values():
        poses = tpl.resting_rotations()
        assert poses and sum(w for _, w in poses) == pytest.approx(1.0)
        for R, _ in poses:
            v = tpl.mesh.vertices @ R.T
            low = v[:, 2] < v[:, 2].min() + 1e-4
            com = np.asarray(tpl.mesh.center_mass) @ R.T
            # the centre of mass is above the support polygon (its bounding box here)
            sup = v[low, :2]
            assert sup[:, 0].min() - 1e-4 <= com[0] <= sup[:, 0].max() + 1e-4
            assert sup[:, 1].min() - 1e-4 <= com[1] <= sup[:, 1].max() + 1e-4


# ----------------------------------------------------------------------------- bad files
def _write(tmp_path, doc, name="t.yaml", mesh=True):
    if mesh:
        trimesh.creation.box(extents=[0.1, 0.1, 0.05]).export(tmp_path / "box.stl")
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc))
    return str(path)


@pytest.mark.parametrize(
    "doc,key",
    [
        ({"mesh": "box.stl"}, "name"),
        ({"name": "x"}, "mesh"),
        ({"name": "x", "mesh": "missing.stl"}, "mesh"),
        ({"name": "x", "mesh": "box.stl", "mesh_scale": -1}, "mesh_scale"),
        ({"name": "x", "mesh": "box.stl", "mesh_scale": "big"}, "mesh_scale"),
        (
            {"name": "x", "mesh": "box.stl", "symmetry": {"axis": [0, 0, 1], "kind": "helical"}},
            "symmetry",
        ),
        (
            {"name": "x", "mesh": "box.stl", "symmetry": {"axis": [0, 0, 1], "order": 0}},
            "symmetry.order",
        ),
        (
            {"name": "x", "mesh": "box.stl", "symmetry": {"axis": [0, 0, 0], "order": 2}},
            "symmetry.axis",
        ),
        (
            {"name": "x", "mesh": "box.stl", "symmetry": {"order": 2, "point": [0, "a", 0]}},
            "symmetry.point",
        ),
        (
            {"name": "x", "mesh": "box.stl", "symmetry": {"order": 2, "point": [0, 0]}},
            "symmetry.point",
        ),
        ({"name": "x", "mesh": "box.stl", "mount": "sideways"}, "mount"),
        ({"name": "x", "mesh": "box.stl", "mount": {"normal": [0, 0, 1]}}, "mount"),
        ({"name": "x", "mesh": "box.stl", "mount": {"position": [0, 0]}}, "mount.position"),
        (
            {
                "name": "x",
                "mesh": "box.stl",
                "mount": {"rpy": [0, 0, 0], "quaternion": [0, 0, 0, 1]},
            },
            "mount.rpy",
        ),
        (
            {"name": "x", "mesh": "box.stl", "mount": {"quaternion": [0, 0, 0, 2]}},
            "mount.quaternion",
        ),
        (
            {
                "name": "x",
                "primitive": "box",
                "size": {"x": [0.1, 0.2], "y": [0.1, 0.2], "z": [0.1, 0.2]},
                "mount": "none",
            },
            "mount",
        ),
        ({"name": "x", "mesh": "box.stl", "colour": "red"}, "colour"),
        (
            {
                "name": "x",
                "mesh": "box.stl",
                "joints": [
                    {
                        "name": "j",
                        "type": "revolute",
                        "axis": [0, 0, 1],
                        "lower": 1.0,
                        "upper": 0.0,
                        "moving_mesh": "box.stl",
                    }
                ],
            },
            "joints[0].lower/upper",
        ),
        (
            {
                "name": "x",
                "mesh": "box.stl",
                "joints": [
                    {
                        "name": "j",
                        "type": "revolute",
                        "axis": [0, 0, 1],
                        "lower": 0.0,
                        "upper": 1.0,
                    }
                ],
            },
            "joints[0].moving_mesh",
        ),
        (
            {
                "name": "x",
                "mesh": "box.stl",
                "joints": [
                    {
                        "name": "j",
                        "type": "screw",
                        "axis": [0, 0, 1],
                        "lower": 0.0,
                        "upper": 1.0,
                        "moving_mesh": "box.stl",
                    }
                ],
            },
            "joints[0].type",
        ),
        (
            {
                "name": "x",
                "mesh": "box.stl",
                "joints": [
                    {
                        "name": "j",
                        "type": "revolute",
                        "axis": [0, 0, 1],
                        "lower": 0.0,
                        "upper": 1.0,
                        "moving_mesh": "box.stl",
                    }
                ],
                "states": {"open": {"k": 0}},
            },
            "states.open.k",
        ),
    ],
)
def test_bad_template_files_name_the_file_and_key(tmp_path, doc, key):
    path = _write(tmp_path, doc)
    with pytest.raises(TemplateError) as err:
        load_template(path)
    msg = str(err.value)
    assert path in msg and f"key '{key}'" in msg


def test_a_prismatic_joints_states_are_in_the_mesh_units_of_its_limits(tmp_path):
    """A mesh in millimetres (``mesh_scale: 0.001``) with a button that travels 8 (mm): its
    limits, origin and named states are all in those units, and all come out in metres; a
    state past the limits is refused with the limits in the file's units."""
    trimesh.creation.box(extents=[80, 80, 50]).export(tmp_path / "box_mm.stl")
    doc = {
        "name": "stop_mm",
        "mesh": "box_mm.stl",
        "mesh_scale": 0.001,
        "base_mesh": "box_mm.stl",
        "joints": [
            {
                "name": "button",
                "type": "prismatic",
                "axis": [0, 0, -1],
                "origin": [0, 0, 68],
                "lower": 0.0,
                "upper": 8.0,
                "moving_mesh": "box_mm.stl",
            },
            {
                "name": "turn",
                "type": "revolute",
                "axis": [0, 0, 1],
                "lower": 0.0,
                "upper": 1.5,
                "moving_mesh": "box_mm.stl",
            },
        ],
        "states": {"pressed": {"button": 8.0, "turn": 1.5}, "half": {"button": 4}},
    }
    tpl = load_template(_write(tmp_path, doc, mesh=False))
    button = next(j for j in tpl.joints if j.name == "button")
    assert button.upper == pytest.approx(0.008) and button.origin[2] == pytest.approx(0.068)
    assert tpl.states["pressed"] == pytest.approx({"button": 0.008, "turn": 1.5})
    assert tpl.states["half"] == pytest.approx({"button": 0.004})
    doc["states"] = {"through": {"button": 9.0}}
    with pytest.raises(TemplateError, match=r"key 'states.through.button'.*\[0, 8\]"):
        load_template(_write(tmp_path, doc, mesh=False))


def test_a_mesh_that_does_not_load(tmp_path):
    (tmp_path / "broken.stl").write_bytes(
        b"solid x\nfacet normal 0 0 1\n outer loop\n vertex 1 nan"
    )
    path = _write(tmp_path, {"name": "x", "mesh": "broken.stl"}, mesh=False)
    with pytest.raises(TemplateError, match=r"key 'mesh'"):
        load_template(path)


def test_yaml_that_does_not_parse(tmp_path):
    path = _write(tmp_path, "name: [unclosed\n")
    with pytest.raises(TemplateError, match="not valid YAML"):
        load_template(path)
    # a key written twice (PyYAML kept the last one silently)
    path = _write(tmp_path, "name: a\nmesh: box.stl\nname: b\n", name="twice.yaml")
    with pytest.raises(
        TemplateError,
        match=r"twice.yaml: not valid YAML \(line 3\): the key "
        r"'name' is written twice",
    ):
        load_template(path)


def test_duplicate_names_and_empty_directory(tmp_path):
    _write(tmp_path, {"name": "same", "mesh": "box.stl"}, name="a.yaml")
    _write(tmp_path, {"name": "same", "mesh": "box.stl"}, name="b.yaml")
    with pytest.raises(TemplateError, match="duplicate template name 'same'"):
        TemplateLibrary.load(str(tmp_path))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(TemplateError, match="no template files"):
        TemplateLibrary.load(str(empty))


def _pcd_bytes(points: np.ndarray, normals=None, ascii: bool = False) -> bytes:
    """A PCD file of points (N, 3), with normal_x.. fields when ``normals`` (N, 3) are given."""
    fields = "x y z" + (" normal_x normal_y normal_z" if normals is not None else "")
    cols = points if normals is None else np.hstack([points, normals])
    k = cols.shape[1]
    header = (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS {fields}\nSIZE {' '.join(['4'] * k)}\n"
        f"TYPE {' '.join(['F'] * k)}\nCOUNT {' '.join(['1'] * k)}\nWIDTH {len(cols)}\n"
        f"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(cols)}\n"
        f"DATA {'ascii' if ascii else 'binary'}\n"
    ).encode()
    if ascii:
        return header + "".join(" ".join(f"{v:.7g}" for v in row) + "\n" for row in cols).encode()
    return header + cols.astype("<f4").tobytes()


@pytest.mark.parametrize("kind", ["ply", "pcd_ascii", "pcd_binary_normals"])
def test_point_cloud_template(tmp_path, library, kind):
    """A scan of an object (PLY without faces, or PCD) is a template, read like a scene: its
    points are the samples; the file's normals are used where it has them, else estimated
    (pointing away from the centroid); and it fits the object in a simulated scan."""
    from affordance_registration.core.registration import Registrar
    from affordance_registration.core.scene import Scene
    from affordance_registration.core.transforms import pose_error
    from affordance_registration.evaluation.simulation import ply_bytes, simulate_taskboard

    pts, true_normals = library["emergency_stop"].samples(3000, seed=9)
    if kind == "ply":
        (tmp_path / "scan.ply").write_bytes(ply_bytes(pts))
    else:
        given = true_normals if kind == "pcd_binary_normals" else None
        (tmp_path / "scan.pcd").write_bytes(_pcd_bytes(pts, given, ascii=kind == "pcd_ascii"))
    mesh = "scan.ply" if kind == "ply" else "scan.pcd"
    path = _write(tmp_path, {"name": "scanned_stop", "mesh": mesh}, mesh=False)
    tpl = load_template(path)
    assert tpl.is_point_template
    s, n = tpl.samples(400)
    d, idx = cKDTree(pts).query(s)
    assert d.max() < 1e-6  # float32 round trip
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    agree = np.einsum("ij,ij->i", n, true_normals[idx])
    if kind == "pcd_binary_normals":
        assert agree.min() > 0.999  # the file's own normals
    else:
        assert np.median(agree) > 0.9  # estimated, outward (mostly right)
    assert tpl.diameter == pytest.approx(library["emergency_stop"].diameter, rel=0.05)
    sim = simulate_taskboard(library, 1001)
    obj = next(o for o in sim.objects if o.template == "emergency_stop")
    lib = TemplateLibrary([tpl] + [library[n] for n in library if n != "emergency_stop"])
    best = Registrar(lib).fit(Scene(sim.points), obj.click).candidates[0]
    assert best.template == "scanned_stop"
    dt, dr = pose_error(best.T_scene_model, obj.T_scene_model, library["emergency_stop"].symmetry)
    assert dt <= 0.005 and dr <= math.radians(5)


def test_scale_converts_mesh_units(tmp_path):
    trimesh.creation.box(extents=[100, 100, 50]).export(tmp_path / "mm.stl")
    path = _write(tmp_path, {"name": "mm", "mesh": "mm.stl", "mesh_scale": 0.001}, mesh=False)
    assert load_template(path).diameter == pytest.approx(math.sqrt(0.1**2 * 2 + 0.05**2))


def test_generator_reproduces_the_committed_library(tmp_path, library):
    from affordance_registration.evaluation.taskboard import write_library

    write_library(str(tmp_path))
    fresh = TemplateLibrary.load(str(tmp_path))
    assert set(fresh) == set(library)
    for name in library:
        assert fresh[name].diameter == pytest.approx(library[name].diameter, abs=1e-6)
        assert abs(fresh[name].mesh.volume - library[name].mesh.volume) < 1e-9
    src = os.path.join(os.path.dirname(library["ball_valve"].path), "ball_valve.yaml")
    assert yaml.safe_load(open(src)) == yaml.safe_load(open(tmp_path / "ball_valve.yaml"))
    shutil.rmtree(tmp_path)


# ----------------------------------------------------------------------------- articulation
def test_part_samples_and_joint_motion(library):
    tpl = library["ball_valve"]
    P, N, moving = tpl.part_samples(1000, seed=1)
    assert 0.05 < moving.mean() < 0.6
    lever = tpl.joints[0].moving_mesh
    assert mesh_distance(lever, P[moving]).max() < 2e-4
    assert mesh_distance(tpl.base_mesh, P[~moving]).max() < 2e-4
    # a quarter turn moves only the lever, about the joint axis through its origin
    P2, N2 = tpl.pose_parts(P, N, moving, q=math.pi / 2)
    assert np.allclose(P2[~moving], P[~moving])
    R = trimesh.transformations.rotation_matrix(math.pi / 2, [0, 0, 1], [0, 0, 0.085])[:3, :3]
    assert np.allclose(P2[moving] - [0, 0, 0.085], (P[moving] - [0, 0, 0.085]) @ R.T, atol=1e-12)
    assert np.allclose(N2[moving], N[moving] @ R.T)
    moved = tpl.mesh_at(math.pi / 2)
    assert mesh_distance(moved, P2[moving]).max() < 2e-4
    # prismatic: the e-stop button pressed 8 mm goes 8 mm down
    stop = library["emergency_stop"]
    P, N, moving = stop.part_samples(500, seed=1)
    P3, _ = stop.pose_parts(P, N, moving, q=0.008)
    assert np.allclose(P3[moving] - P[moving], [0, 0, -0.008])
    # scale about the base origin
    P4, _ = stop.pose_parts(P, N, moving, scale=1.2)
    assert np.allclose(P4, P * 1.2)
    assert stop.mesh_at(0.0, 1.2).extents == pytest.approx(stop.mesh.extents * 1.2)


def test_scale_range_key(tmp_path, library):
    assert all(t.scale_range is None for t in library.values())
    sized = library["grab_handle"].with_scale_range((0.8, 1.25))
    assert sized.scale_range == (0.8, 1.25) and sized.articulated
    assert library["grab_handle"].scale_range is None
    with pytest.raises(TemplateError, match="scale range"):
        library["grab_handle"].with_scale_range((1.2, 0.8))
    good = _write(tmp_path, {"name": "x", "mesh": "box.stl", "scale": [0.8, 1.25]}, name="g.yaml")
    assert load_template(good).scale_range == (0.8, 1.25)
    for bad in ([1.2, 0.8], [0, 1], "big", [1.0]):
        path = _write(tmp_path, {"name": "x", "mesh": "box.stl", "scale": bad})
        with pytest.raises(TemplateError, match=r"key 'scale'"):
            load_template(path)


def test_joints_need_the_fixed_part(tmp_path):
    trimesh.creation.box(extents=[0.02, 0.02, 0.02]).export(tmp_path / "knob.stl")
    path = _write(
        tmp_path,
        {
            "name": "x",
            "mesh": "box.stl",
            "joints": [
                {
                    "name": "j",
                    "type": "revolute",
                    "axis": [0, 0, 1],
                    "lower": 0.0,
                    "upper": 1.0,
                    "moving_mesh": "knob.stl",
                }
            ],
        },
    )
    with pytest.raises(TemplateError, match=r"key 'base_mesh'"):
        load_template(path)
