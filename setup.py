"""ament_python build of gpf_nav; also a plain pip-installable package (see README)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "gpf_nav"
# What rosidl_generate_interfaces needs from PyPI (the wheels do not all declare their dependencies).
INTERFACE_BUILD = [
    "ament-package", "ament-cmake", "ament-cmake-core", "ament-cmake-export-definitions",
    "ament-cmake-export-dependencies", "ament-cmake-export-include-directories", "ament-cmake-export-interfaces",
    "ament-cmake-export-libraries", "ament-cmake-export-link-flags", "ament-cmake-export-targets",
    "ament-cmake-gen-version-h", "ament-cmake-include-directories", "ament-cmake-libraries", "ament-cmake-python",
    "ament-cmake-target-dependencies", "ament-cmake-test", "ament-cmake-version", "ament-cmake-ros",
    "ament-cmake-gmock", "ament-cmake-gtest", "ament-cmake-pytest", "ament-cmake-vendor-package", "gmock-vendor",
    "gtest-vendor", "fastrtps-cmake-module", "python-cmake-module", "rpyutils", "rosidl-cmake",
    "rosidl-core-generators", "rosidl-default-generators", "rosidl-generator-py",
    "rosidl-generator-type-description", "rosidl-typesupport-fastrtps-c", "rosidl-typesupport-fastrtps-cpp",
    "rosidl-typesupport-introspection-c", "rosidl-typesupport-introspection-cpp",
]

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
    install_requires=["setuptools", "numpy", "scipy", "threadpoolctl", "numba"],
    extras_require={
        # ROS 2 Jazzy Python client from PyPI, for machines without a system ROS installation; rosbags
        # (pure Python rosbag2 reader/writer) for gpf-nav record / replay.
        "ros": ["ros-jazzy-rclpy[fastrtps]", "ros-jazzy-common-interfaces", "rosbags"],
        "experiments": ["matplotlib", "tqdm", "dask[distributed]"],
        # mcap-ros2-support: an independent reader of the bags gpf-nav replay writes. The rosidl/ament
        # wheels: test/interfaces.py builds tf2_msgs (no wheel) with them, for the TF test.
        "test": ["pytest", "hypothesis", "wheel", "colcon-core", "colcon-ros", "colcon-package-selection",
                 "colcon-bash", "mcap-ros2-support"] + ["ros-jazzy-" + name for name in INTERFACE_BUILD],
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
