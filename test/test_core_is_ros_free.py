"""core/ never imports ROS: checked in a fresh interpreter."""
import subprocess
import sys


def test_importing_core_loads_no_ros():
    code = (
        "import sys, importlib, pkgutil\n"
        "import affordance_registration.core as core\n"
        "for m in pkgutil.walk_packages(core.__path__, 'affordance_registration.core.'):\n"
        "    importlib.import_module(m.name)\n"
        "import affordance_registration.bench\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in ('rclpy', 'sensor_msgs', "
        "'geometry_msgs', 'visualization_msgs', 'std_msgs', 'std_srvs', 'viser')]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"core pulled in ROS modules: {out.stdout.strip()}"
