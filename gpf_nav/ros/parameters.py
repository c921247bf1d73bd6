"""Declare a parameter table of :mod:`gpf_nav.estimator.params` on an rclpy node, and warn about
the parameters a node was given but does not declare.

Numbers are declared with dynamic typing, so ``1`` in a YAML file is accepted for a float; every value is
returned coerced to its default's type (:func:`gpf_nav.estimator.params.coerce`).
"""
from __future__ import annotations

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterUninitializedException

from gpf_nav.estimator.params import Spec, coerce


def declare(node, specs: list[Spec]) -> dict:
    """Declare ``specs`` on ``node`` and return ``{name: value}`` coerced to the defaults' types."""
    values = {}
    for spec in specs:
        numeric = isinstance(spec.default, (int, float)) and not isinstance(spec.default, bool)
        descriptor = ParameterDescriptor(description=spec.description, read_only=not spec.live,
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
