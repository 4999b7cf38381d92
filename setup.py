"""Build script of the ament_python package okid_ros (colcon on ROS installs, pip otherwise)."""

from glob import glob
from pathlib import Path
from xml.etree import ElementTree

from setuptools import find_packages, setup

PACKAGE = "okid_ros"
# package.xml is the single source of the version, as ROS tooling reads it from there.
VERSION = ElementTree.parse(Path(__file__).with_name("package.xml")).getroot().findtext("version")

setup(
    name=PACKAGE,
    version=VERSION,
    description="Online OKID system identification and modal state estimation for ROS 2",
    license="Apache-2.0",
    python_requires=">=3.10",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    # Paths are relative to this file: pip and colcon both run it from here.
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*.launch.py"))),
        (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml"))),
    ],
    # numpy, scipy, filterpy, rosbags: from rosdep (package.xml) on ROS installs, from
    # requirements/python.txt on the pip route; not repeated here so colcon never resolves them.
    install_requires=["setuptools"],
    # `okid-ros batch --scheduler ADDRESS`: bags as tasks on a Dask distributed cluster
    extras_require={"dask": ["dask[distributed]"]},
    zip_safe=False,
    entry_points={
        "console_scripts": [
            "okid-ros = okid_ros.cli:main",
            # the nodes, for `ros2 run okid_ros <name>` and launch files
            "arx_identifier = okid_ros.nodes.arx_identifier_node:main",
            "modal_estimator = okid_ros.nodes.modal_estimator_node:main",
        ],
    },
)
