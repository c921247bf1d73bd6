"""The console-script nodes as real processes end cleanly on SIGINT and SIGTERM, whoever sends it: exit
status 0, no traceback, no ``KeyboardInterrupt``. Covers a signal to the process, to its process group
(Ctrl-C in a terminal), SIGINT twice (``ros2 launch`` stopped with Ctrl-C: the group's, then launch's
own) and SIGINT repeated while the node is shutting down. The simulator also exits 0 by itself at the
end of its trajectory."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from domains import fresh_domain

pytest.importorskip("rclpy")

ROOT = Path(__file__).resolve().parents[1]
MODULES = {"estimator": ("gpf_nav.ros.estimator_node", "estimator up"),
           "simulator": ("gpf_nav.ros.simulator_node", "lunar descent:")}
HOW = {
    "SIGINT": lambda p: p.send_signal(signal.SIGINT),
    "SIGTERM": lambda p: p.send_signal(signal.SIGTERM),
    "SIGINT to the group": lambda p: os.killpg(p.pid, signal.SIGINT),
    "SIGINT twice (launch)": lambda p: (os.killpg(p.pid, signal.SIGINT), p.send_signal(signal.SIGINT)),
    "SIGINT then SIGTERM": lambda p: (p.send_signal(signal.SIGINT), p.send_signal(signal.SIGTERM)),
    "SIGINT repeated": lambda p: _repeat(p, signal.SIGINT),
}


def _repeat(proc: subprocess.Popen, sig: int, times: int = 30, gap: float = 0.01) -> None:
    """Ctrl-C pressed again and again (or signals from several senders) while the node shuts down."""
    for _ in range(times):
        if proc.poll() is not None:
            return
        proc.send_signal(sig)
        time.sleep(gap)


def _start(module: str, log: Path, *ros_args: str) -> subprocess.Popen:
    env = dict(os.environ, ROS_DOMAIN_ID=str(fresh_domain()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    args = [sys.executable, "-m", module] + (["--ros-args", *ros_args] if ros_args else [])
    with open(log, "w") as out:
        return subprocess.Popen(args, env=env, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT,
                                start_new_session=True)  # its own process group, as under a terminal


def _wait_for(condition, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.1)
    return condition()


@pytest.mark.parametrize("name", sorted(MODULES))
def test_node_exits_0_without_traceback_on_signals(tmp_path, name):
    module, up_line = MODULES[name]
    procs = {how: _start(module, tmp_path / f"{i}.log") for i, how in enumerate(HOW)}
    logs = {how: tmp_path / f"{i}.log" for i, how in enumerate(HOW)}
    try:
        for how, proc in procs.items():
            assert _wait_for(lambda: up_line in logs[how].read_text() or proc.poll() is not None, 120.0), how
            assert proc.poll() is None, logs[how].read_text()
            HOW[how](proc)
        for how, proc in procs.items():
            proc.wait(timeout=60)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    for how, proc in procs.items():
        text = logs[how].read_text()
        assert proc.returncode == 0, (how, proc.returncode, text)
        assert "Traceback" not in text and "KeyboardInterrupt" not in text, (how, text)


def test_simulator_exits_0_by_itself_at_the_end_of_the_trajectory(tmp_path):
    log = tmp_path / "sim.log"
    proc = _start("gpf_nav.ros.simulator_node", log, "-p", "scenario.duration:=10.0", "-p", "rate_factor:=20.0",
                  "-p", "start_delay:=0.2")
    try:
        assert proc.wait(timeout=120) == 0, log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "trajectory ended" in log.read_text() and "Traceback" not in log.read_text()


LAUNCH_ARGUMENTS = {"params_file", "namespace", "use_sim_time", "log_level", "autostart", "filter", "rate_factor",
                    "shutdown_on_simulator_exit", "publish_suite"}


def test_launch_file_declares_its_arguments_statically():
    """Without launch: the file declares one DeclareLaunchArgument per entry of
    gpf_nav.ros.launch_arguments.ARGUMENTS (test/test_launch_arguments.py tests that table)."""
    import ast

    from gpf_nav.ros.launch_arguments import ARGUMENTS
    assert {a.name for a in ARGUMENTS} == LAUNCH_ARGUMENTS
    tree = ast.parse((ROOT / "launch" / "gpf_nav.launch.py").read_text())
    loops = [node for node in ast.walk(tree) if isinstance(node, ast.ListComp)
             and isinstance(node.elt, ast.Call) and getattr(node.elt.func, "id", "") == "DeclareLaunchArgument"]
    assert len(loops) == 1 and ast.unparse(loops[0].generators[0].iter) == "args.ARGUMENTS"


def test_launch_file_declares_its_arguments():
    """Only where launch and launch_ros are installed (a ROS system; no PyPI wheels exist). A submodule is
    imported: ``import launch`` alone succeeds anywhere, as this repository's own launch/ folder is then
    a namespace package when the tests run from the repository root."""
    pytest.importorskip("launch.actions")
    pytest.importorskip("launch_ros.actions")
    import importlib.util
    from unittest import mock

    from gpf_nav.estimator.factory import FILTERS

    spec = importlib.util.spec_from_file_location("gpf_nav_launch", ROOT / "launch" / "gpf_nav.launch.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    with mock.patch.object(module, "get_package_share_directory", return_value=str(ROOT)):
        description = module.generate_launch_description()
    arguments = {a.name: a for a in description.get_launch_arguments()}
    assert set(arguments) == LAUNCH_ARGUMENTS
    assert all(name in arguments["filter"].description for name in FILTERS)
