"""The distribution installs every package folder and keeps generic names out of site-packages."""

import re
import subprocess
import sys
from pathlib import Path

import tomllib

from tests.helpers import run_python_without

ROOT = Path(__file__).resolve().parents[1]


def _declared():
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return set(data["tool"]["setuptools"]["packages"]), data["tool"]["setuptools"]["package-dir"]


def test_every_package_folder_is_listed():
    packages, mapping = _declared()
    found = set()
    for top, folder in mapping.items():
        base = ROOT / folder
        for init in base.rglob("__init__.py"):
            found.add(".".join([top, *init.parent.relative_to(base).parts]))
    missing = sorted(found - packages)
    assert not missing, f"add these to [tool.setuptools] packages in pyproject.toml: {missing}"


def test_no_generic_top_level_names_installed():
    packages, _ = _declared()
    assert all(p == "aes_planner" or p.startswith("aes_planner.") for p in packages)


def test_import_core_without_hardware_sdk():
    # The core must import without dynamixel-sdk: block it and import everything hardware-free.
    code = (
        "import aes_planner, aes_planner.geometry, aes_planner.cli, aes_planner.devices\n"
        "import aes_planner.cli.gimbal\n"
        "print('ok')"
    )
    out = run_python_without(("dynamixel_sdk", "serial"), code)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_cli_version():
    out = subprocess.run([sys.executable, "-m", "aes_planner", "--version"], capture_output=True, text=True)
    assert out.returncode == 0
    assert re.match(r"aes-planner \d+\.\d+", out.stdout)


def test_hardware_bridge_imports_without_torch():
    # A driver process must start fast, even on a small computer: no torch, no numpy.
    code = (
        "import sys\n"
        "import aes_planner.drivers.dynamixel, aes_planner.drivers.emulator, aes_planner.cli.gimbal\n"
        "from aes_planner.geometry import JointLimits, PanTiltConfig\n"
        "print(sorted(m for m in ('torch', 'numpy') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_the_interface_package_has_one_source_of_its_msg_files():
    """ros2/aes_planner_msgs/msg (what colcon builds) is the package's own aes_planner/ros2/msg
    (what a rosbag2 export's schemas read), not a copy that can drift."""
    msg = ROOT / "ros2" / "aes_planner_msgs" / "msg"
    assert msg.is_symlink() and msg.resolve() == (ROOT / "aes_planner" / "ros2" / "msg").resolve()
    assert sorted(p.name for p in msg.iterdir()) == ["ViewCandidate.msg", "ViewSuggestion.msg"]
