"""The argparse pieces the ``train``, ``evaluate`` and ``benchmark`` CLIs share.

One place for: the parser with its help formatter (each default printed once), the environment
options (``--stage``, ``--mode``, ``--split``, ``--detector``, choices from
:mod:`ops_contract.config`), the ``key=value`` parser (``--hyperparams``, ``--controller-param``,
``--env``) and the removal of ``--ros-args ...`` that ``ros2 run`` users may append.

Pure: imports neither rclpy nor torch nor gymnasium.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Iterable
from typing import Any

from ops_contract.config import (
    DETECTORS,
    MAX_STAGE,
    MODES,
    REALISMS,
    RIG_KEYS,
    SPLITS,
    TIME_KEYS,
    OpsConfig,
    make_config,
)

#: What ``--rig`` takes: the rig's figures and the keys of physical time (time_base, step_s,
#: vibration), which the simulator runs and the controller is told of.
RIG_OPTION_KEYS = (*RIG_KEYS, *TIME_KEYS)

#: The environment options and their defaults (the defaults of OpsConfig).
ENV_DEFAULTS: dict[str, Any] = {
    "stage": OpsConfig.stage,
    "mode": OpsConfig.mode,
    "split": OpsConfig.split,
    "detector": OpsConfig.detector,
}
_CHOICES = {"mode": MODES, "split": SPLITS, "detector": DETECTORS}
_HELP = {
    "stage": f"number of stacking stages N (1 to {MAX_STAGE})",
    "mode": "difficulty mode (initial errors and drift)",
    "split": "noise variant: train, or test (the shifted drift of hard and extreme)",
    "detector": "polarizer: the s port (physical); total: both polarizations (authors' code)",
}
#: ``defaults`` value meaning "taken from the model being evaluated".
FROM_MODEL = None


def int_in(low: int, high: int | None = None, what: str = "value"):
    """An argparse ``type``: an integer in [low, high] (no upper bound when high is None), so a
    value out of range is refused at parse time with the allowed range (``--stage 0`` was once
    read as "not given")."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what} must be an integer (got {text!r})") from None
        if value < low or (high is not None and value > high):
            allowed = f"from {low} to {high}" if high is not None else f">= {low}"
            raise argparse.ArgumentTypeError(f"{what} must be {allowed} (got {value})")
        return value

    parse.__name__ = what  # argparse names the type in its messages
    return parse


def non_negative_float(text: str) -> float:
    """An argparse ``type``: a finite number >= 0 (seconds; 0 often means "no limit")."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds (got {text!r})") from None
    if not (0.0 <= value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0 (got {text})")
    return value


#: ``--stage``: the number of stacking stages, 1 to MAX_STAGE.
stage_type = int_in(1, MAX_STAGE, "stage")
#: A count that must be at least one (episodes, steps, timesteps, ...).
positive_int = int_in(1, None, "count")


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Appends ``(default: X)`` once: not where the help already names its default, nor for
    options whose default is None / False (flags, "the model's")."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text or action.default in (None, False, argparse.SUPPRESS, []):
            return text
        return super()._get_help_string(action)


def make_parser(prog: str, description: str) -> argparse.ArgumentParser:
    """An ArgumentParser named ``ros2 run ops_gym_bridge <prog>`` with :class:`HelpFormatter`."""
    return argparse.ArgumentParser(
        prog=f"ros2 run ops_gym_bridge {prog}",
        description=description,
        formatter_class=HelpFormatter,
    )


def add_env_arguments(
    parser: argparse.ArgumentParser,
    defaults: dict[str, Any] | None = None,
    several: Iterable[str] = (),
    include: Iterable[str] = ("stage", "mode", "split", "detector"),
) -> None:
    """Add ``--stage``, ``--mode``, ``--split``, ``--detector`` to ``parser``.

    ``defaults`` overrides :data:`ENV_DEFAULTS` per name; a default of :data:`FROM_MODEL` (None)
    reads "(default: the model's; <ENV_DEFAULTS value> for a controller)". A name in
    ``several`` becomes a plural option taking one or more values (``--modes easy hard``,
    ``--splits train test``; dest ``modes``, ``splits``) whose default is a list (all
    choices unless ``defaults`` says otherwise).
    """
    defaults = {**ENV_DEFAULTS, **(defaults or {})}
    several = set(several)
    for name in include:
        default = defaults[name]
        kwargs: dict[str, Any] = {"help": _HELP[name]}
        if name == "stage":
            kwargs["type"] = stage_type
        else:
            kwargs["choices"] = _CHOICES[name]
        flag = f"--{name}"
        if name in several:
            flag += "s"
            kwargs["nargs"] = "+"
            if default is not FROM_MODEL and not isinstance(default, list | tuple):
                default = list(_CHOICES.get(name, [default]))
            default = None if default is None else list(default)
        if default is FROM_MODEL:
            kwargs["help"] += f" (default: the model's; {ENV_DEFAULTS[name]} for a controller)"
        parser.add_argument(flag, default=default, **kwargs)


def add_key_value_argument(parser: argparse.ArgumentParser, *flags: str, help: str) -> None:
    """A repeatable ``KEY=VALUE ...`` option (collected as strings; see parse_key_values)."""
    parser.add_argument(
        *flags, nargs="+", action="extend", default=[], metavar="KEY=VALUE", help=help
    )


def add_rig_arguments(parser: argparse.ArgumentParser, told: str) -> None:
    """``--realism PRESET`` and ``--rig KEY=VALUE ...``: the rig (docs/physics.md, "Rig
    imperfections") that the simulator runs and ``told`` knows of."""
    parser.add_argument(
        "--realism",
        choices=REALISMS,
        help="the rig's preset (docs/physics.md, 'Rig imperfections'): ideal (the default) or "
        f"lab; the simulator runs it and {told} is told of it",
    )
    add_key_value_argument(
        parser,
        "--rig",
        help=f"figures of the rig that the simulator runs AND {told} is told of (e.g. "
        "latency_steps=2 trace_adc_bits=8; time_base=seconds step_s=0.01 for a 100 Hz loop in "
        "physical time): " + ", ".join(RIG_OPTION_KEYS),
    )


def add_rig_randomize_argument(parser: argparse.ArgumentParser) -> None:
    """``--rig-randomize KEY=LOW:HIGH ...``: figures of the rig drawn anew for every episode
    of every environment (ops_contract.rig_randomization)."""
    from ops_contract.rig_randomization import RANGE_PRESETS

    parser.add_argument(
        "--rig-randomize",
        nargs="+",
        action="extend",
        default=None,
        metavar="KEY=LOW:HIGH",
        help="draw these figures of the rig anew at every episode of every environment, "
        "uniformly in [LOW, HIGH] (integers for latency_steps, dac_bits, trace_adc_bits, "
        "trace_averages), on top of --realism / --rig; KEY=VALUE fixes one; a named set of "
        f"ranges ({', '.join(RANGE_PRESETS)}: docs/physics.md, 'A rig drawn per episode') "
        "may come first, e.g. --rig-randomize lab latency_steps=0:3. Keys: "
        + ", ".join(RIG_KEYS)
        + " (default: none; --resume: the model's)",
    )


def hold_steps_type(text: str) -> int:
    """An argparse ``type`` for ``--hold-steps`` (train, evaluate): ``auto`` (0) or an integer
    from 1 to ``ops_contract.held.HOLD_STEPS_MAX``."""
    from ops_contract.held import HOLD_STEPS_AUTO, HOLD_STEPS_MAX, check_hold_steps

    if text.strip().lower() == "auto":
        return HOLD_STEPS_AUTO
    try:
        return check_hold_steps(int(text))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--hold-steps must be auto (or 0: the told latency_steps + 1) or an integer from 1 "
            f"to {HOLD_STEPS_MAX} (got {text!r})"
        ) from None


