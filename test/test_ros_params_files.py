"""Params files that match the node wherever it lives, and params files that cannot be read.

* The shipped ``config/*.yaml`` use ``/**/<node>:`` keys, so a namespaced node gets their values: a real
  ``estimator`` process in ``/lander`` given the shipped file edited to ``n_particles: 200`` runs with 200
  particles (its log line and its ``get_parameters`` service say so).
* A params file whose sections do not apply to the node (``gpf_estimator:`` is ``/gpf_estimator`` only)
  is warned about in one line naming the file and the fix; an undeclared key in a section that does
  apply is warned about too (as a misspelt ``-p`` is).
* A missing, unreadable or malformed params file gives one line on stderr naming it and exit status 2,
  for the nodes (``python -m``, what ``ros2 run`` and the console scripts run) and ``gpf-nav``.
* The matching rules (:func:`gpf_nav.estimator.params.section_matches`, used by the warning and by
  ``gpf-nav replay``/``record``) are rcl's: ``test_section_matching_agrees_with_rcl`` asks rcl itself,
  through the overrides an rclpy node gets from the global arguments.
"""
import os
import subprocess
import sys
from pathlib import Path

import pytest

from domains import fresh_domain
from gpf_nav.estimator.params import (ESTIMATOR, ParameterError, parameters_from_files, read_params_file,
                                      section_matches, unmatched_sections)

ROOT = Path(__file__).resolve().parents[1]
WAIT = 120.0


# --- without ROS ------------------------------------------------------------------------------------------
RCL_MATCHES = [  # (key, node, matches), as rcl decides (test_section_matching_agrees_with_rcl)
    ("/**/gpf_estimator", "/gpf_estimator", True), ("/**/gpf_estimator", "/lander/gpf_estimator", True),
    ("/**/gpf_estimator", "/a/lander/gpf_estimator", True), ("gpf_estimator", "/gpf_estimator", True),
    ("gpf_estimator", "/lander/gpf_estimator", False), ("/gpf_estimator", "/lander/gpf_estimator", False),
    ("/**", "/lander/gpf_estimator", True), ("/*/gpf_estimator", "/gpf_estimator", False),
    ("/*/gpf_estimator", "/lander/gpf_estimator", True), ("/lander/*", "/lander/gpf_estimator", True),
    ("lander/gpf_estimator", "/lander/gpf_estimator", True),
    ("/**/lander/gpf_estimator", "/a/lander/gpf_estimator", True), ("/other/gpf_estimator", "/lander/gpf_estimator", False),
]


@pytest.mark.parametrize("key, node, matches", RCL_MATCHES)
def test_section_matching_rules(key, node, matches):
    assert section_matches(key, node) is matches


@pytest.mark.parametrize("key, node, matches", RCL_MATCHES)
def test_section_matching_agrees_with_rcl(tmp_path, key, node, matches):
    """rcl itself (through the overrides a node gets from the global arguments) matches as we do."""
    rclpy = pytest.importorskip("rclpy")
    f = tmp_path / "p.yaml"
    f.write_text(f'"{key}":\n  ros__parameters:\n    seed: 7\n')
    namespace, name = node.rsplit("/", 1)
    context = rclpy.Context()
    rclpy.init(args=["probe", "--ros-args", "-r", f"__ns:={namespace or '/'}", "--params-file", str(f)],
               context=context, domain_id=fresh_domain())
    try:
        probe = rclpy.create_node(name, context=context)
        assert probe.get_fully_qualified_name() == node
        assert ("seed" in probe._parameter_overrides) is matches
        probe.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_shipped_params_files_apply_in_any_namespace():
    for name, node in (("estimator.yaml", "gpf_estimator"), ("simulator.yaml", "lunar_simulator")):
        sections = read_params_file(ROOT / "config" / name)
        assert list(sections) == [f"/**/{node}"]
        for fqn in (f"/{node}", f"/lander/{node}", f"/fleet/lander2/{node}"):
            assert unmatched_sections(sections, fqn) is None


