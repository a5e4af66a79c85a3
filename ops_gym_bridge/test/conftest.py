"""Fixtures of the bridge and training tests: a ROS_DOMAIN_ID per test module, real processes
started as a user would (``ros2 run ...``; the installed executables where no ``ros2`` exists yet)
and stopped in teardown. Reuses test/ros_testing.py of the integration tests."""

from __future__ import annotations

import itertools
import os
import shutil
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "test"))

from ros_testing import ProcessGroup  # noqa: E402

_domains = itertools.count()


def executable(package: str, name: str) -> list[str]:
    """Command line of ``ros2 run package name``."""
    ros2 = shutil.which("ros2")
    if ros2:
        return [ros2, "run", package, name]
    exe = REPO / "install" / package / "lib" / package / name
    if not exe.exists():
        pytest.fail(f"{exe} missing: build the workspace (make setup) and source setup.bash")
    return [str(exe)]


@pytest.fixture(scope="module", autouse=True)
def ros_domain():
    """A ROS_DOMAIN_ID of this module's own (101..200: apart from test/'s 1..100)."""
    saved = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
    domain = 101 + (os.getpid() * 7 + 13 * next(_domains)) % 100
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    yield domain
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


@pytest.fixture
def procs(tmp_path):
    group = ProcessGroup(tmp_path)
    yield group
    group.stop_all()


@pytest.fixture(scope="module")
def module_procs(tmp_path_factory):
    group = ProcessGroup(tmp_path_factory.mktemp("procs"))
    yield group
    group.stop_all()


def start_sim(
    group: ProcessGroup,
    stage: int = 3,
    mode: str = "easy",
    namespace: str = "",
    lockstep: bool = True,
    seed: int = 1,
    name: str = "sim",
):
    args = [
        *executable("ops_sim_ros", "sim"),
        "--ros-args",
        "-p",
        f"stage:={stage}",
        "-p",
        f"mode:={mode}",
        "-p",
        f"lockstep:={'true' if lockstep else 'false'}",
        "-p",
        f"seed:={seed}",
    ]
    if namespace:
        args += ["-r", f"__ns:={namespace}"]
    proc = group.start(args, name=name)
    proc.wait_for(rf"stage={stage} mode={mode}", timeout=30)
    return proc
