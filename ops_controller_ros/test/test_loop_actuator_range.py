"""Without a rig file every controller node keeps its set-points inside the simulator's actuator
range (the nominal model's): a free-running simulator clips a set-point beyond it, and the loop
would wait for ever for a command the simulator never takes (seen over DDS: a policy whose blind
stage walked to +30 cycles stalled after 45 s)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")


@pytest.fixture
def make_node():
    from nodes_in_process import NodesInProcess

    nodes = NodesInProcess()

    def make(module: str, cls: str, *overrides: str):
        import importlib

        node_cls = getattr(importlib.import_module(f"ops_controller_ros.{module}"), cls)
        return nodes.start(node_cls, *overrides)

    yield make
    nodes.close()


def _start(node, stage: int = 5, samples: int = 8):
    node._delays = np.zeros(stage, dtype=np.float32)
    node._trace = (np.zeros((2**stage - 1) * samples, dtype=np.float32), samples)
    node._start()
    assert node.ctrl is not None


def test_spgd_is_kept_inside_the_actuator_range(make_node):
    node = make_node("spgd_node", "SpgdNode")
    _start(node)
    model = node.nominal_model(stage=5)
    reach, period = model.actuator_range_fs, model.optical_period_fs
    keeper = node._range
    assert keeper is not None and np.allclose(keeper.high_fs, reach)
    near = np.array([reach - 0.5 * period, 0.0, -reach + 0.2 * period, 0.0, 1.5 * reach])
    out = node._in_range(near)
    assert np.all(np.abs(out) <= reach + 1e-9)  # nothing beyond the range goes out
    moved = out[:3] - near[:3]
    assert abs(moved[0]) >= period and abs(moved[2]) >= period and moved[1] == 0.0
    k = moved[[0, 2]] / period
    assert np.allclose(k, np.round(k))  # whole periods: the same interference
    assert keeper.moves >= 2


def test_the_tracker_keeps_its_own_range_and_the_node_only_clips(make_node):
    """The tracker moves its own set-points off a limit (tracker/period.py); the node keeps
    the range too, by clipping."""
    node = make_node("tracker_node", "TrackerNode")
    _start(node)
    assert node._range is not None and node.keeps_own_range
    reach = node.nominal_model(stage=5).actuator_range_fs
    assert np.all(np.abs(node._in_range(np.full(5, 2 * reach))) <= reach + 1e-9)
