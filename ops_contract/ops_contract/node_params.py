"""Declaring and validating node parameters with descriptors, for every node of the project.

Each parameter is described once (:class:`ParamSpec`): its type (that of its default), a
description, the values it allows and whether it may change while the node runs (``read_only``:
fixed after start). :func:`declare_all` declares them with ``ParameterDescriptor`` ranges (visible
in ``ros2 param describe``) and turns any bad value into a :class:`ParameterError` that names the
parameter and the allowed values; :func:`check_change` validates a runtime change the same way.
A float parameter takes an integer as well (``-p rate_hz:=50``, ``ros2 param set ... rate_hz 50``).

Live changes: :func:`declare_all` installs one validating callback per node. A node that can apply
a change passes ``on_change`` (an rclpy on-set callback, called once the values are valid); every
parameter of a node without one is fixed after start, so no change ever answers "successful" and
does nothing. ``use_sim_time`` cannot be switched on while a node runs (its timers would stop).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from .config import LIMITS
from .ros_interface import ParameterError


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: bool | int | float | str
    description: str
    low: float | None = None  # inclusive lower bound for numbers
    high: float | None = None  # inclusive upper bound for numbers
    choices: tuple[str, ...] = ()  # allowed strings
    low_exclusive: bool = False  # True: value must be > low
    read_only: bool = False  # True: fixed while the node runs (a change is refused with why)
    special: tuple = ()  # values allowed outside the range (e.g. -1: "the mode's default")

    @property
    def allowed(self) -> str:
        if self.choices:
            return "one of " + ", ".join(self.choices)
        kind = type(self.default).__name__
        if kind == "bool":
            return "true or false"
        if self.low is not None and self.high is not None:
            text = f"{kind} in {'(' if self.low_exclusive else '['}{self.low}, {self.high}]"
        elif self.low is not None:
            text = f"{kind} {'>' if self.low_exclusive else '>='} {self.low}"
        else:
            text = kind
        return " or ".join([*(f"{v:g}" for v in self.special), text])

    def descriptor(self) -> ParameterDescriptor:
        # read_only is enforced by check_change (with a reason naming the parameter), not by
        # rclpy (whose refusal does not say what to do), so the descriptor does not set it.
        d = ParameterDescriptor(
            name=self.name,
            description=self.description,
            additional_constraints=f"allowed: {self.allowed}"
            + ("; fixed while the node runs" if self.read_only else ""),
        )
        # Ranges are checked by check_value (for a clear message); the descriptor carries them
        # for tools, with both ends set as ROS requires.
        if self.special:
            pass  # the allowed values are not one interval: only check_value knows them
        elif isinstance(self.default, int) and not isinstance(self.default, bool):
            if self.low is not None and self.high is not None:
                d.integer_range = [
                    IntegerRange(from_value=int(self.low), to_value=int(self.high), step=1)
                ]
        elif isinstance(self.default, float) and self.low is not None and self.high is not None:
            d.floating_point_range = [
                FloatingPointRange(from_value=float(self.low), to_value=float(self.high), step=0.0)
            ]
        return d


# Parameters of both nodes that publish the optics' outputs (ops_sim and ops_rig), declared once.


def samples_per_slot_spec(description: str) -> ParamSpec:
    """``samples_per_slot``: trace samples per pulse slot, in the config's range, fixed after
    start."""
    low, high = LIMITS["samples_per_slot"]
    return ParamSpec("samples_per_slot", 8, description, low=low, high=high, read_only=True)


DIAGNOSTICS_PERIOD_SPEC = ParamSpec(
    "diagnostics_period_s", 1.0, "period of /diagnostics status", low=0.1, high=3600.0
)


def coerce(spec: ParamSpec, value):
    """``value`` as the parameter's type where ROS hands an integer for a float parameter."""
    if isinstance(spec.default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def check_value(spec: ParamSpec, value) -> str | None:
    """Why ``value`` is not allowed for ``spec``, or None."""
    want = type(spec.default)
    value = coerce(spec, value)
    if not isinstance(value, want) or (want is not bool and isinstance(value, bool)):
        return f"{spec.name} must be {spec.allowed} (got {value!r})"
    if spec.choices and value not in spec.choices:
        return f"{spec.name} must be {spec.allowed} (got {value!r})"
    if want in (int, float):
        if value != value:  # NaN
            return f"{spec.name} must be {spec.allowed} (got {value!r})"
        if value in spec.special:
            return None
        too_low = spec.low is not None and (
            value <= spec.low if spec.low_exclusive else value < spec.low
        )
        too_high = spec.high is not None and value > spec.high
        if too_low or too_high:
            return f"{spec.name} must be {spec.allowed} (got {value!r})"
    return None


def check_change(specs: dict[str, ParamSpec], name: str, value) -> str | None:
    """Why a runtime change of ``name`` to ``value`` is refused, or None (unknown names pass)."""
    spec = specs.get(name)
    if spec is None:
        return None
    if spec.read_only:
        return f"{name} cannot change while the node runs; restart the node"
    return check_value(spec, value)


def _float_spec_names(specs: list[ParamSpec]) -> set[str]:
    return {s.name for s in specs if isinstance(s.default, float)}


def declare_all(
    node: Node,
    specs: list[ParamSpec],
    on_change: Callable[[list[Parameter]], SetParametersResult] | None = None,
) -> dict:
    """Declare every parameter; return their values, or raise ParameterError naming the bad one.

    A float parameter is declared dynamically typed, so that an integer given on the command line
    is taken, then made a static double; runtime integers are turned into doubles before rclpy
    checks their type (a pre-set callback). Runtime changes are validated (:func:`check_change`)
    before ``on_change`` sees them; without ``on_change`` every parameter of ``specs`` is fixed."""
    values = {}
    floats = _float_spec_names(specs)
    for spec in specs:
        descriptor = spec.descriptor()
        if spec.name in floats:
            descriptor = ParameterDescriptor(
                name=spec.name, description=spec.description, dynamic_typing=True
            )
        try:
            param = node.declare_parameter(spec.name, spec.default, descriptor)
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            raise ParameterError(f"{spec.name} must be {spec.allowed} ({exc})") from None
        value = coerce(spec, param.value)
        problem = check_value(spec, value)
        if problem:
            raise ParameterError(problem)
        if spec.name in floats:  # from now on a static double
            static = spec.descriptor()
            static.type = Parameter.Type.DOUBLE.value
            msg_value = Parameter(spec.name, value=value).get_parameter_value()
            node.set_descriptor(spec.name, static, msg_value)
        values[spec.name] = value
    _convert_ints_for(node, floats)
    by_name = {s.name: s for s in specs}
    if on_change is None:  # nothing can apply a change: every parameter is fixed
        by_name = {n: replace(s, read_only=True) for n, s in by_name.items()}
    node.add_on_set_parameters_callback(lambda params: _validate(node, by_name, params, on_change))
    return values


def _validate(node: Node, specs: dict[str, ParamSpec], params, on_change) -> SetParametersResult:
    """The on-set callback of :func:`declare_all`: refuse with a reason, or pass to on_change."""
    ours = []
    for p in params:
        if p.name == "use_sim_time":
            if p.value != node.get_parameter("use_sim_time").value:
                return SetParametersResult(
                    successful=False,
                    reason="use_sim_time cannot change while the node runs (its timers would "
                    "wait for /clock); restart the node with -p use_sim_time:=true",
                )
            continue
        if p.name not in specs:
            continue  # another declare_all's, or rclpy's own
        problem = check_change(specs, p.name, coerce(specs[p.name], p.value))
        if problem:
            return SetParametersResult(successful=False, reason=problem)
        ours.append(p)
    if ours and on_change is not None:
        return on_change(ours)
    return SetParametersResult(successful=True)


#: The node attribute holding the names of its float parameters, across declare_all calls.
_FLOAT_NAMES = "_ops_float_parameter_names"


def _convert_ints_for(node: Node, floats: set[str]) -> None:
    """One pre-set callback per node turns integers into doubles for every declare_all's floats:
    rclpy concatenates the lists its pre-set callbacks return, so a second callback would hand
    each parameter on twice."""
    names = getattr(node, _FLOAT_NAMES, None)
    if names is None:
        names = set()
        setattr(node, _FLOAT_NAMES, names)
        node.add_pre_set_parameters_callback(lambda params: _ints_to_floats(params, names))
    names.update(floats)


def _ints_to_floats(params: list[Parameter], floats: set[str]) -> list[Parameter]:
    return [
        Parameter(p.name, value=float(p.value))
        if p.name in floats and p.type_ == Parameter.Type.INTEGER
        else p
        for p in params
    ]
