"""The simulator node's parameters, in-process: integers for floats, live-ness, bounds."""

from __future__ import annotations

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.parameter import Parameter  # noqa: E402


@pytest.fixture
def make_node():
    """SimNode() on the default context, initialized with ``-p`` overrides."""
    nodes = []

    def make(*overrides: str):
        from ops_sim_ros.sim_node import SimNode

        rclpy.init(args=["sim", "--ros-args", *[a for o in overrides for a in ("-p", o)]])
        node = SimNode()
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()


def test_float_parameters_take_integers_at_start_and_at_runtime(make_node):
    node = make_node("rate_hz:=50", "samples_per_slot:=1")
    p = node.get_parameter("rate_hz")
    assert p.type_ == Parameter.Type.DOUBLE and p.value == 50.0
    assert node.set_parameters([Parameter("rate_hz", value=70)])[0].successful
    assert node.get_parameter("rate_hz").value == 70.0
    assert not node.set_parameters([Parameter("rate_hz", value="fast")])[0].successful


def test_read_only_parameters_and_bounded_noise(make_node):
    node = make_node()
    refused = node.set_parameters([Parameter("stage", value=4)])[0]
    assert not refused.successful and "stage cannot change" in refused.reason
    too_big = node.set_parameters([Parameter("jitter_sigma_cycles", value=1.0e30)])[0]
    assert not too_big.successful and "jitter_sigma_cycles" in too_big.reason


def test_unbounded_noise_at_start_is_a_parameter_error(make_node):
    from ops_contract.ros_interface import ParameterError

    with pytest.raises(ParameterError, match="jitter_sigma_cycles"):
        make_node("jitter_sigma_cycles:=1.0e+30")


@pytest.mark.parametrize(
    "param, words",
    [
        ("time_base:=minutes", ["time_base", "one of step, seconds", "minutes"]),
        ("step_s:=0.0", ["step_s", "-1 or float in [1e-05, 10.0]"]),
        ("step_s:=20.0", ["step_s", "-1 or float in [1e-05, 10.0]"]),
        ("vibration:=loud", ["vibration", "one of none, lab, open", "loud"]),
    ],
)
def test_bad_physical_time_at_start_is_a_parameter_error(make_node, param, words):
    from ops_contract.ros_interface import ParameterError

    with pytest.raises(ParameterError) as err:
        make_node(param)
    for w in words:
        assert w in str(err.value), (w, str(err.value))


def test_bad_physical_time_at_runtime_is_refused_and_the_config_kept(make_node):
    node = make_node("time_base:=seconds", "rate_hz:=500")
    config = node._config
    assert config.time_base == "seconds" and config.step_s == pytest.approx(0.002)
    for name, value, words in (
        ("time_base", "minutes", ["time_base", "one of step, seconds"]),
        ("step_s", 1e-6, ["step_s", "[1e-05, 10.0]"]),
        ("step_s", float("nan"), ["step_s"]),
        ("vibration", "loud", ["vibration", "one of none, lab, open"]),
        ("rate_hz", 20000.0, ["rate_hz", "10000.0"]),  # (rclpy says the range its own way)
    ):
        result = node.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful, (name, value)
        for w in words:
            assert w in result.reason, (w, result.reason)
    assert node._config == config
    assert node.set_parameters([Parameter("vibration", value="lab")])[0].successful
    assert node._config.vibration == "lab"


def test_rate_hz_sets_the_step_and_the_ms_figures_keep_their_seconds(make_node):
    """Under time_base seconds a step lasts 1 / rate_hz: latency_ms and actuator_lag_ms stay
    the same time at any rate; under step latency_ms counts steps at rate_hz as before."""
    node = make_node("time_base:=seconds", "rate_hz:=100", "latency_ms:=20", "actuator_lag_ms:=3")
    assert node._config.step_s == pytest.approx(0.01)
    assert node._config.latency_steps == 2
    assert node._config.actuator_lag_steps == pytest.approx(0.3)
    assert node.set_parameters([Parameter("rate_hz", value=1000.0)])[0].successful
    assert node._config.step_s == pytest.approx(0.001)
    assert node._config.latency_steps == 20
    assert node._config.actuator_lag_steps == pytest.approx(3.0)
    assert node.set_parameters([Parameter("step_s", value=0.005)])[0].successful  # given: kept
    assert node._config.step_s == 0.005 and node._config.latency_steps == 4
    assert node.set_parameters([Parameter("time_base", value="step")])[0].successful
    assert node._config.latency_steps == 20  # steps at rate_hz


def test_the_default_node_keeps_the_papers_step(make_node):
    node = make_node("rate_hz:=500")
    assert node._config.time_base == "step" and node._config.step_s == 0.1
    assert node._config.vibration == "none"


def test_the_drift_turn_is_a_parameter_in_seconds_of_the_loop(make_node):
    """drift_turn_s reaches the simulation as steps of the loop; -1 keeps the mode's one-step
    turn; a negative value other than -1 is refused and the turn kept."""
    node = make_node("mode:=hard", "time_base:=seconds", "rate_hz:=50", "drift_turn_s:=30")
    assert node._config.drift_turn_s == 30.0
    assert node._sim.noise.turn_steps == 1500  # 30 s at 50 Hz
    assert not node.set_parameters([Parameter("drift_turn_s", value=-2.0)])[0].successful
    assert node._config.drift_turn_s == 30.0
    assert node.set_parameters([Parameter("drift_turn_s", value=-1.0)])[0].successful
    assert node._config.drift_turn_s == 0.0 and node._sim.noise.turn_steps == 0
