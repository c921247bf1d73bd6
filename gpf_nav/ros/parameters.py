"""Declare a parameter table (:mod:`gpf_nav.schema`) on an rclpy node, warn about the
parameters a node was given but does not declare and about params files none of whose sections applies
to the node, and check the params files of a command line before ``rclpy.init`` reads them.

Numbers are declared with dynamic typing, so ``1`` in a YAML file is accepted for a float; every value is
returned coerced to its default's type (:func:`gpf_nav.schema.coerce`).
"""
from __future__ import annotations

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterUninitializedException

from gpf_nav.estimator.params import read_params_file, unmatched_sections
from gpf_nav.schema import ParameterError, Spec, coerce


def declare(node, specs: list[Spec]) -> dict:
    """Declare ``specs`` on ``node`` and return ``{name: value}`` coerced to the defaults' types."""
    values = {}
    for spec in specs:
        numeric = isinstance(spec.default, (int, float)) and not isinstance(spec.default, bool)
        descriptor = ParameterDescriptor(description=spec.help, read_only=not spec.live,
                                         dynamic_typing=numeric or spec.default is None)
        if spec.default is None:  # no default, any numeric list: declared NOT_SET with dynamic typing
            node.declare_parameter(spec.name, None, descriptor)
            try:
                value = node.get_parameter(spec.name).value
            except ParameterUninitializedException:
                value = None
        else:
            value = node.declare_parameter(spec.name, spec.default, descriptor).value
        values[spec.name] = coerce(spec, value)
    return values


def params_files(argv) -> list[str]:
    """The ``--params-file PATH`` arguments of the ``--ros-args`` parts of ``argv``, in order."""
    files, in_ros_args, args = [], False, list(argv)
    for i, arg in enumerate(args):
        if arg == "--ros-args":
            in_ros_args = True
        elif arg == "--":
            in_ros_args = False
        elif in_ros_args and arg == "--params-file" and i + 1 < len(args):
            files.append(args[i + 1])
        elif in_ros_args and arg.startswith("--params-file="):
            files.append(arg.partition("=")[2])
    return files


def params_file_error(argv) -> str | None:
    """One line naming the first params file of ``argv`` that is missing, unreadable or not a YAML
    mapping, or None. rcl would otherwise fail inside ``rclpy.init`` with a traceback."""
    for path in params_files(argv):
        try:
            read_params_file(path)
        except ParameterError as err:
            return str(err)
    return None


def warn_unmatched_params_files(node, files) -> list[str]:
    """One warning line per params file in ``files`` that gives ``node`` nothing because its sections are
    written for another namespace (``gpf_estimator:`` is ``/gpf_estimator``, not
    ``/lander/gpf_estimator``) or for other nodes only; returns the files warned about."""
    fqn, warned = node.get_fully_qualified_name(), []
    for path in files:
        try:
            sections = read_params_file(path)
        except ParameterError:
            continue  # main() refuses these before rclpy.init
        named = unmatched_sections(sections, fqn)
        if named is None:
            continue
        listed = ", ".join(repr(str(k)) for k in (named or sections)) or "none"
        node.get_logger().warning(
            f"params file {path} sets nothing for {fqn}: no section applies to it (sections: {listed}); "
            f"write '/**/{node.get_name()}:' to match the node in any namespace (docs/ros.md, Parameters)")
        warned.append(str(path))
    return warned


def warn_undeclared(node) -> list[str]:
    """One warning line naming the parameters given to ``node`` (``--ros-args -p``, params files) that it
    does not declare, which it therefore ignores; returns their names. Call after declaring."""
    # rclpy keeps the overrides from the command line and params files only in this attribute
    names = sorted(name for name in node._parameter_overrides if not node.has_parameter(name))
    if names:
        node.get_logger().warning(f"ignoring parameter(s) that {node.get_name()} does not declare: "
                                  f"{', '.join(names)} (ros2 param list {node.get_fully_qualified_name()} "
                                  "lists the declared ones; docs/ros.md)")
    return names
