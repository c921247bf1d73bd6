"""One parameter schema (issue 25): every parameter of the two nodes is one :class:`gpf_nav.schema.Spec`,
and what follows from it is checked here.

* ``docs/parameters.md`` and ``config/*.yaml`` are what ``gpf-nav parameters`` writes from the schemas;
* every bound and choice of an entry is applied: by :func:`check_estimator_parameters`, or, for the
  filter's options, by ``make_filter`` for the filters that use them; ``make_filter``'s defaults are the
  schema's;
* a new parameter is one schema entry: added to the table, a real node declares it (with its description,
  unit and bounds), refuses a value outside its bounds, and the generated table and params file list it.
"""
from __future__ import annotations

import inspect
import math
from dataclasses import fields
from pathlib import Path

import pytest

from gpf_nav.estimator.factory import FILTERS, make_filter
from gpf_nav.estimator.params import BY_NAME, ESTIMATOR, check_estimator_parameters
from gpf_nav.models.lunar import LunarDescentModel
from gpf_nav.schema import Spec, defaults, within
from gpf_nav.sim.sensor_suite import SuiteConfig
from gpf_nav.sim.simulator_params import SUITE, check_simulator_parameters, simulator_specs
from gpf_nav.tools.parameter_docs import generated_files, out_of_date

ROOT = Path(__file__).resolve().parents[1]


def test_generated_files_are_up_to_date():
    assert out_of_date(ROOT) == [], "run: gpf-nav parameters (from the repository root)"


def test_every_suite_field_is_described():
    assert set(SUITE) == {f.name for f in fields(SuiteConfig)}


def _outside(bounds: str, default) -> float:
    """A value just outside ``bounds`` (of the default's type)."""
    if bounds == "finite":
        return math.inf
    low = float(bounds.strip("[(>= ").split(",")[0])
    return low - 1 if isinstance(default, int) and not isinstance(default, bool) else low - 1e-3


def _inside_edge(bounds: str, default):
    """The lower edge when ``bounds`` include it, else the default."""
    if bounds.startswith((">=", "[")):
        low = float(bounds.strip("[>= ").split(",")[0])
        return int(low) if isinstance(default, int) else low
    return default


SCHEMA_CHECKED = [s for s in ESTIMATOR if s.bounds and not s.checked_by and s.default is not None
                  and not isinstance(s.default, (list, str))]


@pytest.mark.parametrize("spec", SCHEMA_CHECKED, ids=lambda s: s.name)
def test_the_node_applies_each_bound(spec):
    values = defaults(ESTIMATOR)
    values[spec.name] = _inside_edge(spec.bounds, spec.default)
    if spec.name == "monitor_false_alarm_rate":
        values["monitor_warn_false_alarm_rate"] = max(values[spec.name], 0.5)
    assert check_estimator_parameters(values) == []
    values[spec.name] = _outside(spec.bounds, spec.default)
    errors = check_estimator_parameters(values)
    assert any(f"'{spec.name}'" in e for e in errors), errors


FILTER_CHECKED = [s for s in ESTIMATOR if s.checked_by == "make_filter" and (s.bounds or s.choices)]
MODEL = LunarDescentModel()


@pytest.mark.parametrize("spec", FILTER_CHECKED, ids=lambda s: s.name)
def test_make_filter_applies_each_filter_option_bound(spec):
    """Outside its bounds (or choices) the filters that use the option refuse it, naming it; at the edge
    of the bounds one of them takes it (the schema's bounds are the widest; enkf needs n_particles >= 2)."""
    options = {s.name: s.default for s in ESTIMATOR if s.group == "Filter" and s.name != "filter"}
    bad = "bogus" if spec.choices else _outside(spec.bounds, spec.default)
    if spec.name == "filter":
        with pytest.raises(ValueError, match="'filter'"):
            make_filter(bad, MODEL, **options)
        return
    refused = []
    for name in FILTERS:
        try:
            make_filter(name, MODEL, **{**options, spec.name: bad})
        except ValueError as err:
            refused.append(name)
            assert f"'{spec.name}'" in str(err)
    assert refused, f"no filter refuses {spec.name} = {bad!r}"
    if spec.bounds:
        edge = {**options, "n_particles": 20, spec.name: _inside_edge(spec.bounds, spec.default)}
        taken = []
        for name in refused:
            try:
                taken.append(make_filter(name, MODEL, **edge))
            except ValueError:
                pass
        assert taken, f"every filter refuses {spec.name} at the edge of {spec.bounds}"


def test_make_filter_defaults_are_the_schema_defaults():
    signature = inspect.signature(make_filter).parameters
    for spec in ESTIMATOR:
        if spec.name in signature and spec.name != "filter":
            default = signature[spec.name].default  # (a list parameter's default is a tuple there)
            assert (list(default) if isinstance(default, tuple) else default) == spec.default, spec.name


def test_simulator_bounds_and_rule():
    values = defaults(simulator_specs())
    assert check_simulator_parameters(values) == []
    assert "'clock_rate' = 0.0 must be positive" in check_simulator_parameters({**values, "clock_rate": 0.0})[0]
    assert "publish_clock" in check_simulator_parameters({**values, "publish_clock": False, "rate_factor": 2.0})[0]


def test_bounds_notation():
    assert within("[0, 1)", 0.0) and not within("[0, 1)", 1.0) and within("(0, 1]", 1.0)
    assert within(">= 2", 2) and not within("> 0", 0.0) and not within("> 0", math.nan)
    assert within("finite", -1e300) and not within("finite", math.inf)


# --- a new parameter is one schema entry -------------------------------------------------------------------
NEW = Spec("test_only_gain", 2.5, "A parameter that exists only in this test.", "m/s", "> 0",
           group="Outputs and diagnostics")


@pytest.fixture
def new_parameter():
    """:data:`NEW` added to the estimator's schema, and only there."""
    ESTIMATOR.append(NEW)
    BY_NAME[NEW.name] = NEW
    yield NEW
    ESTIMATOR.remove(NEW)
    del BY_NAME[NEW.name]


def test_a_new_parameter_is_validated_and_documented(new_parameter):
    values = defaults(ESTIMATOR)
    assert values[NEW.name] == 2.5 and check_estimator_parameters(values) == []
    assert check_estimator_parameters({**values, NEW.name: -1.0}) == [
        "parameter 'test_only_gain' = -1.0 must be positive"]
    files = generated_files()
    assert "| `test_only_gain` | float | `2.5` | > 0 | m/s | A parameter that exists only in this test. |" \
        in files["docs/parameters.md"]
    assert "    test_only_gain: 2.5" in files["config/estimator.yaml"]


def test_a_new_parameter_is_declared_by_the_node(new_parameter):
    rclpy = pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter

    from domains import fresh_domain
    from gpf_nav.ros.estimator_node import EstimatorNode
    from gpf_nav.schema import ParameterError

    context = rclpy.Context()
    rclpy.init(args=[], context=context, domain_id=fresh_domain())
    try:
        node = EstimatorNode(context=context, parameter_overrides=[Parameter(NEW.name, value=4.0)])
        try:
            assert node.get_parameter(NEW.name).value == 4.0 and node.params[NEW.name] == 4.0
            descriptor = node.describe_parameter(NEW.name)
            assert descriptor.read_only and "m/s" in descriptor.description and "> 0" in descriptor.description
        finally:
            node.destroy_node()
        with pytest.raises(ParameterError, match="'test_only_gain' = -1.0 must be positive"):
            EstimatorNode(context=context, parameter_overrides=[Parameter(NEW.name, value=-1.0)])
    finally:
        rclpy.try_shutdown(context=context)
