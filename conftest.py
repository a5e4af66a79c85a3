"""Fixtures of every test folder (packages' test/ and the integration tests in test/).

Isolation: each test module gets its own ROS_DOMAIN_ID, and DDS discovery is kept on localhost.
Under pytest-xdist (``make test`` runs one worker more than cores) each worker draws from a
slice of the domains of its own, so two workers never share one; within a slice the modules take
turns, offset by the pid so that two test runs on one machine rarely meet.

``procs`` starts commands the way a user would (``ros2 run``) and stops every one of them (SIGINT,
then SIGKILL) when the test ends; see ops_bench.processes (tools/ops_bench).

Threads: the test process's own numpy work (the closed loops of the tracker and simulator tests)
runs on one BLAS thread, as every node and CLI does (ops_contract.threads.limit_blas_threads;
the processes a test starts limit themselves). ``make test`` already keeps every core busy; a
BLAS thread pool per worker on top of that waits for a core that another process holds (60
readings of a tracker in a global search on the loaded 2-core machine: 56 s wall, 7 s on one).
torch, when the test process imports it, runs on one thread likewise, as the policy node does
(test_shipped_models alone: 85 s with torch's thread per core, 18 s on one).
"""

from __future__ import annotations

import itertools
import os

import pytest
from ops_bench.processes import ProcessGroup
from ops_contract.heap import freeze_after_heavy_imports
from ops_contract.import_hooks import after_import
from ops_contract.threads import limit_blas_threads, limit_torch_threads

limit_blas_threads()  # (not the environment: what the tests start keeps its own choice)

_domains = itertools.count()
#: Domains 1..100 (0, the default, is left to whatever else runs on the machine), cut into one
#: slice per xdist worker (PYTEST_XDIST_WORKER "gw3", PYTEST_XDIST_WORKER_COUNT).
DOMAINS = 100


def _domain_for_next_module() -> int:
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
    size = DOMAINS // max(workers, 1)
    return 1 + worker * size + (os.getpid() * 7 + 13 * next(_domains)) % size


@pytest.fixture(scope="module", autouse=True)
def ros_domain():
    """A ROS_DOMAIN_ID of this module's own, also seen by everything it starts."""
    domain = _domain_for_next_module()
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ROS_DOMAIN_ID", str(domain))
        mp.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        yield domain


# torch, when this process imports it, on one thread (as the policy node runs it), unless the
# user set a thread count.
after_import("torch", lambda _torch: limit_torch_threads())
# ... and its heap, with stable-baselines3's, out of the collector's walks (ops_contract.heap).
freeze_after_heavy_imports()


@pytest.fixture(scope="session", autouse=True)
def sb3_logdir(tmp_path_factory):
    """stable-baselines3 gives a model without a logger one in ``SB3_LOGDIR``, else a new
    /tmp/SB3-<date> folder per model: the tests' go to a folder of the test run's own."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3_logs")))
        yield


@pytest.fixture
def procs(tmp_path):
    group = ProcessGroup(tmp_path)
    yield group
    group.stop_all()


@pytest.fixture(scope="module")
def module_procs(tmp_path_factory):
    """Processes shared by the tests of one module, stopped when the module ends."""
    group = ProcessGroup(tmp_path_factory.mktemp("procs"))
    yield group
    group.stop_all()


@pytest.fixture
def observer():
    from ops_bench.observer import TopicObserver

    obs = TopicObserver()
    yield obs
    obs.close()


#: The longest modules, longest first: each module's time in the suite (pytest-xdist, two workers,
#: --dist loadfile), measured 2026-11-29 on the idle 2-core machine (`bash scripts/test.sh
#: --junitxml=FILE` in a fresh clone; "~": estimated for modules changed since).
#: Handed out longest first, the workers finish together (longest-processing-time order: a
#: simulation of the scheduler on the measured times gave 1,338 s against 1,438 s for xdist's own
#: order, by the number of tests in a module, which scripts/test.sh turns off with
#: --no-loadscope-reorder). A module not listed comes after them.
LONGEST_MODULES = (
    "test_tracker.py",  # 113 s (idle fresh-clone run, --junitxml)
    "test_policy_runner.py",  # 96
    "test_sim_nodes.py",  # 93
    "test_benchmark_cli.py",  # 83
    "test_ray_cluster.py",  # 76
    "test_lossy_link.py",  # 69
    "test_train_cli.py",  # 63
    "test_bag.py",  # 61
    "test_tracker_weights.py",  # ~50
    "test_benchmark_ray.py",  # 44
    "test_train_ros.py",  # 42
    "test_tracker_noisy.py",  # 41
    "test_ros2cli.py",  # 37
    "test_rig_node.py",  # 36
    "test_executors_over_dds.py",  # 33
    "test_bridge_env.py",  # 33
    "test_tracker_node.py",  # 32
    "test_demo.py",  # 31
    "test_recipes.py",  # ~25
    "test_two_hosts.py",  # 24
    "test_hostile.py",  # 20
    "test_realtime_over_dds.py",  # ~20
    "test_rig_calibration.py",  # 19
    "test_latency_check.py",  # 15
    "test_tracker_first_lock.py",  # 15
    "test_calibration.py",  # 14
    "test_shipped_models.py",  # 13
    "test_setpoint_range.py",  # 12
    "test_time_base.py",  # 11
)
_RANK = {name: rank for rank, name in enumerate(LONGEST_MODULES)}


def pytest_collection_modifyitems(config, items):
    """The long modules first, longest first (:data:`LONGEST_MODULES`), then the other modules
    that start processes over DDS, then the rest: pytest-xdist hands modules to its workers in
    this order, so the short ones fill in at the end and the workers finish together. Within a
    module the order stays as written."""

    def rank(item) -> int:
        if item.path.name in _RANK:
            return _RANK[item.path.name]
        integration = item.get_closest_marker("integration") is not None
        return len(LONGEST_MODULES) + (0 if integration else 1)

    items.sort(key=rank)
