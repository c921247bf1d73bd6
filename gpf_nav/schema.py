"""A node's parameters declared once, as a table of :class:`Spec`: name, type (the default's), default,
bounds or choices, unit and description.

Everything else follows from the table: :func:`coerce` converts a given value to the parameter's type,
:func:`check` applies the bounds and choices, :func:`markdown_table` writes the reference table of
``docs/parameters.md`` and :func:`params_file` a ROS 2 params file of the defaults (``config/*.yaml``).
:func:`gpf_nav.ros.parameters.declare` declares a table on a node. No ROS here.

Bounds are written as the docs show them: ``"> 0"``, ``">= 2"``, ``"[0, 1)"``, ``"(0, 1]"`` or
``"finite"`` (numbers), ``"non-empty"`` (strings); a list parameter's bounds apply to each element. A
parameter whose rules depend on another parameter's value (a filter option means something only to some filters) names the code that
checks it in ``checked_by``; its bounds are then the widest that code allows, and a test holds it to them.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass


class ParameterError(ValueError):
    """An invalid parameter value; the message names the parameter and says what is allowed."""


@dataclass(frozen=True)
class Spec:
    """One parameter. ``default`` None: an optional list of ``length`` items (floats, or strings with
    ``item`` ``"string"``) with no default, none given being an empty list."""
    name: str
    default: object
    description: str
    unit: str = ""
    bounds: str = ""
    choices: tuple[str, ...] = ()
    length: int = 0          # lists: the number of elements (0: any)
    symbol: str = ""         # the name the papers and messages give it (ess_threshold: tau)
    group: str = ""          # heading of the docs table and the params file
    live: bool = False       # may be changed at run time with ros2 param set
    checked_by: str = ""     # the code that checks it, when not :func:`check` (see the module docstring)
    item: str = "float"      # a list's elements: "float" or "string"

    @property
    def type_name(self) -> str:
        """``bool``, ``int``, ``float``, ``string`` or ``float[]`` / ``float[n]`` / ``string[]``."""
        if self.default is None or isinstance(self.default, list):
            return f"{self.item}[{self.length}]" if self.length else f"{self.item}[]"
        return {bool: "bool", int: "int", float: "float", str: "string"}[type(self.default)]

    @property
    def help(self) -> str:
        """The description with the unit and what is allowed, as the node's parameter descriptor says it."""
        allowed = ", ".join(part for part in (self.bounds, " | ".join(self.choices)) if part)
        extras = "; ".join(part for part in (self.unit and f"unit {self.unit}", allowed and f"allowed {allowed}")
                           if part)
        return f"{self.description} ({extras})" if extras else self.description


def coerce(spec: Spec, value):
    """``value`` converted to the type of ``spec.default``; ParameterError when it cannot be."""
    default = spec.default
    try:
        if default is None and spec.item == "string":
            if value is None or len(value) == 0:
                return None
            if isinstance(value, str) or not all(isinstance(v, str) for v in value):
                raise TypeError
            return list(value)
        if default is None:
            return None if value is None or len(value) == 0 else [float(v) for v in value]
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise TypeError
            return value
        if isinstance(default, int):
            if isinstance(value, bool) or not float(value).is_integer():
                raise TypeError
            return int(value)
        if isinstance(default, float):
            if isinstance(value, (bool, str)):
                raise TypeError
            return float(value)
        if isinstance(default, list):
            return [float(v) for v in value]
        if isinstance(default, str):
            if not isinstance(value, str):
                raise TypeError
            return value
    except (TypeError, ValueError):
        pass
    raise ParameterError(f"parameter '{spec.name}' = {value!r} has the wrong type; expected "
                         f"{type(default).__name__ if default is not None else _list_type(spec)}")


def _list_type(spec: Spec) -> str:
    count = spec.length or "any number of"
    return f"a list of {count} {'strings' if spec.item == 'string' else 'floats'}"


_INTERVAL = re.compile(r"([\[(])\s*(\S+)\s*,\s*(\S+)\s*([\])])")
_BOUND = re.compile(r"(>=|>)\s*(\S+)")


def within(bounds: str, x: float) -> bool:
    """Whether the number ``x`` satisfies ``bounds`` (module docstring); every bound implies finite."""
    if not math.isfinite(x):
        return False
    interval = _INTERVAL.fullmatch(bounds)
    if interval:
        left, low, high, right = interval.groups()
        low, high = float(low), float(high)
        return (x >= low if left == "[" else x > low) and (x <= high if right == "]" else x < high)
    bound = _BOUND.fullmatch(bounds)
    if bound:
        op, limit = bound.groups()
        return x >= float(limit) if op == ">=" else x > float(limit)
    if bounds == "finite":
        return True
    raise ValueError(f"unknown bounds {bounds!r}")


