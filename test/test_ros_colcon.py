"""The ament_python layout, proved with colcon (colcon-core + colcon-ros from PyPI) in a temporary
workspace, and the installed console scripts run as separate processes over DDS:

* the documented ``colcon build --packages-select gpf_nav`` installs ``lib/gpf_nav/{estimator,simulator}``
  (what ``ros2 run`` looks for), the ament index marker and ``share/gpf_nav/{config,launch}``, and
  ``source install/setup.bash`` puts the package on the paths; ``--symlink-install`` gives the same layout;
* the installed ``estimator`` refuses ``filter:=bogus`` with a clear FATAL line and exit code 2;
* the installed ``gpf-nav`` runs from ``lib/gpf_nav`` (``ros2 run gpf_nav gpf-nav``), and the installed
  scripts refuse a missing params file in one line with exit code 2;
* the installed ``simulator`` and ``estimator`` run as two processes (``use_sim_time``) while this test
  subscribes to ``odometry/filtered`` and ``truth/odometry`` and checks the error is bounded.
Skipped only when colcon is not importable (CI installs it).
"""
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from domains import fresh_domain

pytest.importorskip("colcon_core")
pytest.importorskip("colcon_ros")
rclpy = pytest.importorskip("rclpy")

from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from gpf_nav.ros import conversions as conv  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_FILES = ("setup.py", "setup.cfg", "pyproject.toml", "package.xml", "resource", "gpf_nav", "config", "launch")
COLCON = "import sys; from colcon_core.command import main; sys.exit(main())"


