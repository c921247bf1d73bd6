"""The user story with no arguments at all: ``simulator`` and ``estimator`` (here ``python -m`` of their
modules) as two processes on a private domain, no parameters, the estimator on the wall clock. The
simulator stamps from the wall-clock time and hands its prior over on ``set_state`` (latched), so the
estimator, even started after the trajectory began, is initialised at once, publishes odometry at
``publish_rate`` and reports sane diagnostics. Nothing here asserts wall-clock speed: conditions are
awaited with generous deadlines, and rates are read from the messages' own stamps."""
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from domains import fresh_domain

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import Vector3Stamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402

from gpf_nav.ros import conversions as conv  # noqa: E402
from gpf_nav.ros.diagnostics import STATUS_NAME, parse_values  # noqa: E402
from gpf_nav.estimator.params import ESTIMATOR  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULTS = {spec.name: spec.default for spec in ESTIMATOR}
S = 1_000_000_000


def _spin_until(executor, condition, timeout: float, procs=()) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        for proc, log in procs:
            assert proc.poll() is None, log.read_text()
        executor.spin_once(timeout_sec=0.05)
    return condition()


def test_simulator_and_estimator_with_no_arguments(tmp_path):
    domain = fresh_domain()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONPATH=str(ROOT))
    context = rclpy.Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    node = rclpy.create_node("gpf_defaults_probe", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    odom, rae, diagnostics = [], [], []
    node.create_subscription(Odometry, "odometry/filtered", odom.append, 1000)
    node.create_subscription(Vector3Stamped, "measurements/rae", rae.append, qos_profile_sensor_data)
    node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 100)
    procs = []

    def start(module: str, name: str):
        log = tmp_path / f"{name}.log"
        with open(log, "w") as out:
            proc = subprocess.Popen([sys.executable, "-m", module], env=env, cwd=tmp_path, stdout=out,
                                    stderr=subprocess.STDOUT)
        procs.append((proc, log))
        return proc

    try:
        # the simulator first: the trajectory is under way (and the prior handed over) before the estimator
        start("gpf_nav.ros.simulator_node", "simulator")
        assert _spin_until(executor, lambda: rae, 120.0, procs), "no measurement from the simulator"
        start("gpf_nav.ros.estimator_node", "estimator")
        assert _spin_until(executor, lambda: node.count_publishers("odometry/filtered") > 0, 120.0, procs), \
            "the estimator never advertised odometry/filtered"
        up = time.monotonic()
        assert _spin_until(executor, lambda: odom, 120.0, procs), "no odometry from the estimator"
        first_wall = time.monotonic() - up  # printed, not asserted: the machine may be busy
        assert _spin_until(executor, lambda: len(odom) >= 40, 120.0, procs), len(odom)

        def status():
            for msg in reversed(diagnostics):
                for st in msg.status:
                    if st.name == STATUS_NAME:
                        return st, parse_values(st)
            return None, {}

        assert _spin_until(executor, lambda: status()[1].get("initialized") == "true"
                           and int(status()[1].get("measurements accepted", 0)) >= 2, 120.0, procs), status()[1]
    finally:
        for proc, _ in procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc, _ in procs:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    logs = {log.stem: log.read_text() for _, log in procs}
    assert all(proc.returncode == 0 for proc, _ in procs), logs

    # stamps on the wall clock: the estimator (wall clock) accepted them, none is dated 1970 + 1000 s
    stamps = np.array([conv.stamp_to_ns(m.header.stamp) for m in odom])
    wall = time.time_ns()
    assert np.all(np.abs(stamps - wall) < 3600 * S), (stamps.min(), wall)
    assert "initialised from set_state" in logs["estimator"], logs["estimator"]
    # odometry at publish_rate: the predictions' own stamps are 1/publish_rate apart (median; a stalled
    # scheduler may stretch some gaps, it cannot shrink them below the timer period)
    gaps = np.diff(np.sort(stamps)) * 1e-9
    period = 1.0 / DEFAULTS["publish_rate"]
    assert 0.5 * period <= np.median(gaps) <= 3.0 * period, np.median(gaps)
    assert all(math.isfinite(v) for m in odom for v in conv.odometry_state(m))

    st, values = status()
    assert values["initialized from"] == "set_state" and st.level != b"\x02", (st.message, values)
    age = float(values["last measurement age"])
    assert 0.0 <= age <= DEFAULTS["sensor_timeout"], values
    assert int(values["accepted set_state"]) == 1 and values["messages rejected"] == "0", values
    for msg in diagnostics:
        for s in msg.status:
            for kv in s.values:
                try:
                    number = float(kv.value)
                except ValueError:
                    continue
                assert math.isfinite(number), (kv.key, kv.value)
    print(f"first odometry {first_wall:.2f} s after the estimator was up; median stamp gap "
          f"{np.median(gaps):.3f} s; last measurement age {age:.2f} s")