def _requirement(bounds: str) -> str:
    if bounds == "> 0":
        return "be positive"
    if bounds == "finite":
        return "be finite"
    return f"lie in {bounds}" if _INTERVAL.fullmatch(bounds) else f"be {bounds}"


def check_value(spec: Spec, value) -> str | None:
    """Why ``value`` (already coerced) breaks the bounds, choices or length of ``spec``, or None."""
    label = f"parameter '{spec.name}'" + (f" ({spec.symbol})" if spec.symbol else "")
    if spec.choices and value not in spec.choices:
        return f"{label} = {value!r} must be one of {', '.join(spec.choices)}"
    if isinstance(value, list) and spec.item == "string":
        return None if all(value) else f"{label} = {value!r} must not hold an empty name"
    if isinstance(value, list):
        if (spec.length and len(value) != spec.length) or not all(
                within(spec.bounds or "finite", v) for v in value):
            count = spec.length or "any number of"
            each = "finite" if spec.bounds in ("", "finite") else f"each {spec.bounds}"
            return f"{label} = {value!r} must be {count} numbers, {each}" + (f" [{spec.unit}]" if spec.unit else "")
        return None
    if spec.bounds == "non-empty":
        return None if value else f"{label} must not be empty"
    if spec.bounds and not isinstance(value, (bool, str)) and not within(spec.bounds, value):
        return f"{label} = {value!r} must {_requirement(spec.bounds)}"
    return None


def check(specs: list[Spec], values: dict) -> list[str]:
    """The bound, choice and length errors of ``values`` (coerced, ``{name: value}``) against ``specs``,
    skipping the parameters another piece of code checks (``checked_by``) and unset optional ones."""
    errors = []
    for spec in specs:
        if spec.checked_by or values.get(spec.name) is None:
            continue
        error = check_value(spec, values[spec.name])
        if error:
            errors.append(error)
    return errors


def defaults(specs: list[Spec]) -> dict:
    """``{name: default}`` (lists copied)."""
    return {s.name: list(s.default) if isinstance(s.default, list) else s.default for s in specs}


def yaml_value(value) -> str:
    """``value`` written as YAML reads it back: floats keep a decimal point, strings are quoted."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        text = repr(value)
        return text.replace("e", ".0e") if "e" in text and "." not in text else text
    if isinstance(value, list):
        return "[" + ", ".join(yaml_value(v) for v in value) + "]"
    if isinstance(value, str):
        return json.dumps(value)
    return str(value)


def params_file(specs: list[Spec], node: str, header: list[str]) -> str:
    """A ROS 2 params file of the defaults of ``specs`` for ``node`` in any namespace (``/**/node``), one
    commented line per parameter (``a.b`` written as ``b`` under ``a:``), ``header`` lines first (without
    the ``#``)."""
    lines = [f"# {line}".rstrip() for line in header] + [
        "", f"/**/{node}:{' ' * max(1, 45 - len(node))}# any namespace (rcl: \"{node}:\" would be /{node} only)",
        "  ros__parameters:"]
    group = section = None
    for spec in specs:
        if spec.group != group and spec.group:
            lines.append(f"    # {spec.group}")
        group = spec.group
        prefix, _, key = spec.name.rpartition(".")  # scenario.dt: "dt" under "scenario:"
        if prefix and prefix != section:
            lines.append(f"    {prefix}:")
        section = prefix
        indent = "      " if prefix else "    "
        entry = f"# {key}: [{spec.length or 'any number of'} values]" if spec.default is None else f"{key}: {yaml_value(spec.default)}"
        lines.append(f"{indent + entry:<47} # {spec.help}")
    return "\n".join(lines) + "\n"


def markdown_table(specs: list[Spec]) -> str:
    """The reference table of ``specs``: one Markdown table, a bold row opening each group."""
    out, group = ["| name | type | default | allowed | unit | description |", "|---|---|---|---|---|---|"], object()
    for spec in specs:
        if spec.group != group:
            group = spec.group
            if group:
                out.append(f"| **{group}** | | | | | |")
        allowed = " \\| ".join(spec.choices) if spec.choices else spec.bounds
        if spec.live:
            allowed = f"{allowed} (live)" if allowed else "(live)"
        default = "unset" if spec.default is None else yaml_value(spec.default)
        description = spec.description + (f" Checked by `{spec.checked_by}`." if spec.checked_by else "")
        description = description.replace("|", r"\|")
        out.append(f"| `{spec.name}` | {spec.type_name} | `{default}` | {allowed} | {spec.unit} | {description} |")
    return "\n".join(out) + "\n"