def _build(ws: Path, *options: str) -> Path:
    """Copy the package to ``ws/src/gpf_nav`` and run the documented colcon command in ``ws``."""
    src = ws / "src" / "gpf_nav"
    src.mkdir(parents=True)
    for name in PACKAGE_FILES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        elif path.exists():
            shutil.copy2(path, src / name)
    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env.pop("PYTHONPATH", None)
    result = subprocess.run([sys.executable, "-c", COLCON, "build", "--packages-select", "gpf_nav", *options],
                            cwd=ws, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return ws


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    return _build(tmp_path_factory.mktemp("colcon_ws"))


def _assert_ros2_run_layout(ws: Path) -> None:
    prefix = ws / "install" / "gpf_nav"
    for script in ("estimator", "simulator", "gpf-nav"):
        path = prefix / "lib" / "gpf_nav" / script
        assert path.is_file() and os.access(path, os.X_OK), path
    assert not (prefix / "bin").exists()
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "gpf_nav").is_file()
    assert (prefix / "share" / "gpf_nav" / "package.xml").is_file()
    for name in ("estimator.yaml", "simulator.yaml"):
        assert (prefix / "share" / "gpf_nav" / "config" / name).is_file()
    assert (prefix / "share" / "gpf_nav" / "launch" / "gpf_nav.launch.py").is_file()
    # `source install/setup.bash` (colcon-bash) finds the package
    probe = ('source install/setup.bash && echo "$AMENT_PREFIX_PATH" && '
             'python -c "import gpf_nav; print(gpf_nav.__file__)"')
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH")}
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    shown = subprocess.run(["bash", "-c", probe], cwd=ws, env=env, capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0, shown.stderr
    assert str(prefix) in shown.stdout.splitlines()[0]
    assert str(ws) in shown.stdout.splitlines()[-1], shown.stdout


def _installed_env(ws: Path, domain: int) -> dict:
    env = dict(os.environ)
    site = next((ws / "install" / "gpf_nav" / "lib").glob("python3*/site-packages"))
    env["PYTHONPATH"] = str(site)  # the installed package only, not the source tree
    env["ROS_DOMAIN_ID"] = str(domain)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return env


def test_colcon_build_installs_the_ros2_run_layout(workspace):
    _assert_ros2_run_layout(workspace)
    env = _installed_env(workspace, 0)
    where = subprocess.run([sys.executable, "-c", "import gpf_nav; print(gpf_nav.__file__)"], env=env,
                           cwd=workspace, capture_output=True, text=True, timeout=60)
    assert str(workspace / "install" / "gpf_nav") in where.stdout


def test_colcon_symlink_install_gives_the_same_layout(tmp_path):
    _assert_ros2_run_layout(_build(tmp_path, "--symlink-install"))


def test_installed_estimator_refuses_bad_parameters(workspace):
    script = workspace / "install" / "gpf_nav" / "lib" / "gpf_nav" / "estimator"
    result = subprocess.run([str(script), "--ros-args", "-p", "filter:=bogus", "-p", "ess_threshold:=1.5"],
                            env=_installed_env(workspace, 0), cwd=workspace, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 2, result.stderr
    assert "refusing to start" in result.stderr
    assert "'filter' = 'bogus' is not a known filter; choose one of gpf, gpf-mm, gpf-ladder, spf, ekf, ukf, enkf, gpf-single" in result.stderr


def test_installed_gpf_nav_runs_where_ros2_run_finds_it(workspace):
    """``ros2 run gpf_nav gpf-nav ...`` runs ``lib/gpf_nav/gpf-nav`` (colcon puts no bin/ on PATH)."""
    script = workspace / "install" / "gpf_nav" / "lib" / "gpf_nav" / "gpf-nav"
    env = _installed_env(workspace, 0)
    result = subprocess.run([str(script), "--help"], env=env, cwd=workspace, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0 and "gpf-nav demo" in result.stdout, result.stderr
    result = subprocess.run([str(script), "nosuch"], env=env, cwd=workspace, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 2 and "unknown command 'nosuch'" in result.stderr, result.stderr


@pytest.mark.parametrize("program", ["estimator", "simulator", "gpf-nav"])
def test_installed_scripts_refuse_a_missing_params_file_in_one_line(workspace, program):
    script = workspace / "install" / "gpf_nav" / "lib" / "gpf_nav" / program
    missing = workspace / "missing.yaml"
    args = ["replay", "nobag", "--out", "out", "--params-file"] if program == "gpf-nav" else ["--ros-args",
                                                                                                "--params-file"]
    result = subprocess.run([str(script), *args, str(missing)], env=_installed_env(workspace, 0), cwd=workspace,
                            capture_output=True, text=True, timeout=120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, (result.returncode, result.stdout, result.stderr)
    assert f"params file {missing}: No such file or directory" in lines[0], lines


def test_installed_simulator_and_estimator_processes_track_truth(workspace):
    domain = fresh_domain()
    env = _installed_env(workspace, domain)
    lib = workspace / "install" / "gpf_nav" / "lib" / "gpf_nav"
    share = workspace / "install" / "gpf_nav" / "share" / "gpf_nav" / "config"
    context = rclpy.Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    node = rclpy.create_node("gpf_colcon_probe", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    odom, truth = {}, {}
    node.create_subscription(Odometry, "odometry/filtered",
                             lambda m: odom.__setitem__(conv.stamp_to_ns(m.header.stamp), conv.odometry_state(m)), 500)
    node.create_subscription(Odometry, "truth/odometry",
                             lambda m: truth.__setitem__(conv.stamp_to_ns(m.header.stamp), conv.odometry_state(m)), 500)
    logs = workspace / "logs"
    logs.mkdir(exist_ok=True)
    est_log = open(logs / "estimator.log", "w")
    sim_log = open(logs / "simulator.log", "w")
    est = subprocess.Popen([str(lib / "estimator"), "--ros-args", "--params-file", str(share / "estimator.yaml"),
                            "-p", "use_sim_time:=true", "-p", "n_particles:=300", "-p", "queue_depth:=200"],
                           env=env, cwd=workspace, stdout=est_log, stderr=subprocess.STDOUT)
    sim = None
    try:
        # a fresh install compiles the filter's kernels before the node comes up (a minute or more on a
        # busy machine): the simulator starts only once the estimator is there to hear it
        deadline = time.monotonic() + 600.0
        while time.monotonic() < deadline and node.count_publishers("odometry/filtered") == 0:
            assert est.poll() is None, (logs / "estimator.log").read_text()
            executor.spin_once(timeout_sec=0.1)
        assert node.count_publishers("odometry/filtered") > 0, (logs / "estimator.log").read_text()
        sim = subprocess.Popen([str(lib / "simulator"), "--ros-args", "--params-file", str(share / "simulator.yaml"),
                                "-p", "rate_factor:=25.0", "-p", "scenario.duration:=120.0",
                                "-p", "start_delay:=2.0", "-p", "truth_rate:=0.0", "-p", "imu_rate:=0.0"],
                               env=env, cwd=workspace, stdout=sim_log, stderr=subprocess.STDOUT)
        # queues deeper than the run (60 measurements, truth only at their stamps): a busy machine delays
        # messages but sheds none, so wait for the estimates rather than for a duration
        deadline = time.monotonic() + 240.0
        while time.monotonic() < deadline and (sim.poll() is None or len(set(odom) & set(truth)) < 40):
            executor.spin_once(timeout_sec=0.05)
        assert sim.returncode == 0, (logs / "simulator.log").read_text()
        assert "trajectory ended" in (logs / "simulator.log").read_text()
        assert est.poll() is None, (logs / "estimator.log").read_text()
        common = sorted(set(odom) & set(truth))
        # (the measurements that reach a loaded estimator before the simulator's latched prior are used
        # to start it but give no estimate at their own stamps: up to a dozen of the 60 on a busy machine)
        assert len(common) >= 40, (len(odom), len(truth), (logs / "estimator.log").read_text())
        err = np.array([np.linalg.norm(odom[k][:3] - truth[k][:3]) for k in common])
        assert np.all(np.isfinite(err)) and np.median(err) < 5e3 and err.max() < 25e3, err
    finally:
        for proc in (sim, est):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    proc.kill()
        est_log.close()
        sim_log.close()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert est.returncode == 0, (logs / "estimator.log").read_text()
