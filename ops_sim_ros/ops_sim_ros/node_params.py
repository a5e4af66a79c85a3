"""Declaring and validating node parameters with descriptors, for every node of the project.

Each parameter is described once (:class:`ParamSpec`): its default, a description, and the values
it allows. :func:`declare_all` declares them with ``ParameterDescriptor`` ranges (visible in
``ros2 param describe``) and turns any bad value into a :class:`ParameterError` that names the
parameter and the allowed values; :func:`check_value` validates a runtime change the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node

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
    read_only: bool = False

    @property
    def allowed(self) -> str:
        if self.choices:
            return "one of " + ", ".join(self.choices)
        kind = type(self.default).__name__
        if kind == "bool":
            return "true or false"
        if self.low is not None and self.high is not None:
            return f"{kind} in {'(' if self.low_exclusive else '['}{self.low}, {self.high}]"
        if self.low is not None:
            return f"{kind} {'>' if self.low_exclusive else '>='} {self.low}"
        return kind

    def descriptor(self) -> ParameterDescriptor:
        d = ParameterDescriptor(
            name=self.name,
            description=self.description,
            additional_constraints=f"allowed: {self.allowed}",
            read_only=self.read_only,
        )
        # Ranges are checked by check_value (for a clear message); the descriptor carries them
        # for tools, with both ends set as ROS requires.
        if isinstance(self.default, int) and not isinstance(self.default, bool):
            if self.low is not None and self.high is not None:
                d.integer_range = [
                    IntegerRange(from_value=int(self.low), to_value=int(self.high), step=1)
                ]
        elif isinstance(self.default, float) and self.low is not None and self.high is not None:
            d.floating_point_range = [
                FloatingPointRange(from_value=float(self.low), to_value=float(self.high), step=0.0)
            ]
        return d


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
        too_low = spec.low is not None and (
            value <= spec.low if spec.low_exclusive else value < spec.low
        )
        too_high = spec.high is not None and value > spec.high
        if too_low or too_high:
            return f"{spec.name} must be {spec.allowed} (got {value!r})"
    return None


def declare_all(node: Node, specs: list[ParamSpec]) -> dict:
    """Declare every parameter; return their values, or raise ParameterError naming the bad one."""
    values = {}
    for spec in specs:
        try:
            param = node.declare_parameter(
                spec.name, spec.default, spec.descriptor(), ignore_override=False
            )
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            raise ParameterError(f"{spec.name} must be {spec.allowed} ({exc})") from None
        value = coerce(spec, param.value)
        problem = check_value(spec, value)
        if problem:
            raise ParameterError(problem)
        values[spec.name] = value
    return values
