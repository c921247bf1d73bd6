"""The package's floors (docs/ros.md, top): a module imports only from its own floor or below, and
nothing below gpf_nav/ros imports rclpy or a ROS message package. Read from the source (every import
statement, lazy ones included), so it needs no ROS."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "gpf_nav"

# floor of each top-level module or sub-package of gpf_nav; a new one must be placed here
FLOORS = {
    "allocator": 0, "arguments": 0, "blas": 0, "collector": 0, "kernels": 0, "linalg": 0, "resampling": 0, "integrity": 0,
    "openmp": 0, "schema": 0,
    "models": 0, "sensors": 0, "sim": 0,
    "filters": 1, "registry": 1,
    "estimator": 2,
    "ros": 3,
    "bags": 4, "tools": 4, "experiments": 4, "cli": 4,
}
ROS_FLOOR = FLOORS["ros"]


def _unit(path: Path) -> str:
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    return parts[0]


def _imports(path: Path) -> list[str]:
    """Absolute names of every module ``path`` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(), str(path))
    package = ["gpf_nav", *path.relative_to(PACKAGE).parent.parts]
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            names += [module] if node.module else [f"{module}.{alias.name}" for alias in node.names]
    return names


MODULES = sorted(p for p in PACKAGE.rglob("*.py") if p.name != "__init__.py" or p.parent != PACKAGE)


def test_every_module_has_a_floor():
    unplaced = {_unit(p) for p in MODULES} - set(FLOORS)
    assert not unplaced, f"gpf_nav.{', gpf_nav.'.join(sorted(unplaced))}: give it a floor in FLOORS"


def test_no_two_modules_share_a_name():
    names = [p.stem for p in MODULES if p.name != "__init__.py"]
    shared = sorted({n for n in names if names.count(n) > 1})
    assert not shared, f"modules sharing a name: {shared}"


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_import_up_a_floor(path):
    floor = FLOORS[_unit(path)]
    for name in _imports(path):
        parts = name.split(".")
        if parts[0] == "gpf_nav" and len(parts) > 1:
            above = FLOORS[parts[1]]
            assert above <= floor, f"{path.name} (floor {floor}) imports {name} (floor {above})"
        elif floor < ROS_FLOOR:
            ros = parts[0] in ("rclpy", "rosbags", "launch", "launch_ros") or parts[0].endswith(
                ("_msgs", "_srvs", "_interfaces"))
            assert not ros, f"{path.name} is below gpf_nav/ros and imports {name}"