def test_every_params_file_example_in_the_docs_applies_in_any_namespace():
    """The YAML blocks of README.md and docs/*.md that give a node's parameters use '/**/<node>:' keys."""
    yaml = pytest.importorskip("yaml")
    checked = 0
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = doc.read_text()
        for block in text.split("```yaml")[1:]:
            document = yaml.safe_load(block.split("```")[0])
            if not isinstance(document, dict) or "ros__parameters" not in str(document):
                continue
            for key in document:
                checked += 1
                assert str(key) == "/**" or str(key).startswith("/**/"), (doc.name, key)
    assert checked >= 2


def test_nested_node_names_and_unmatched_sections(tmp_path):
    nested = tmp_path / "nested.yaml"
    nested.write_text("lander:\n  gpf_estimator:\n    ros__parameters:\n      n_particles: 300\n")
    sections = read_params_file(nested)
    assert sections == {"lander/gpf_estimator": {"n_particles": 300}}
    assert unmatched_sections(sections, "/lander/gpf_estimator") is None
    assert unmatched_sections(sections, "/gpf_estimator") == ["lander/gpf_estimator"]
    assert unmatched_sections({"lifecycle_manager": {}}, "/gpf_estimator") == []
    assert unmatched_sections({"lifecycle_manager": {}, "/**": {}}, "/x/gpf_estimator") is None


@pytest.mark.parametrize("content, expected", [
    (None, "No such file or directory"),
    ("a: [\n", "is not valid YAML"),
    ("x:\n  foo: 1\n", "expected node names under 'x/foo'"),
    ("/**:\n  ros__parameters: 3\n", "expected '<node>: ros__parameters: <mapping>' at '/**'"),
])
def test_unusable_params_files_raise_one_line_naming_the_file(tmp_path, content, expected):
    path = tmp_path / "p.yaml"
    if content is not None:
        path.write_text(content)
    with pytest.raises(ParameterError) as err:
        read_params_file(path)
    assert str(path) in str(err.value) and expected in str(err.value) and "\n" not in str(err.value)