def resolve_rig_randomize(items: Iterable[str] | None):
    """The :class:`~ops_contract.rig_randomization.RigRanges` of ``--rig-randomize`` (ValueError
    naming the figure and its allowed range)."""
    from ops_contract.rig_randomization import RigRanges

    return RigRanges.parse(items)


def resolve_rig(realism: str | None, items: Iterable[str] | None) -> dict[str, Any]:
    """The OpsConfig fields of ``--realism`` and ``--rig``, checked as make_config checks them
    (ValueError naming the figure and what it may be)."""
    rig = parse_key_values(items, "--rig figure")
    unknown = sorted(set(rig) - set(RIG_OPTION_KEYS))
    if unknown:
        raise ValueError(
            f"--rig {', '.join(unknown)}: not a figure of the rig; allowed: "
            + ", ".join(RIG_OPTION_KEYS)
        )
    if realism is not None:
        rig["realism"] = realism
    make_config(**rig)
    return rig


def parse_key_value(text: str, what: str = "parameter") -> tuple[str, Any]:
    """``"key=value"`` -> (key, value parsed as YAML: ``1`` int, ``0.1`` float, ``[64, 64]``
    list, ``true`` bool, ``1e30`` float, anything else a string). ValueError names ``what``
    was malformed."""
    import yaml

    if "=" not in text:
        raise ValueError(f"{what} {text!r} must look like key=value")
    key, raw = text.split("=", 1)
    key = key.strip()
    if not key.isidentifier():
        raise ValueError(f"{what} name {key!r} is not a valid name")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError as exc:
        raise ValueError(f"cannot parse the value of {key}: {raw!r} ({exc})") from None
    if isinstance(value, str):  # YAML 1.1 reads 1e30 (no dot, no sign) as a string
        with contextlib.suppress(ValueError):
            value = float(value)
    return key, value


def parse_key_values(items: Iterable[str] | None, what: str = "parameter") -> dict[str, Any]:
    """``["a=1", "b=x"]`` -> ``{"a": 1, "b": "x"}`` (the last of a repeated key wins)."""
    return dict(parse_key_value(text, what) for text in items or [])


def strip_ros_args(argv: list[str]) -> list[str]:
    """Drop ``--ros-args ... [--]`` that ``ros2 run`` users may append."""
    out, skipping = [], False
    for a in argv:
        if a == "--ros-args":
            skipping = True
            continue
        if skipping:
            if a == "--":
                skipping = False
            continue
        out.append(a)
    return out


def parse_args(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """Parse ``argv`` (default: sys.argv[1:]) without ``--ros-args``."""
    return parser.parse_args(strip_ros_args(list(sys.argv[1:] if argv is None else argv)))
