"""The tracker node's progress line, as readers match it."""

from __future__ import annotations

import re
from types import SimpleNamespace

from ops_controller_ros.tracker_node import TrackerNode

#: How the integration test (and a user's grep) finds a locked reading in the node's log.
LOCKED_LINE = r"reading \d+ \(locked;[^)\n]*\): P_N/P_max = 0\.9"


def test_the_knot_counts_keep_the_progress_line_to_one_pair_of_parentheses():
    """Seen in CI: with a knot taken, the counts' own parentheses ended the "(locked; ...)"
    part early and the node's locked readings no longer matched."""
    ctrl = SimpleNamespace(knots=3, knot_tests_spread=2, knot_tests_cut=1)
    note = TrackerNode._knot_note(SimpleNamespace(ctrl=ctrl))
    assert note == ", since start: knots 3, knot tests spread 2 / cut 1"
    line = f"reading 74 (locked; model 1030.4 nm, 1000 fs{note}): P_N/P_max = 0.9961"
    assert re.search(LOCKED_LINE, line)
    quiet = SimpleNamespace(knots=0, knot_tests_spread=0, knot_tests_cut=0)
    assert TrackerNode._knot_note(SimpleNamespace(ctrl=quiet)) == ""


def test_the_detector_note_keeps_the_progress_line_to_one_pair_of_parentheses():
    """A detector taken as noisy said so in parentheses of its own, which ended the
    "(locked; ...)" part early, as the knot counts did."""
    ctrl = SimpleNamespace(measured_noise=0.0003, fit_noise=0.001, noisy=True)
    note = TrackerNode._detector_note(SimpleNamespace(ctrl=ctrl))
    assert note == ", noise 0.0003, fits 0.0010, noisy"
    line = f"reading 74 (locked; model 1030.4 nm, 1000 fs{note}): P_N/P_max = 0.9961"
    assert re.search(LOCKED_LINE, line)
    early = SimpleNamespace(measured_noise=None, fit_noise=None, noisy=False)
    assert TrackerNode._detector_note(SimpleNamespace(ctrl=early)) == ""
    clean = SimpleNamespace(measured_noise=0.0002, fit_noise=None, noisy=False)
    assert TrackerNode._detector_note(SimpleNamespace(ctrl=clean)) == ", noise 0.0002"
