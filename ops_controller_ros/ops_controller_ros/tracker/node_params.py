"""The tracker node's side of :class:`.params.TrackerParams`: which fields are parameters of the
node, their values there and the node's ParamSpecs, all read from the fields' declarations."""

from __future__ import annotations

from dataclasses import fields

from .params import TrackerParams


def declared(name: str) -> dict:
    """The declaration (doc, low, high, ...) of the field ``name`` of TrackerParams."""
    return TrackerParams.__dataclass_fields__[name].metadata


#: The fields of TrackerParams that are parameters of the tracker node, in declaration order.
NODE_FIELDS = tuple(f.name for f in fields(TrackerParams) if f.metadata.get("node"))


def node_defaults() -> dict:
    """The node's values of its TrackerParams fields: the defaults, except the real-time caps."""
    base = TrackerParams()
    out = {}
    for name in NODE_FIELDS:
        meta = declared(name)
        out[name] = getattr(base, name) if meta["node_default"] is None else meta["node_default"]
    return out


def node_param_specs() -> list:
    """The node's ParamSpecs of its TrackerParams fields, generated from the declarations."""
    from ops_contract.node_params import ParamSpec

    specs = []
    for name, default in node_defaults().items():
        meta = declared(name)
        specs.append(
            ParamSpec(
                name,
                default,
                meta["doc"],
                low=meta["low"],
                high=meta["high"],
                low_exclusive=meta["low_open"],
                choices=meta["choices"],
            )
        )
    return specs
