"""The arguments of ``launch/gpf_nav.launch.py`` and what they do to the nodes, without ``launch``.

``launch`` and ``launch_ros`` have no PyPI wheel, so the launch file is a thin shell over this module:
it declares :data:`ARGUMENTS` (with their ``choices``, which ``ros2 launch`` enforces: a value outside
them stops the launch with ``Argument 'filter' provided value 'bogus' is not valid. Valid options are:
[...]`` and a non-zero exit), then builds both nodes from :func:`check`, :func:`estimator_parameters` and
:func:`simulator_parameters`, which the tests exercise here.

An estimator argument whose default is ``''`` (:data:`NOT_GIVEN`) overrides the params file only when
the user gives it: the estimator gets ``--params-file params_file`` and then, if anything is to be
overridden, a file of the given arguments (:func:`estimator_parameter_files`), so a file saying
``filter: ekf`` runs the EKF unless the command line says ``filter:=...``. :data:`LAUNCH_DEFAULTS` go
into that second file only for the parameters the params file does not set.

Order is subtle: rcl merges all params files into one table of node keys, and rclpy applies the keys
that match the node in the order each key *first* appeared. A later file does not win if its key
already appeared earlier (``/lander/gpf_estimator`` in the user's file, then ``/**/gpf_estimator``, then an
override keyed ``/lander/gpf_estimator``: the user's ``/**/gpf_estimator`` wins). So the override file's key
is one that matches the node and that the params file does not use (:func:`override_key`).
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from gpf_nav.estimator import params
from gpf_nav.estimator.params import ParameterError, read_params_file, section_matches
from gpf_nav.schema import Spec, within
from gpf_nav.sim.simulator_params import simulator_specs

NOT_GIVEN = ""
BOOLEANS = ("true", "false")
LOG_LEVELS = ("debug", "info", "warn", "error", "fatal")
"""rcutils' severities, as ``--ros-args --log-level`` takes them (test_launch_arguments asks rcl)."""
ESTIMATOR_NAME = "gpf_estimator"
SIMULATOR_NAME = "lunar_simulator"


def choices(spec: Spec) -> tuple[str, ...]:
    """A parameter's values as launch arguments spell them: its choices, or true and false."""
    return BOOLEANS if isinstance(spec.default, bool) else spec.choices


ESTIMATOR = params.BY_NAME
SIMULATOR = {spec.name: spec for spec in simulator_specs()}


@dataclass(frozen=True)
class Argument:
    name: str
    default: str | None          # None: the installed config/estimator.yaml (known only to the launch file)
    description: str
    choices: tuple[str, ...] | None = None


ARGUMENTS = [
    Argument("params_file", None, "ROS 2 params file of the estimator ('/**/gpf_estimator: ros__parameters:', "
             "which applies in any namespace); default: the installed config/estimator.yaml."),
    Argument("namespace", "", "Namespace of both nodes (their topics are relative; /tf, /clock and /diagnostics "
             "stay global)."),
    Argument("use_sim_time", NOT_GIVEN, "Estimator clock: true follows the simulator's /clock, false the wall "
             "clock; not given: the params file's value, else true.", ("",) + BOOLEANS),
    Argument("log_level", "info", "Log level of both nodes.", LOG_LEVELS),
    Argument("autostart", NOT_GIVEN, "true: the estimator configures and activates itself; false: it waits, "
             "unconfigured, for a lifecycle manager; not given: the params file's value, else true.",
             ("",) + choices(ESTIMATOR["autostart"])),
    Argument("filter", NOT_GIVEN, "Estimator filter; not given: the params file's value, else gpf.",
             ("",) + choices(ESTIMATOR["filter"])),
    Argument("rate_factor", "1.0", "Simulated seconds per wall second (a positive number)."),
    Argument("publish_suite", "false", "true: the simulator also publishes measurements/altitude, "
             "measurements/position (TRN, 4 s late) and measurements/velocity.", choices(SIMULATOR["publish_suite"])),
    Argument("shutdown_on_simulator_exit", "false", "true: end the launch (and the estimator) when the simulator "
             "exits at the end of its trajectory; false: the estimator stays up.", BOOLEANS),
]
BY_NAME = {a.name: a for a in ARGUMENTS}
ESTIMATOR_OVERRIDES = ("use_sim_time", "autostart", "filter")
"""Arguments that set the estimator parameter of the same name, when given."""
LAUNCH_DEFAULTS = {"use_sim_time": True}
"""Estimator parameters the launch file sets before the params file (so the file, then the arguments, win):
the estimator follows the simulator's clock, as ``rate_factor`` other than 1 needs."""


