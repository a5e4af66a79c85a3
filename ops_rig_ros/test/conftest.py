"""Fixtures of the rig's unit tests: simulated instruments in this process (real TCP socket,
real pseudo-terminal), stopped after each test."""

from __future__ import annotations

import pytest
from ops_rig_ros.simlab.main import Lab


@pytest.fixture
def lab():
    made = Lab(stage=3, mode="easy", seed=7, quiet=True)
    yield made
    made.close()
