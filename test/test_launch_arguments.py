"""The launch file's arguments (``gpf_nav.ros.launch_arguments``, which ``launch/gpf_nav.launch.py``
declares and applies; ``launch``/``launch_ros`` have no wheel, so the launch file itself is checked only
where they are installed, and by hand: docs/ros.md, *Launch arguments*).

* every choice is valid for what receives it (log levels: rcl itself; filters: the factory's list;
  booleans: the parameter types), every default is one of its choices, and values outside them,
  a bad ``rate_factor`` or an unusable ``params_file`` are refused before any node starts;
* ``use_sim_time``, ``autostart`` and ``filter`` override the params file only when given: the
  estimator, started as ``launch_ros`` starts it with the launch file's parameter files
  (``--params-file`` each, in order), runs the file's filter, or the argument's when it is given, also
  when the file uses the very key launch_ros would give the node (rclpy applies keys in the order they
  first appear, not the order of the files: ``test_rclpy_applies_keys_in_order_of_first_appearance``).
"""
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gpf_nav.estimator.factory import FILTERS
from gpf_nav.estimator.params import ESTIMATOR
from gpf_nav.ros import launch_arguments as la

ROOT = Path(__file__).resolve().parents[1]
LAUNCH_FILE = ROOT / "launch" / "gpf_nav.launch.py"
DEFAULTS = {a.name: a.default for a in la.ARGUMENTS if a.default is not None}
WAIT = 120.0


def _values(**given) -> dict:
    return {**DEFAULTS, "params_file": str(ROOT / "config" / "estimator.yaml"), **given}


def test_every_default_is_one_of_its_choices_and_the_choices_come_from_the_code():
    for a in la.ARGUMENTS:
        if a.choices is not None:
            assert a.default in a.choices, a.name
    assert la.BY_NAME["filter"].choices == ("",) + tuple(FILTERS)
    assert la.BY_NAME["log_level"].choices == la.LOG_LEVELS
    for name in ("use_sim_time", "autostart"):
        assert la.BY_NAME[name].choices == ("", "true", "false")
    for name in ("publish_suite", "shutdown_on_simulator_exit"):
        assert la.BY_NAME[name].choices == ("true", "false")
    estimator_params = {spec.name for spec in ESTIMATOR} | {"use_sim_time"}
    assert set(la.ESTIMATOR_OVERRIDES) <= estimator_params and set(la.LAUNCH_DEFAULTS) <= estimator_params


def test_the_documented_argument_table_lists_exactly_these_arguments():
    text = (ROOT / "docs" / "ros.md").read_text()
    table = text.split("**Launch arguments**")[1].split("\n\n")[1]
    names = [line.split("|")[1].strip().strip("`") for line in table.splitlines()[2:]]
    assert names == [a.name for a in la.ARGUMENTS]


@pytest.mark.parametrize("level", la.LOG_LEVELS + ("bogus",))
def test_rcl_accepts_every_log_level_choice(level):
    rclpy = pytest.importorskip("rclpy")
    context = rclpy.Context()
    if level == "bogus":
        with pytest.raises(RuntimeError, match="log"):
            rclpy.init(args=["probe", "--ros-args", "--log-level", level], context=context)
        return
    rclpy.init(args=["probe", "--ros-args", "--log-level", level], context=context)
    rclpy.try_shutdown(context=context)


def test_the_defaults_pass_and_override_nothing_but_the_launch_default_clock():
    assert la.check(_values()) == []
    assert la.estimator_parameters(_values()) == {"use_sim_time": True}  # the shipped file has no use_sim_time
    assert la.estimator_parameters(_values(), {"/**/gpf_estimator": {"use_sim_time": False}}) == {}
    assert la.estimator_parameters(_values(), {"/other/gpf_estimator": {"use_sim_time": False}}) == \
        {"use_sim_time": True}
    assert la.simulator_parameters(_values()) == {"rate_factor": 1.0, "publish_clock": True, "publish_suite": False}


def test_given_arguments_are_typed_parameters():
    assert la.estimator_parameters(_values(filter="ekf", use_sim_time="false", autostart="true")) == \
        {"filter": "ekf", "use_sim_time": False, "autostart": True}
    assert la.estimator_parameters(_values(filter="ekf"), {"/**": {"use_sim_time": False}}) == {"filter": "ekf"}
    assert la.simulator_parameters(_values(rate_factor="20", publish_suite="true"))["publish_suite"] is True


@pytest.mark.parametrize("given, expected", [
    ({"filter": "bogus"}, "launch argument filter:='bogus' is not one of '', 'gpf'"),
    ({"log_level": "loud"}, "launch argument log_level:='loud' is not one of 'debug', 'info'"),
    ({"autostart": "yes"}, "launch argument autostart:='yes' is not one of '', 'true', 'false'"),
    ({"publish_suite": "1"}, "publish_suite:='1' is not one of 'true', 'false'"),
    ({"rate_factor": "fast"}, "rate_factor:='fast' must be a positive number"),
    ({"rate_factor": "0"}, "rate_factor:='0' must be a positive number"),
    ({"params_file": "/nonexistent/estimator.yaml"}, "params file /nonexistent/estimator.yaml: No such file"),
])
def test_bad_arguments_are_refused(given, expected):
    errors = la.check(_values(**given))
    assert len(errors) == 1 and expected in errors[0], errors


def test_a_params_file_that_sets_nothing_in_the_namespace_is_refused(tmp_path):
    plain = tmp_path / "plain.yaml"
    plain.write_text("gpf_estimator:\n  ros__parameters:\n    filter: ekf\n")
    assert la.check(_values(params_file=str(plain))) == []
    errors = la.check(_values(params_file=str(plain), namespace="lander"))
    assert len(errors) == 1 and "has no section for /lander/gpf_estimator" in errors[0], errors
    assert "'/**/gpf_estimator:'" in errors[0]
    assert la.check(_values(namespace="lander")) == []  # the shipped file applies in any namespace