def check(values: dict[str, str]) -> list[str]:
    """The problems of the launch arguments ``values`` (name -> string): choices (as ``ros2 launch``
    checks them), ``rate_factor`` and the params file (it must exist and be a readable params file; a
    file none of whose sections applies to the estimator in ``namespace`` is refused too, as it would
    set nothing). Empty: all good."""
    errors = []
    for name, value in values.items():
        argument = BY_NAME.get(name)
        if argument is not None and argument.choices is not None and value not in argument.choices:
            errors.append(f"launch argument {name}:={value!r} is not one of {', '.join(map(repr, argument.choices))}")
    rate = values.get("rate_factor", BY_NAME["rate_factor"].default)
    try:
        ok = within(SIMULATOR["rate_factor"].bounds, float(rate))
    except ValueError:
        ok = False
    if not ok:
        errors.append(f"launch argument rate_factor:={rate!r} must be a positive number")
    path = values.get("params_file")
    if path is not None:
        try:
            sections = read_params_file(path)
        except ParameterError as err:
            errors.append(f"launch argument params_file: {err}")
        else:
            fqn = estimator_name(values.get("namespace", ""))
            if not any(section_matches(key, fqn) for key in sections):
                errors.append(f"launch argument params_file: {path} has no section for {fqn} (sections: "
                              f"{', '.join(map(repr, sections)) or 'none'}); write '/**/{ESTIMATOR_NAME}:' to match "
                              "it in any namespace")
    return errors


def estimator_name(namespace: str) -> str:
    """The estimator's fully qualified name in ``namespace`` (as launch_ros makes it absolute)."""
    namespace = namespace.strip("/")
    return f"/{namespace}/{ESTIMATOR_NAME}" if namespace else f"/{ESTIMATOR_NAME}"


def estimator_parameters(values: dict[str, str], file_sections: dict | None = None) -> dict:
    """The estimator parameters to set after the params file: the given (non-empty) override arguments,
    typed, and the :data:`LAUNCH_DEFAULTS` that no section of the params file (``file_sections``, from
    :func:`gpf_nav.estimator.params.read_params_file`) applying to the estimator sets."""
    given = {}
    for name in ESTIMATOR_OVERRIDES:
        value = values.get(name, NOT_GIVEN)
        if value != NOT_GIVEN:
            given[name] = value == "true" if BY_NAME[name].choices[1:] == BOOLEANS else value
    fqn = estimator_name(values.get("namespace", ""))
    in_file = {name for key, section in (file_sections or {}).items() if section_matches(key, fqn)
               for name in section}
    for name, value in LAUNCH_DEFAULTS.items():
        if name not in given and name not in in_file:
            given[name] = value
    return given


def override_key(file_sections: dict, namespace: str) -> str:
    """A params-file key that matches the estimator in ``namespace`` and that ``file_sections`` does not
    use, so rclpy applies it after every section of the params file (see the module's docstring)."""
    used = {"/" + str(key).lstrip("/") for key in file_sections}
    candidates = [estimator_name(namespace)] + ["/**" * depth + "/" + ESTIMATOR_NAME for depth in range(1, 10)]
    return next(key for key in candidates if key not in used)


def estimator_parameter_files(values: dict[str, str], directory: str) -> list[str]:
    """The estimator's ``--params-file`` arguments, in order: ``params_file``, then (when there is anything
    to set) a file written in ``directory`` with :func:`estimator_parameters` under :func:`override_key`.
    Call after :func:`check` found no problem."""
    import yaml
    path = values["params_file"]
    sections = read_params_file(path)
    overrides = estimator_parameters(values, sections)
    if not overrides:
        return [path]
    name = os.path.join(directory, "gpf_estimator_launch_arguments.yaml")
    with open(name, "w") as f:
        yaml.safe_dump({override_key(sections, values.get("namespace", "")): {"ros__parameters": overrides}}, f)
    return [path, name]


def simulator_parameters(values: dict[str, str]) -> dict:
    """The simulator parameters the launch file sets after config/simulator.yaml."""
    return {"rate_factor": float(values.get("rate_factor", BY_NAME["rate_factor"].default)), "publish_clock": True,
            "publish_suite": values.get("publish_suite", "false") == "true"}
