"""pip puts the console scripts on PATH (``<prefix>/bin``), editable or not, in an environment that has
``wheel`` (this one does: the ``test`` extra installs it), which once made pip take the legacy
``setup.py develop`` path and read setup.cfg's colcon-only script directory. pip builds through
pyproject.toml (PEP 517/660) instead. The colcon side (``lib/gpf_nav``) is test_ros_colcon.py.

Offline: ``--no-build-isolation --no-deps`` into a temporary prefix, with this environment's setuptools.
"""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ("gpf-nav", "estimator", "simulator")
PACKAGE_FILES = ("setup.py", "setup.cfg", "pyproject.toml", "package.xml", "resource", "gpf_nav", "config", "launch")


@pytest.fixture
def source(tmp_path) -> Path:
    src = tmp_path / "gpf_nav_src"
    src.mkdir()
    for name in PACKAGE_FILES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(path, src / name)
    return src


@pytest.mark.parametrize("editable", [True, False], ids=["pip install -e", "pip install"])
def test_pip_installs_the_console_scripts_in_bin(tmp_path, source, editable):
    pytest.importorskip("wheel")
    prefix = tmp_path / "prefix"
    cmd = [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--ignore-installed",
           "--no-index", "--prefix", str(prefix)] + (["-e", str(source)] if editable else [str(source)])
    env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_")}
    result = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "setup.py develop" not in result.stdout
    for script in SCRIPTS:
        path = prefix / "bin" / script
        assert path.is_file() and os.access(path, os.X_OK), sorted(p.name for p in prefix.rglob("*"))[:50]
    assert not (prefix / "lib" / "gpf_nav").exists()
    # the installed script runs (here with this interpreter's packages plus the prefix's)
    site = next(prefix.glob("lib/python3*/site-packages"))
    run = subprocess.run([str(prefix / "bin" / "gpf-nav"), "nosuch"], env=dict(env, PYTHONPATH=str(site)),
                         cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "unknown command 'nosuch'" in run.stderr, run.stderr