def _estimator_log(tmp_path: Path, ros_args: list[str]) -> str:
    """The log of an estimator process started with ``ros_args`` once it is up (then stopped)."""
    env = dict(os.environ, ROS_DOMAIN_ID="0", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONPATH=str(ROOT),
               PYTHONUNBUFFERED="1")
    log = tmp_path / f"estimator{len(list(tmp_path.glob('estimator*.log')))}.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "gpf_nav.ros.estimator_node", "--ros-args", *ros_args],
                                env=env, cwd=tmp_path, stdout=out, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + WAIT
        while time.monotonic() < deadline and "estimator up" not in log.read_text() and proc.poll() is None:
            time.sleep(0.1)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return log.read_text()


def test_rclpy_applies_keys_in_order_of_first_appearance(tmp_path):
    """Why the override file has a key of its own: the same key in a later file does not win over a key
    that appeared in between."""
    pytest.importorskip("rclpy")
    exact, anywhere = tmp_path / "exact.yaml", tmp_path / "anywhere.yaml"
    exact.write_text("/lander/gpf_estimator:\n  ros__parameters:\n    filter: ukf\n")
    anywhere.write_text("/**/gpf_estimator:\n  ros__parameters:\n    filter: ekf\n")
    files = lambda *fs: [a for f in fs for a in ("--params-file", str(f))]  # noqa: E731
    assert "ekf estimator up" in _estimator_log(tmp_path, ["-r", "__ns:=/lander", *files(exact, anywhere, exact)])
    assert "ukf estimator up" in _estimator_log(tmp_path, ["-r", "__ns:=/lander", *files(anywhere, exact)])


@pytest.mark.parametrize("given, runs", [({}, "ekf"), ({"filter": "ukf"}, "ukf"), ({"filter": "enkf"}, "enkf")])
@pytest.mark.parametrize("keys", [("/**/gpf_estimator",), ("/lander/gpf_estimator", "/**/gpf_estimator")])
def test_a_launch_argument_overrides_the_params_file_only_when_given(tmp_path, given, runs, keys):
    """The estimator started with the parameter files the launch file passes (launch_ros gives each as
    ``--params-file``, in order): the filter is the params file's (ekf) unless the filter argument is
    given, whatever keys the file uses."""
    pytest.importorskip("rclpy")
    user = tmp_path / "mine.yaml"
    user.write_text("".join(f"{key}:\n  ros__parameters:\n    filter: {'ekf' if key.startswith('/**') else 'spf'}\n"
                            for key in keys))
    values = _values(params_file=str(user), namespace="lander", **given)
    assert la.check(values) == []
    files = la.estimator_parameter_files(values, str(tmp_path))
    assert files[0] == str(user) and len(files) == 2  # use_sim_time at least: the file does not set it
    ros_args = ["--log-level", values["log_level"], "-r", "__node:=gpf_estimator", "-r", "__ns:=/lander"]
    text = _estimator_log(tmp_path, ros_args + [a for f in files for a in ("--params-file", f)])
    assert f"{runs} estimator up" in text, text
    assert "sets nothing" not in text and "does not declare" not in text, text


# --- where launch and launch_ros are installed (a ROS system; colcon test there) -------------------------
def test_the_launch_file_declares_these_arguments_with_their_choices():
    pytest.importorskip("launch.actions")  # not `launch`: this repository's launch/ folder imports as that
    pytest.importorskip("launch_ros.actions")
    import importlib.util
    from unittest import mock

    from launch.actions import DeclareLaunchArgument
    spec = importlib.util.spec_from_file_location("gpf_nav_launch", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    with mock.patch.object(module, "get_package_share_directory", return_value=str(ROOT)):
        description = module.generate_launch_description()
    declared = {e.name: e for e in description.entities if isinstance(e, DeclareLaunchArgument)}
    assert list(declared) == [a.name for a in la.ARGUMENTS]
    for a in la.ARGUMENTS:
        assert declared[a.name].choices == (list(a.choices) if a.choices else None), a.name


@pytest.mark.parametrize("argument, message", [
    ("filter:=bogus", "Argument \"filter\" provided value \"bogus\" is not valid"),
    ("log_level:=bogus", "Argument \"log_level\" provided value \"bogus\" is not valid"),
    ("rate_factor:=fast", "rate_factor:='fast' must be a positive number"),
])
def test_ros2_launch_stops_on_a_bad_argument(tmp_path, argument, message):
    if shutil.which("ros2") is None:
        pytest.skip("no ros2 command (a ROS installation)")
    pytest.importorskip("launch_ros.actions")
    if subprocess.run(["ros2", "pkg", "prefix", "gpf_nav"], capture_output=True, timeout=WAIT).returncode != 0:
        pytest.skip("gpf_nav is not in the sourced ROS environment (colcon build; source install/setup.bash)")
    r = subprocess.run(["ros2", "launch", "gpf_nav", "gpf_nav.launch.py", argument], cwd=tmp_path,
                       capture_output=True, text=True, timeout=WAIT)
    assert r.returncode != 0 and message in r.stdout + r.stderr, (r.returncode, r.stdout, r.stderr)
    assert "process started" not in r.stdout + r.stderr


def test_the_launch_file_compiles():
    """Its syntax at least, everywhere (it imports launch_ros, so it is loaded only where that exists)."""
    compile(LAUNCH_FILE.read_text(), str(LAUNCH_FILE), "exec")
