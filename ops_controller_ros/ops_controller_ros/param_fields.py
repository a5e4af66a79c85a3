"""A controller's parameters declared once: each a dataclass field with its meaning and its allowed
values, from which both the dataclass's own check and its node's parameters are made.

``declare(default, doc, low, high, low_open=..., choices=...)`` is the field; :func:`check` (the
dataclass's ``__post_init__``) refuses a value outside it; :func:`param_specs` gives the node's
:class:`~ops_contract.node_params.ParamSpec` of every field (the same name, default, description
and range), so ``declare_all`` refuses on the command line exactly what the dataclass refuses in
process, in the same words: "gain must be float in (0.0, 1000000.0] (got 0.0)", the wording of
``ParamSpec.allowed`` and ``node_params.check_value``. Pure Python: no rclpy (the node imports
``node_params``, here only :func:`param_specs` does).
"""

from __future__ import annotations

import math
from dataclasses import field, fields
from numbers import Integral, Real


def declare(default, doc: str, low=None, high=None, *, low_open: bool = False, choices=()):
    """A dataclass field with its description and allowed values: numbers in [``low``, ``high``]
    (``low_open``: ``low`` itself excluded), a string one of ``choices``, a bool either."""
    meta = {"doc": doc, "low": low, "high": high, "low_open": low_open, "choices": tuple(choices)}
    return field(default=default, metadata=meta)


def allowed(default, meta) -> str:
    """The allowed values of a declared field, worded as ``ParamSpec.allowed`` words them."""
    if meta["choices"]:
        return "one of " + ", ".join(meta["choices"])
    kind = type(default).__name__
    if kind == "bool":
        return "true or false"
    low, high = meta["low"], meta["high"]
    if low is not None and high is not None:
        return f"{kind} in {'(' if meta['low_open'] else '['}{low}, {high}]"
    if low is not None:
        return f"{kind} {'>' if meta['low_open'] else '>='} {low}"
    return kind


def _right_type(default, value) -> bool:
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(value, bool):
        return False
    if isinstance(default, int):
        return isinstance(value, Integral)
    if isinstance(default, float):
        return isinstance(value, Real)  # an integer too, as the node takes -p gain:=1
    return isinstance(value, type(default))


def problem(name: str, default, meta, value) -> str | None:
    """Why ``value`` is not allowed for the declared field ``name``, or None: the message of
    ``node_params.check_value`` for the field's ParamSpec."""
    if not _right_type(default, value):
        return f"{name} must be {allowed(default, meta)} (got {value!r})"
    if isinstance(default, float):
        value = float(value)  # as the node takes an integer: its message shows 1.0 for 1
    bad = f"{name} must be {allowed(default, meta)} (got {value!r})"
    if meta["choices"]:
        return None if value in meta["choices"] else bad
    if isinstance(default, bool) or not isinstance(value, Real):
        return None
    if math.isnan(value):
        return bad
    low, high = meta["low"], meta["high"]
    too_low = low is not None and (value <= low if meta["low_open"] else value < low)
    too_high = high is not None and value > high
    return bad if too_low or too_high else None


def check(params) -> None:
    """Raise ValueError naming the first field of the dataclass ``params`` whose value its
    declaration does not allow."""
    for f in fields(params):
        why = problem(f.name, f.default, f.metadata, getattr(params, f.name))
        if why:
            raise ValueError(why)


def param_specs(cls) -> list:
    """The node's ParamSpec of every declared field of the dataclass ``cls``, in order."""
    from ops_contract.node_params import ParamSpec

    return [
        ParamSpec(
            f.name,
            f.default,
            f.metadata["doc"],
            low=f.metadata["low"],
            high=f.metadata["high"],
            low_exclusive=f.metadata["low_open"],
            choices=f.metadata["choices"],
        )
        for f in fields(cls)
    ]
