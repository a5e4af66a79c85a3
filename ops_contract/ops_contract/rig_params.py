"""The rig's node parameters, declared once for every node that is told the rig: the preset
``realism`` and one parameter per figure of the rig (``ops_contract.config.REALISM_PRESETS``'s
keys; docs/physics.md, "Rig imperfections"), each -1 for "the preset's value" or a value in the
config's range (``LIMITS``).

The controller nodes (``ops_tracker``, ``ops_spgd``, ``ops_policy``) declare :data:`RIG_PARAMS`
and build the nominal model they control with :func:`rig_config`, as ``evaluate --realism /
--rig`` does; the values mean what the simulator node's parameters of the same names mean.
"""

from __future__ import annotations

from .config import LIMITS, REALISM_PRESETS, REALISMS, make_config
from .node_params import ParamSpec
from .ros_interface import ParameterError

#: What each figure of the rig means (docs/physics.md, "Rig imperfections").
RIG_DESCRIPTIONS = {
    "latency_steps": "a command acts this many steps after the reading it answered",
    "actuator_lag_steps": "first-order response of the delay lines, steps",
    "actuator_hysteresis": "open-loop piezo hysteresis: loop width, fraction of the travel",
    "dac_bits": "bits of the drive's DAC over the actuator range (0: ideal)",
    "trace_adc_bits": "bits of the trace's digitizer (0: ideal)",
    "trace_full_scale": "the digitizer's full scale, normalized pulse energy",
    "trace_averages": "traces averaged per reading",
    "pulse_amplitude_noise": "rms pulse-to-pulse energy noise of the source, fraction",
    "burst_envelope": "energy droop from the burst's first pulse to its last, fraction",
}
#: The figures of the rig a node is told of: the presets' keys that the config knows.
RIG_PARAM_KEYS = tuple(k for k in REALISM_PRESETS["ideal"] if k in LIMITS)


def _spec(name: str) -> ParamSpec:
    integer = isinstance(REALISM_PRESETS["ideal"][name], int)
    low, high = LIMITS[name]
    return ParamSpec(
        name,
        -1 if integer else -1.0,
        RIG_DESCRIPTIONS.get(name, name.replace("_", " ")) + " (-1: the realism preset's)",
        low=low,
        high=high,
        special=(-1,) if integer else (-1.0,),
    )


REALISM = ParamSpec(
    "realism",
    "ideal",
    "the rig's preset: ideal (an ideal stacker) or lab (a typical lab's rig)",
    choices=REALISMS,
)
RIG_PARAMS = [REALISM, *(_spec(name) for name in RIG_PARAM_KEYS)]


def rig_values(values: dict) -> dict:
    """The rig a node was told of, as ``make_config`` keywords: ``realism`` and every figure
    given (not -1)."""
    rig = {"realism": values["realism"]}
    rig.update({k: values[k] for k in RIG_PARAM_KEYS if k in values and values[k] != -1})
    return rig


def rig_config(values: dict, **model):
    """The nominal model (an OpsConfig) of ``model`` (stage, wavelength, ...) on the rig the
    parameter ``values`` tell; ParameterError names what make_config refuses."""
    try:
        return make_config(**model, **rig_values(values))
    except ValueError as exc:
        raise ParameterError(str(exc)) from None