def test_offline_parameters_read_any_namespace_key(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("/**/gpf_estimator:\n  ros__parameters:\n    n_particles: 200\n"
                 "/other/gpf_estimator:\n  ros__parameters:\n    seed: 9\n")
    p = parameters_from_files(ESTIMATOR, "gpf_estimator", [f])
    assert p["n_particles"] == 200 and p["seed"] == 0
    assert parameters_from_files(ESTIMATOR, "gpf_estimator", [ROOT / "config/estimator.yaml"])["n_particles"] == 500


def test_params_files_of_a_command_line():
    from_argv = pytest.importorskip("gpf_nav.ros.parameters").params_files
    argv = ["estimator", "--params-file", "not_ros.yaml", "--ros-args", "-p", "a:=1", "--params-file", "a.yaml",
            "-r", "__ns:=/x", "--params-file=b.yaml", "--", "--params-file", "c.yaml", "--ros-args",
            "--params-file", "d.yaml"]
    assert from_argv(argv) == ["a.yaml", "b.yaml", "d.yaml"]


# --- processes ---------------------------------------------------------------------------------------------
def _env(domain: int = 0) -> dict:
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")


def _unusable(tmp_path: Path) -> dict:
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [\n")
    unreadable = tmp_path / "unreadable.yaml"
    unreadable.write_text("/**:\n  ros__parameters:\n    seed: 1\n")
    unreadable.chmod(0)
    cases = {"missing": (tmp_path / "missing.yaml", "No such file or directory"),
             "not YAML": (bad, "is not valid YAML"),
             "a directory": (tmp_path, "Is a directory")}
    if not os.access(unreadable, os.R_OK):  # root reads anything
        cases["unreadable"] = (unreadable, "Permission denied")
    return cases


@pytest.mark.parametrize("program, command", [
    ("estimator", ["-m", "gpf_nav.ros.estimator_node", "--ros-args", "--params-file"]),
    ("simulator", ["-m", "gpf_nav.ros.simulator_node", "--ros-args", "--params-file"]),
    ("gpf-nav replay", ["-m", "gpf_nav.cli", "replay", "nobag", "--out", "out", "--params-file"]),
    ("gpf-nav record", ["-m", "gpf_nav.cli", "record", "bag", "--params-file"]),
])
def test_an_unusable_params_file_is_one_line_and_exit_2(tmp_path, program, command):
    pytest.importorskip("rclpy")
    for what, (path, expected) in _unusable(tmp_path).items():
        r = subprocess.run([sys.executable, *command, str(path)], env=_env(), cwd=tmp_path, capture_output=True,
                           text=True, timeout=WAIT)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1, (what, r.returncode, r.stdout, r.stderr)
        assert lines[0].startswith(f"{program}: error: params file {path}") and expected in lines[0], (what, lines)
        assert "Traceback" not in r.stdout + r.stderr


def test_a_namespaced_estimator_gets_the_shipped_file_and_warns_about_a_file_for_another_namespace(tmp_path):
    rclpy = pytest.importorskip("rclpy")
    from rcl_interfaces.srv import GetParameters
    from rclpy.executors import SingleThreadedExecutor

    shipped = tmp_path / "estimator.yaml"
    text = (ROOT / "config" / "estimator.yaml").read_text()
    assert "    n_particles: 500 " in text
    shipped.write_text(text.replace("    n_particles: 500 ", "    n_particles: 200 "))
    plain = tmp_path / "plain.yaml"  # written as the docs used to say: /gpf_estimator only
    plain.write_text("gpf_estimator:\n  ros__parameters:\n    seed: 7\n")
    typo = tmp_path / "typo.yaml"
    typo.write_text("/**/gpf_estimator:\n  ros__parameters:\n    n_particle: 100\n")
    domain = fresh_domain()
    log = tmp_path / "estimator.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "gpf_nav.ros.estimator_node", "--ros-args", "-r", "__ns:=/lander",
                                 "--params-file", str(shipped), "--params-file", str(plain), "--params-file", str(typo)],
                                env=_env(domain), cwd=tmp_path, stdout=out, stderr=subprocess.STDOUT)
    context = rclpy.Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    node = rclpy.create_node("gpf_params_probe", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    client = node.create_client(GetParameters, "/lander/gpf_estimator/get_parameters")
    try:
        import time
        deadline = time.monotonic() + WAIT
        values = None
        while time.monotonic() < deadline and values is None:
            assert proc.poll() is None, log.read_text()
            if not client.service_is_ready():
                executor.spin_once(timeout_sec=0.1)
                continue
            future = client.call_async(GetParameters.Request(names=["n_particles", "seed"]))
            resend = time.monotonic() + 5.0  # DDS may lose a request while discovery settles
            while not future.done() and time.monotonic() < resend:
                executor.spin_once(timeout_sec=0.1)
            if future.done():
                values = [v.integer_value for v in future.result().values]
            else:
                client.remove_pending_request(future)
        assert values == [200, 0], (values, log.read_text())
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    text = log.read_text()
    assert proc.returncode == 0 and "Traceback" not in text, text
    assert "gpf estimator up: N=200," in text, text
    unmatched = [line for line in text.splitlines() if "sets nothing for /lander/gpf_estimator" in line]
    assert len(unmatched) == 1 and "WARN" in unmatched[0] and str(plain) in unmatched[0], text
    assert "'gpf_estimator'" in unmatched[0] and "'/**/gpf_estimator:'" in unmatched[0], unmatched
    undeclared = [line for line in text.splitlines() if "n_particle" in line and "does not declare" in line]
    assert len(undeclared) == 1 and "WARN" in undeclared[0], text


@pytest.mark.parametrize("module, program", [("gpf_nav.ros.estimator_node", "estimator"),
                                             ("gpf_nav.ros.simulator_node", "simulator")])
def test_arguments_rcl_refuses_end_with_one_line_of_ours_and_exit_2(tmp_path, module, program):
    """What the pre-check cannot see (rcl's own argument rules) still ends without a traceback."""
    pytest.importorskip("rclpy")
    r = subprocess.run([sys.executable, "-m", module, "--ros-args", "--log-level", "bogus"], env=_env(),
                       cwd=tmp_path, capture_output=True, text=True, timeout=WAIT)
    ours = [line for line in r.stderr.splitlines() if line.startswith(f"{program}: error: ")]
    assert r.returncode == 2 and len(ours) == 1 and "log level" in ours[0], (r.returncode, r.stderr)
    assert "Traceback" not in r.stdout + r.stderr
