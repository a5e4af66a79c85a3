"""The rig node's parameters, declared once (ParamSpec: type, range, description); docs/rig.md
lists them from here. Everything about the instruments is in the rig YAML (``config``)."""

from __future__ import annotations

from ops_contract.node_params import DIAGNOSTICS_PERIOD_SPEC, ParamSpec, samples_per_slot_spec

PARAMS = [
    ParamSpec(
        "config",
        "",
        "path of the rig YAML: instruments, limits, calibration (docs/rig.md)",
        read_only=True,
    ),
    ParamSpec(
        "rate_hz",
        -1.0,
        "readings per second (-1: the YAML's rate_hz)",
        low=1.0,
        high=1000.0,
        special=(-1.0,),
        read_only=True,
    ),
    samples_per_slot_spec("trace samples per pulse slot in ops/intensity"),
    ParamSpec(
        "reconnect_period_s",
        1.0,
        "time between attempts to reach an instrument that is gone",
        low=0.05,
        high=60.0,
        read_only=True,
    ),
    ParamSpec(
        "full_scale_window",
        250,
        "readings whose median summed slot energy (less the dark slots' floor), above the "
        "calibrated full scale, raises it (a stack shows no more light than its perfect stack; "
        "0: keep the calibration's)",
        low=0,
        high=100000,
        read_only=True,
    ),
    DIAGNOSTICS_PERIOD_SPEC,
    ParamSpec(
        "park_timeout_s",
        10.0,
        "longest time the park on shutdown may take at the slew limit",
        low=0.0,
        high=600.0,
        read_only=True,
    ),
]


def markdown_table(params=PARAMS) -> str:
    """The parameters as the Markdown table of docs/rig.md (a test keeps the two equal)."""
    rows = ["| parameter | default | allowed | meaning |", "|---|---|---|---|"]
    for p in params:
        default = f'"{p.default}"' if isinstance(p.default, str) else f"{p.default}"
        rows.append(f"| `{p.name}` | {default} | {p.allowed} | {p.description} |")
    return "\n".join(rows) + "\n"
