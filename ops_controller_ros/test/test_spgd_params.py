"""SPGD-PID's parameters are declared once (spgd.SpgdParams): the dataclass in process and the
``spgd`` node's parameters refuse the same values, at the same bounds, in the same words."""

from __future__ import annotations

import math
from dataclasses import fields

import pytest
from ops_controller_ros.param_fields import allowed, check, declare, problem
from ops_controller_ros.spgd import RECOVERIES, SpgdParams

pytest.importorskip("rclpy")
from ops_contract.node_params import check_value
from ops_contract.ros_interface import ParameterError
from ops_controller_ros.spgd_node import PARAMS

SPECS = {spec.name: spec for spec in PARAMS}
NUMBERS = [f.name for f in fields(SpgdParams) if type(f.default) in (int, float)]


def _outside(spec) -> list:
    """The values just outside a numeric parameter's range: one unit (int) or one ulp (float)
    past each end, the open lower end itself."""
    low, high = spec.low, spec.high
    if isinstance(spec.default, int):
        return [low if spec.low_exclusive else low - 1, high + 1]
    below = low if spec.low_exclusive else math.nextafter(low, -math.inf)
    return [below, math.nextafter(high, math.inf), float("nan"), math.inf]


def _inside(spec) -> list:
    low, high = spec.low, spec.high
    if spec.low_exclusive:
        low = low + 1 if isinstance(spec.default, int) else math.nextafter(low, math.inf)
    return [low, high, spec.default]


def _refused_in_process(name: str, value) -> str | None:
    try:
        SpgdParams(**{name: value})
    except ValueError as exc:
        return str(exc)
    return None


def test_every_field_is_a_node_parameter_with_its_declaration():
    assert list(SPECS) == [f.name for f in fields(SpgdParams)]
    for f in fields(SpgdParams):
        spec = SPECS[f.name]
        assert spec.default == f.default and type(spec.default) is type(f.default)
        assert spec.description == f.metadata["doc"] and spec.description
        assert (spec.low, spec.high, spec.low_exclusive, spec.choices) == (
            f.metadata["low"],
            f.metadata["high"],
            f.metadata["low_open"],
            f.metadata["choices"],
        )
        if f.name in NUMBERS:  # every number has both ends: no infinity gets through
            assert spec.low is not None and spec.high is not None
    assert SPECS["recovery"].choices == RECOVERIES


@pytest.mark.parametrize("name", NUMBERS)
def test_a_value_out_of_range_is_refused_by_both_in_the_same_words(name):
    spec = SPECS[name]
    for value in _outside(spec):
        node_says = check_value(spec, value)
        assert node_says is not None, (name, value)
        assert node_says.startswith(f"{name} must be {spec.allowed} (got ")
        assert _refused_in_process(name, value) == node_says
    for value in _inside(spec):
        assert check_value(spec, value) is None, (name, value)
        assert _refused_in_process(name, value) is None, (name, value)


@pytest.mark.parametrize(
    ("name", "value"),
    [("recovery", "sometimes"), ("recovery", ""), ("normalized", "yes"), ("gain", "0.1")],
)
def test_a_wrong_choice_or_type_is_refused_by_both_in_the_same_words(name, value):
    node_says = check_value(SPECS[name], value)
    assert node_says is not None and node_says.startswith(f"{name} must be ")
    assert _refused_in_process(name, value) == node_says


def test_an_integer_for_a_float_is_taken_by_both_and_named_alike_when_refused():
    assert SpgdParams(gain=2, restart_range_fs=3).gain == 2  # as -p gain:=2 on the command line
    assert check_value(SPECS["gain"], 2) is None
    assert _refused_in_process("gain", 0) == check_value(SPECS["gain"], 0)
    assert "(got 0.0)" in check_value(SPECS["gain"], 0)
    assert _refused_in_process("restart_after", True) == check_value(SPECS["restart_after"], True)


def test_the_declaration_helpers_word_and_check_as_the_node_does():
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class Example:
        rate: float = declare(1.0, "a rate", 0.0, low_open=True)
        count: int = declare(3, "a count", 1, 9)
        name: str = declare("a", "a name", choices=("a", "b"))

    meta = {f.name: f.metadata for f in fields(Example)}
    assert allowed(1.0, meta["rate"]) == "float > 0.0"
    assert allowed(3, meta["count"]) == "int in [1, 9]"
    assert allowed("a", meta["name"]) == "one of a, b"
    assert problem("rate", 1.0, meta["rate"], 1e300) is None  # no upper end declared
    assert problem("count", 3, meta["count"], 2.0) == "count must be int in [1, 9] (got 2.0)"
    with pytest.raises(ValueError, match=r"name must be one of a, b \(got 'c'\)"):
        check(Example(name="c"))
    check(Example())


@pytest.fixture
def make_node():
    from nodes_in_process import NodesInProcess
    from ops_controller_ros.spgd_node import SpgdNode

    nodes = NodesInProcess()
    yield lambda *overrides: nodes.start(SpgdNode, *overrides)
    nodes.close()


@pytest.mark.parametrize(
    ("override", "says"),
    [
        ("gain:=0.0", r"gain must be float in \(0\.0, 1000000\.0\] \(got 0\.0\)"),
        ("momentum:=1.0", r"momentum must be float in \[0\.0, 0\.999\] \(got 1\.0\)"),
        ("restart_after:=0", r"restart_after must be int in \[1, 100000\]"),  # rclpy's range
        ("recovery:=sometimes", r"recovery must be one of restart, none \(got 'sometimes'\)"),
        ("integral_limit_fs:=-1", r"integral_limit_fs must be float in \[0\.0, 1000\.0\]"),
    ],
)
def test_the_node_refuses_a_bad_value_naming_it_and_what_is_allowed(make_node, override, says):
    with pytest.raises(ParameterError, match=says):
        make_node(override)
    name, _, value = override.partition(":=")
    spec = SPECS[name]
    value = spec.default.__class__(value) if not isinstance(spec.default, str) else value
    with pytest.raises(ValueError, match=says):  # in process: the same bound, the same words
        SpgdParams(**{name: value})


def test_the_node_builds_spgd_from_its_parameters(make_node):
    node = make_node("integral_limit_fs:=2", "restart_after:=7", "recovery:=none")
    assert node._params == SpgdParams(integral_limit_fs=2.0, restart_after=7, recovery="none")
    assert node.get_parameter("integral_limit_fs").value == 2.0
