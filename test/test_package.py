"""Both ROS packages are well formed, and colcon builds them as on a ROS 2 installation."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from xml.etree import ElementTree

import okid_ros

ROOT = Path(__file__).resolve().parent.parent
MSG_DIR = ROOT / "msg_defs"


def _package_xml(path: Path) -> ElementTree.Element:
    root = ElementTree.parse(path).getroot()
    assert root.tag == "package" and root.get("format") == "3", path
    return root


def _dependencies(root: ElementTree.Element) -> set[str]:
    tags = ("depend", "exec_depend", "build_depend", "buildtool_depend")
    return {element.text for tag in tags for element in root.iter(tag)}


def test_okid_ros_package_xml() -> None:
    root = _package_xml(ROOT / "package.xml")
    assert root.findtext("name") == "okid_ros"
    assert root.findtext("export/build_type") == "ament_python"
    required = {"rclpy", "std_msgs", "sensor_msgs", "geometry_msgs", "diagnostic_msgs",
                "okid_msgs", "python3-numpy", "python3-scipy"}
    assert required <= _dependencies(root)


def test_okid_msgs_package_xml_and_cmake() -> None:
    root = _package_xml(MSG_DIR / "package.xml")
    assert root.findtext("name") == "okid_msgs"
    assert root.findtext("export/build_type") == "ament_cmake"
    assert root.findtext("member_of_group") == "rosidl_interface_packages"
    assert {"ament_cmake", "rosidl_default_generators", "std_msgs"} <= _dependencies(root)
    # every .msg file is generated, and nothing that is not there
    listed = set(re.findall(r'"(msg/\w+\.msg)"', (MSG_DIR / "CMakeLists.txt").read_text()))
    present = {f"msg/{p.name}" for p in (MSG_DIR / "msg").glob("*.msg")}
    assert listed == present


def test_versions_agree() -> None:
    version = _package_xml(ROOT / "package.xml").findtext("version")
    assert okid_ros.__version__ == version
    assert metadata.version("okid_ros") == version


def test_ament_resource_marker() -> None:
    assert (ROOT / "resource" / "okid_ros").is_file()


def test_colcon_builds_both_packages(tmp_path: Path) -> None:
    """The system-ROS route: `colcon build --base-paths . msg_defs`, then the overlay works.

    On the pip route the venv plays the part of /opt/ros/jazzy. Builds into tmp_path.
    """
    colcon = shutil.which("colcon") or str(Path(sys.executable).parent / "colcon")
    env = dict(os.environ)
    if "AMENT_PREFIX_PATH" not in env:  # pip route: nothing sourced, ROS lives in the venv
        env["AMENT_PREFIX_PATH"] = env["CMAKE_PREFIX_PATH"] = sys.prefix
    # colcon runs make with -jN -lN (N cores) unless MAKEFLAGS says otherwise; -l held the build to
    # one job whenever the load average (this test run's own processes included) was above N.
    env.setdefault("MAKEFLAGS", f"-j{os.cpu_count() or 1}")
    build = subprocess.run(
        [colcon, "--log-base", str(tmp_path / "log"), "build",
         "--base-paths", ".", "msg_defs",
         "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install"),
         "--event-handlers", "console_direct-",
         "--cmake-args", f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF"],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stdout + build.stderr
    assert "2 packages finished" in build.stdout, build.stdout

    install = tmp_path / "install"
    share = install / "okid_ros" / "share"
    assert (share / "ament_index" / "resource_index" / "packages" / "okid_ros").is_file()
    assert (share / "okid_ros" / "package.xml").is_file()
    for script in ("okid-ros", "arx_identifier", "modal_estimator"):  # for `ros2 run`
        assert (install / "okid_ros" / "lib" / "okid_ros" / script).is_file(), script

    # Sourced overlay: both packages import from install/, and the installed script runs.
    # Run from tmp_path so the source tree is not on sys.path.
    check = (
        f"source {install}/setup.bash && "
        f"{sys.executable} -c 'import okid_msgs.msg, okid_ros; "
        "print(okid_msgs.__file__); print(okid_ros.__file__)' && "
        f"{install}/okid_ros/lib/okid_ros/okid-ros --version"
    )
    result = subprocess.run(["bash", "-c", check], cwd=tmp_path, env=env, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    msgs_file, ros_file, version_line = result.stdout.splitlines()[-3:]
    assert msgs_file.startswith(str(install / "okid_msgs")), result.stdout
    assert ros_file.startswith(str(install / "okid_ros")), result.stdout
    assert version_line == f"okid-ros {okid_ros.__version__}"


def _pins(name: str) -> set[str]:
    lines = (ROOT / "requirements" / name).read_text().splitlines()
    return {line.split("==")[0].strip().lower() for line in lines if line.strip() and not line.startswith("#")}


def test_runtime_requirements_leave_tests_and_benchmarks_out() -> None:
    runtime, test = _pins("python.txt"), _pins("test.txt")
    assert {"numpy", "scipy", "filterpy", "pyyaml", "rosbags"} <= runtime
    assert {"pytest", "ruff", "control", "sippy-unipi", "nfoursid", "pandas"} <= test
    assert not runtime & test
    lock = _pins("lock.txt")
    assert runtime | test <= lock  # every pin has its transitive dependencies locked
