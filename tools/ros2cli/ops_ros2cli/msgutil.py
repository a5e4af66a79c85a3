"""Interface import and message <-> YAML conversion.

Behaves like ``rosidl_runtime_py`` (``get_message``, ``message_to_yaml``,
``set_message_fields``), which the ROS 2 Jazzy wheels do not ship.
"""

import array
import importlib
import sys
from collections import OrderedDict

import yaml


def _split_identifier(identifier, kind):
    parts = identifier.split("/")
    if len(parts) == 2:
        package, name = parts
    elif len(parts) == 3 and parts[1] == kind:
        package, name = parts[0], parts[2]
    else:
        raise ValueError(f"Invalid interface identifier '{identifier}'")
    if not package or not name:
        raise ValueError(f"Invalid interface identifier '{identifier}'")
    return package, name


def get_message(identifier):
    """Import ``pkg/msg/Name`` (or ``pkg/Name``) and return the message class."""
    package, name = _split_identifier(identifier, "msg")
    module = importlib.import_module(f"{package}.msg")
    cls = getattr(module, name)
    if not hasattr(cls, "get_fields_and_field_types"):
        raise ValueError(f"'{identifier}' is not a message")
    return cls


def get_service(identifier):
    """Import ``pkg/srv/Name`` (or ``pkg/Name``) and return the service class."""
    package, name = _split_identifier(identifier, "srv")
    module = importlib.import_module(f"{package}.srv")
    return getattr(module, name)


def _numpy():
    try:
        import numpy
    except ImportError:  # pragma: no cover - rclpy depends on numpy
        return None
    return numpy


def _convert_value(value, truncate_length=None, no_arr=False, no_str=False):
    numpy = _numpy()
    if isinstance(value, bytes):
        if truncate_length is not None and len(value) > truncate_length:
            value = "".join(chr(c) for c in value[:truncate_length]) + "..."
        else:
            value = "".join(chr(c) for c in value)
    elif isinstance(value, str):
        if no_str:
            value = f"<string length: <{len(value)}>>"
        elif truncate_length is not None and len(value) > truncate_length:
            value = value[:truncate_length] + "..."
    elif isinstance(value, (array.array, list, tuple)) or (
        numpy is not None and isinstance(value, numpy.ndarray)
    ):
        if no_arr:
            kind = value.typecode if isinstance(value, array.array) else type(value).__name__
            return f"<array type: {kind}, length: {len(value)}>"
        typename = tuple if isinstance(value, tuple) else list
        if truncate_length is not None and len(value) > truncate_length:
            value = typename(
                [
                    _convert_value(v, truncate_length, no_arr, no_str)
                    for v in value[:truncate_length]
                ]
                + ["..."]
            )
        else:
            value = typename([_convert_value(v, truncate_length, no_arr, no_str) for v in value])
    elif isinstance(value, dict):
        value = OrderedDict(
            (_convert_value(k), _convert_value(v, truncate_length, no_arr, no_str))
            for k, v in value.items()
        )
    elif numpy is not None and isinstance(value, numpy.generic):
        value = value.item()
    elif not isinstance(value, (bool, float, int)):
        # neither a collection nor a primitive: a nested message
        value = message_to_ordereddict(value, truncate_length, no_arr, no_str)
    return value


def message_to_ordereddict(msg, truncate_length=None, no_arr=False, no_str=False):
    """Convert a message to an OrderedDict in field order (like rosidl_runtime_py)."""
    d = OrderedDict()
    for field_name in msg.get_fields_and_field_types():
        value = getattr(msg, field_name)
        d[field_name] = _convert_value(value, truncate_length, no_arr, no_str)
    return d


class _Dumper(yaml.SafeDumper):
    pass


def _represent_ordereddict(dumper, data):
    items = [(dumper.represent_data(k), dumper.represent_data(v)) for k, v in data.items()]
    return yaml.nodes.MappingNode("tag:yaml.org,2002:map", items)


_Dumper.add_representer(OrderedDict, _represent_ordereddict)


def message_to_yaml(msg, truncate_length=None, no_arr=False, no_str=False, flow_style=False):
    """Render a message as YAML the way ``ros2 topic echo`` does."""
    return yaml.dump(
        message_to_ordereddict(msg, truncate_length, no_arr, no_str),
        Dumper=_Dumper,
        allow_unicode=True,
        width=sys.maxsize,
        default_flow_style=flow_style,
    )


def _import_namespaced(namespaced_type):
    module = importlib.import_module(".".join(namespaced_type.namespaces))
    return getattr(module, namespaced_type.name)


def _now_msg():
    from rclpy.clock import Clock

    return Clock().now().to_msg()


def set_message_fields(msg, values):
    """Fill ``msg`` from a dict (like rosidl_runtime_py.set_message_fields).

    Supports ``auto`` for a std_msgs/Header and ``now`` for a builtin_interfaces/Time
    (the current time), as ``ros2 topic pub`` does.
    """
    from rosidl_parser.definition import AbstractNestedType, NamespacedType

    numpy = _numpy()
    if not isinstance(values, dict):
        raise TypeError(
            f"Expected a dictionary for '{type(msg).__name__}', got {type(values).__name__}"
        )
    slot_types = dict(zip(msg.get_fields_and_field_types(), msg.SLOT_TYPES, strict=False))
    for field_name, field_value in values.items():
        field = getattr(msg, field_name)
        field_type = type(field)
        qualified = f"{field_type.__module__}.{field_type.__name__}"
        if field_type is array.array:
            value = array.array(field.typecode, field_value)
        elif numpy is not None and field_type is numpy.ndarray:
            value = numpy.array(field_value, dtype=field.dtype)
        elif type(field_value) is field_type:
            value = field_value
        elif qualified == "std_msgs.msg._header.Header" and field_value == "auto":
            value = field_type(stamp=_now_msg())
        elif qualified == "builtin_interfaces.msg._time.Time" and field_value == "now":
            value = _now_msg()
        else:
            try:
                value = field_type(field_value)
            except TypeError:
                value = field_type()
                set_message_fields(value, field_value)
        rosidl_type = slot_types[field_name]
        if isinstance(rosidl_type, AbstractNestedType) and isinstance(
            rosidl_type.value_type, NamespacedType
        ):
            element_type = _import_namespaced(rosidl_type.value_type)
            elements = []
            for element_value in value:
                if isinstance(element_value, element_type):
                    elements.append(element_value)
                    continue
                element = element_type()
                set_message_fields(element, element_value)
                elements.append(element)
            value = elements
        setattr(msg, field_name, value)


def fill_from_yaml(msg, text):
    """Fill ``msg`` from the YAML mapping ``text`` (the ``values`` argument of
    ``ros2 topic pub`` and ``ros2 service call``); return ``msg``.

    Raises RuntimeError with the real tool's message when the text is not YAML, not a
    mapping, or names a field the message does not have.
    """
    try:
        values = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        detail = " ".join(str(exc).split())
        raise RuntimeError(f"The passed value is not valid YAML: {detail}") from None
    if values is None:
        values = {}
    if not isinstance(values, dict):
        raise RuntimeError("The passed value needs to be a dictionary in YAML format")
    try:
        set_message_fields(msg, values)
    except Exception as exc:
        raise RuntimeError(f"Failed to populate field: {exc}") from None
    return msg
