"""pip puts the console scripts on PATH (``<prefix>/bin``), editable or not, in an environment that has
``wheel`` (this one does: the ``test`` extra installs it), which once made pip take the legacy
``setup.py develop`` path and read setup.cfg's colcon-only script directory. pip builds through
pyproject.toml (PEP 517/660) instead. The colcon side (``lib/gpf_nav``) is test_ros_colcon.py.

Offline: ``--no-build-isolation --no-deps`` into a fresh virtual environment without pip
(``pip --python``), with this interpreter's setuptools and wheel visible only while pip builds. The
installed script then runs on that environment alone, so it finds ``gpf_nav`` only if the install put
it there: the test does not depend on this interpreter having ``gpf_nav`` (it once passed only in the
README's venv, where an editable ``gpf_nav`` was already importable, and failed under ``colcon test``).
"""
import os
import shutil
import subprocess
import sys
import venv
from pathlib import Path

import pytest

setuptools = pytest.importorskip("setuptools")
wheel = pytest.importorskip("wheel")

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


def _environment(path: Path) -> Path:
    """A virtual environment without pip at ``path``; returns its site-packages."""
    venv.create(path, with_pip=False, clear=True)
    return next(path.glob("lib/python3*/site-packages"))


@pytest.mark.parametrize("editable", [True, False], ids=["pip install -e", "pip install"])
def test_pip_installs_the_console_scripts_in_bin(tmp_path, source, editable):
    pytest.importorskip("wheel")
    prefix = tmp_path / "env"
    site = _environment(prefix)
    python = prefix / "bin" / "python"
    # the build needs setuptools (and wheel, whose presence once sent pip down the legacy path): this
    # interpreter's, as plain path entries (their .pth files, and any gpf_nav they install, stay unseen)
    borrowed = site / "zz_build_tools.pth"
    borrowed.write_text("\n".join(sorted({str(Path(m.__file__).parents[1]) for m in (setuptools, wheel)})) + "\n")
    cmd = [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-build-isolation",
           "--ignore-installed", "--no-index"] + (["-e", str(source)] if editable else [str(source)])
    env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_") and k not in ("PYTHONPATH", "PYTHONHOME")}
    result = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "setup.py develop" not in result.stdout
    for script in SCRIPTS:
        path = prefix / "bin" / script
        assert path.is_file() and os.access(path, os.X_OK), sorted(p.name for p in prefix.rglob("*"))[:50]
        # the new environment's interpreter (pip writes a /bin/sh trampoline when the path is too long)
        assert str(python) in "\n".join(path.read_text().splitlines()[:3]), path.read_text()[:300]
    assert not (prefix / "lib" / "gpf_nav").exists()
    borrowed.unlink()  # from here on, the new environment alone
    where = subprocess.run([str(python), "-c", "import gpf_nav; print(gpf_nav.__file__)"], env=env, cwd=tmp_path,
                           capture_output=True, text=True, timeout=120)
    assert where.returncode == 0, where.stderr
    assert Path(where.stdout.strip()).is_relative_to(source if editable else site), where.stdout
    run = subprocess.run([str(prefix / "bin" / "gpf-nav"), "nosuch"], env=env, cwd=tmp_path, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 2 and "unknown command 'nosuch'" in run.stderr, run.stderr
