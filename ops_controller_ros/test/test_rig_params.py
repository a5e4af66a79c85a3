"""The rig a controller node is told of and the tracker's parameters, declared once: pure
checks, no node."""

from __future__ import annotations

from dataclasses import fields

import pytest
from ops_contract.config import make_config
from ops_contract.node_params import check_value
from ops_contract.rig_params import RIG_PARAM_KEYS, RIG_PARAMS, rig_config, rig_values
from ops_contract.ros_interface import ParameterError
from ops_controller_ros.controllers import make_controller
from ops_controller_ros.spgd_node import PARAMS as SPGD_PARAMS
from ops_controller_ros.tracker import NODE_FIELDS, PhaseTracker, TrackerParams, node_defaults
from ops_controller_ros.tracker_node import PARAMS as TRACKER_PARAMS

UNSET = {spec.name: spec.default for spec in RIG_PARAMS}  # the node's defaults: -1, ideal


def test_the_rig_parameters_make_the_nominal_model_as_evaluate_does():
    assert rig_config(UNSET, stage=5) == make_config(stage=5)  # the defaults: the ideal stacker
    told = {**UNSET, "realism": "lab", "latency_steps": 2}
    assert rig_values(told) == {"realism": "lab", "latency_steps": 2}
    model = rig_config(told, stage=5, samples_per_slot=8)
    assert model == make_config(stage=5, samples_per_slot=8, realism="lab", latency_steps=2)
    assert model.latency_steps == 2 and model.trace_adc_bits == 8  # given, and the preset's
    assert make_controller("tracker", model).latency == 2
    assert make_controller("spgd", model).latency == 2


def test_bad_rig_values_are_named_with_their_range():
    specs = {spec.name: spec for spec in RIG_PARAMS}
    assert "latency_steps" in specs and set(RIG_PARAM_KEYS) <= set(specs)
    cases = {
        "latency_steps": (-2, "latency_steps must be -1 or int in [0, 1000] (got -2)"),
        "trace_adc_bits": (33, "trace_adc_bits must be -1 or int in [0, 32]"),
        "dac_bits": (40, "dac_bits must be -1 or int in [0, 32]"),
        "actuator_hysteresis": (1.0, "actuator_hysteresis must be -1 or float in [0.0, 0.99]"),
        "realism": ("perfect", "realism must be one of ideal, lab"),
    }
    for name, (value, message) in cases.items():
        assert message in check_value(specs[name], value)
        assert check_value(specs[name], specs[name].default) is None  # -1: the preset's value
    with pytest.raises(ParameterError, match="realism must be one of"):
        rig_config({**UNSET, "realism": "perfect"}, stage=5)


def test_every_controller_node_declares_the_rig_once():
    from ops_controller_ros.loop_node import LOOP_PARAMS

    loop = {spec.name for spec in LOOP_PARAMS}
    assert {"realism", *RIG_PARAM_KEYS, "rig_config"} <= loop  # the rig file: every node's
    for params in (TRACKER_PARAMS, SPGD_PARAMS):
        assert not loop & {spec.name for spec in params}  # not declared a second time


def test_the_node_and_evaluate_run_one_default_set():
    """The tracker node's parameters are generated from TrackerParams: the same names as before,
    the same defaults; only the real-time cap on the knot test (ms) is the node's own."""
    names = {spec.name for spec in TRACKER_PARAMS}
    before = {"window", "noisy_window", "hold_dither_cycles", "hold_pattern", "detector_noise"}
    before |= {"hop_every", "defer_knot_test", "knot_budget_ms", "step_budget_ms"}
    assert before | {"wavelength_nm", "pulse_fwhm_fs", "detector"} <= names
    assert set(NODE_FIELDS) <= names
    node = node_defaults()
    default = TrackerParams()
    differ = {k for k in NODE_FIELDS if node[k] != getattr(default, k)}
    assert differ == {"knot_budget_ms"} and default.knot_budget_ms == 0.0  # in process: no cap
    assert node["step_budget_ms"] == default.step_budget_ms == 0.0
    for spec in TRACKER_PARAMS:
        if spec.name in NODE_FIELDS:
            assert spec.default == node[spec.name]
            assert check_value(spec, node[spec.name]) is None
    built = make_controller("tracker", make_config(stage=3))
    assert isinstance(built, PhaseTracker) and built.params == default
    assert len(fields(TrackerParams)) > len(NODE_FIELDS)


def test_a_declared_range_is_checked_by_tracker_params():
    with pytest.raises(ValueError, match=r"hold_dither_cycles must be in \[0, 0.25\]"):
        TrackerParams(hold_dither_cycles=0.3)
    with pytest.raises(ValueError, match="hold_pattern must be one or all"):
        TrackerParams(hold_pattern="some")
    with pytest.raises(ValueError, match=r"recover_readings must be in \[2, window\]"):
        TrackerParams(window=3, recover_readings=4)


def test_the_policy_node_counts_a_randomized_figure_as_trained_on():
    """A model trained on rigs drawn per episode (train --rig-randomize) is not warned about a
    told figure inside the drawn range; outside it, or for a figure not drawn, it is."""
    from types import SimpleNamespace

    from ops_controller_ros.policy_node import PolicyNode

    def warnings_for(told: dict, ranges: dict | None) -> list[str]:
        said: list[str] = []
        node = SimpleNamespace(
            nominal_model=lambda stage: make_config(stage=stage, **told),
            get_logger=lambda: SimpleNamespace(warning=said.append),
        )
        trained = make_config(stage=3, realism="lab").to_dict()
        meta = SimpleNamespace(config=trained, stage=3, entries={"rig_randomize": ranges})
        PolicyNode._check_rig(node, SimpleNamespace(meta=meta))
        return said

    ranges = {"latency_steps": [0, 2], "trace_adc_bits": [6, 12]}
    assert warnings_for({"realism": "lab"}, ranges) == []
    assert warnings_for({"realism": "lab", "latency_steps": 2}, ranges) == []
    assert (
        "latency_steps=2 (trained: 1)"
        in warnings_for({"realism": "lab", "latency_steps": 2}, None)[0]
    )
    said = warnings_for({"realism": "lab", "latency_steps": 3, "dac_bits": 12}, ranges)
    assert "latency_steps=3 (trained: 1)" in said[0] and "dac_bits=12 (trained: 16)" in said[0]
