# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What an integrator relies on: the package-root imports, requirements.txt equal to setup.py's
pins, package.xml, and the RViz config the README points at."""

import ast
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def _setup_list(name: str) -> list[str]:
    """A list literal assigned at the top of setup.py (read, not executed)."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
            getattr(t, "id", None) == name for t in node.targets
        ):
            return ast.literal_eval(node.value)
    raise AssertionError(f"setup.py has no {name}")


def test_package_root_exports_the_public_api_without_loading_ros():
    code = (
        "import sys\n"
        "import affordance_registration as ar\n"
        "before = sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'open3d') or "
        "m.startswith('affordance_registration.core'))\n"
        "from affordance_registration import AffordanceEngine, TemplateLibrary, Registrar, "
        "FitSettings, Scene\n"
        "from affordance_registration.core.engine import AffordanceEngine as E\n"
        "from affordance_registration.core.templates import TemplateLibrary as T\n"
        "from affordance_registration.core.scene import Scene as S\n"
        "import affordance_registration.core.registration as reg\n"
        "assert (AffordanceEngine, TemplateLibrary, Scene) == (E, T, S)\n"
        "assert (Registrar, FitSettings) == (reg.Registrar, reg.FitSettings)\n"
        "assert set(ar.__all__) <= set(dir(ar))\n"
        "print(','.join(before) + '|' + str('rclpy' in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    loaded_by_root, rclpy_after = out.stdout.strip().split("|")
    assert loaded_by_root == "", f"importing the package root loaded: {loaded_by_root}"
    assert rclpy_after == "False"


def test_unknown_root_attribute_is_an_attribute_error():
    import affordance_registration

    try:
        affordance_registration.NoSuchThing
    except AttributeError as exc:
        assert "NoSuchThing" in str(exc)
    else:
        raise AssertionError("no AttributeError")


def test_requirements_txt_equals_setup_pins():
    lines = [ln.strip() for ln in (ROOT / "requirements.txt").read_text().splitlines()]
    pins = [ln for ln in lines if ln and not ln.startswith("#")]
    core = _setup_list("CORE_REQUIRES")
    assert pins == core
    assert all("==" in pin for pin in pins)


def test_every_new_ros_wheel_is_pinned_exactly():
    for name in ("ROS_REQUIRES", "INTERFACE_BUILD_REQUIRES"):
        for req in _setup_list(name):
            assert req.count("==") == 1 and req.startswith("ros-jazzy-"), req


def test_package_xml_keys():
    """Keys checked against rosdistro's rosdep/base.yaml, python.yaml and jazzy/distribution.yaml:
    python3-hid and python3-manifold3d-pip do not exist there (hidapi's key is python3-hidapi;
    manifold3d is pip-only, via requirements.txt)."""
    root = ET.parse(ROOT / "package.xml").getroot()
    deps = [e.text for e in root if e.tag.endswith("depend")]
    assert "python3-hid" not in deps and "python3-manifold3d-pip" not in deps
    assert {"python3-hidapi", "tf2_msgs", "tf2_ros_py"} <= set(deps)
    assert len(deps) == len(set(deps))


def test_rviz_config_names_the_operator_displays():
    path = ROOT / "launch_configs" / "operator.rviz"
    config = yaml.safe_load(path.read_text())
    manager = config["Visualization Manager"]
    displays = {d["Class"]: d for d in manager["Displays"]}
    assert displays["rviz_default_plugins/PointCloud2"]["Topic"]["Value"] == "/points"
    markers = displays["rviz_default_plugins/MarkerArray"]["Topic"]
    assert markers["Value"] == "/affordance_engine/markers"
    assert markers["Durability Policy"] == "Transient Local"  # the node publishes latched
    interactive = displays["rviz_default_plugins/InteractiveMarkers"]
    assert interactive["Interactive Markers Namespace"] == "/affordance_correction"
    assert displays["rviz_default_plugins/TF"]["Enabled"] is True
    tools = {t["Class"]: t for t in manager["Tools"]}
    assert tools["rviz_default_plugins/PublishPoint"]["Topic"]["Value"] == "/clicked_point"
    assert "launch_configs/operator.rviz" in (ROOT / "README.md").read_text()
