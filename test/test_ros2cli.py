"""The `ros2` command line as a user runs it: real processes over real DDS, no mocks.

Runs whichever `ros2` is on PATH (the project's subset from tools/ros2cli after
`source setup.bash`, or a real ros2cli where ROS 2 is installed): the expected outputs are
the real tool's. Shared processes (a demo node started with `ros2 run`, a `ros2 topic pub`)
are module-scoped; conftest.py gives the module its own ROS_DOMAIN_ID.
"""

from __future__ import annotations

import os
import re
import signal
import time

import pytest
from ops_bench.processes import ProcessGroup, assert_no_traceback, ros2_command, run_ros2
from ros2cli_helpers import DEMO_PKG, env_with_prefix, make_ament_prefix, pid_alive

# These tests are about the project's subset; where a real ROS 2 provides `ros2`, set-up does not
# install the subset and there is nothing of ours to test.
pytest.importorskip("ops_ros2cli", reason="a real ros2 is in use; the subset is not installed")

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]


@pytest.fixture(scope="module")
def env(ros_domain, tmp_path_factory):
    """Environment of every command: this module's domain, demo_pkg first on the prefix path."""
    return env_with_prefix(make_ament_prefix(tmp_path_factory.mktemp("prefix")))


@pytest.fixture(scope="module")
def shared(env, tmp_path_factory):
    """The demo node (via `ros2 run`) and `ros2 topic pub -r 10 /chatter ...`, for the module."""
    group = ProcessGroup(tmp_path_factory.mktemp("shared"))
    cmd = ros2_command()
    node = group.start([*cmd, "run", DEMO_PKG, "demo_node"], name="demo_node", env=env)
    pub = group.start(
        [*cmd, "topic", "pub", "-r", "10", "/chatter", "std_msgs/msg/String", "{data: hi}"],
        name="pub",
        env=env,
    )
    node.wait_for(r"ready")
    pub.wait_for(r"publishing #1: std_msgs\.msg\.String\(data='hi'\)")
    yield {"node": node, "pub": pub}
    group.stop_all()


@pytest.fixture
def procs(tmp_path):
    group = ProcessGroup(tmp_path)
    yield group
    group.stop_all()


# --- help and unsupported commands --------------------------------------------------------


def test_help(env):
    top = run_ros2("--help", env=env)
    assert top.returncode == 0, top.stderr
    assert top.stdout.startswith("usage: ros2")
    for command in ("run", "topic", "node", "service", "param"):
        assert re.search(rf"^\s+{command}\s", top.stdout, re.M), top.stdout
    echo = run_ros2("topic", "echo", "--help", env=env)
    assert echo.returncode == 0, echo.stderr
    for option in ("--once", "--field", "--timeout", "--qos-reliability"):
        assert option in echo.stdout
    run_help = run_ros2("run", "--help", env=env)
    assert run_help.returncode == 0 and "package_name" in run_help.stdout


def test_unsupported_commands_say_so(env):
    for args in (("launch", "demo_pkg", "x.launch.py"), ("action", "list"), ("topic", "bw")):
        result = run_ros2(*args, env=env)
        assert result.returncode != 0, args
        assert "is not provided by this ros2 command line" in result.stderr
        assert "full ROS 2 installation" in result.stderr
        assert_no_traceback(result.stderr)


# --- ros2 run -----------------------------------------------------------------------------


def test_run_unknown_package(env):
    result = run_ros2("run", "no_such_pkg", "talker", env=env)
    assert result.returncode == 1
    assert result.stderr == "Package 'no_such_pkg' not found\n"


def test_run_unknown_or_not_executable(env):
    for exe in ("no_such_exe", "not_executable"):
        result = run_ros2("run", DEMO_PKG, exe, env=env)
        assert result.returncode == 1
        assert result.stderr == "No executable found\n"


def test_run_passes_arguments_and_exit_code(env):
    result = run_ros2("run", DEMO_PKG, "exit_with", "7", "--ros-args", "-p", "a:=1", env=env)
    assert result.returncode == 7
    assert result.stdout == "['7', '--ros-args', '-p', 'a:=1']\n"
    assert run_ros2("run", DEMO_PKG, "exit_with", "0", env=env).returncode == 0


def _child_pid(proc) -> int:
    return int(proc.wait_for(r"ready pid=(\d+)").group(1))


def test_run_ctrl_c_stops_the_child_once(env, procs):
    # Ctrl-C: SIGINT to the whole process group, as a terminal does
    proc = procs.start([*ros2_command(), "run", DEMO_PKG, "sleeper"], name="sleeper", env=env)
    child = _child_pid(proc)
    proc.signal(signal.SIGINT)
    assert proc.wait_exit(20) == 0
    assert "child got SIGINT x1 SIGTERM x0" in proc.output
    assert_no_traceback(proc.output)
    assert not pid_alive(child)


def test_run_forwards_sigterm_and_returns_child_code(env, procs):
    proc = procs.start([*ros2_command(), "run", DEMO_PKG, "sleeper"], name="sleeper", env=env)
    child = _child_pid(proc)
    os.kill(proc.popen.pid, signal.SIGTERM)  # to `ros2` only
    assert proc.wait_exit(20) == 5
    assert "child got SIGINT x0 SIGTERM x1" in proc.output
    assert_no_traceback(proc.output)
    assert not pid_alive(child)


def test_run_survives_stop_and_continue_then_forwards_ctrl_c(env, procs):
    """SIGSTOP / SIGCONT (a shell's Ctrl-Z and fg, or a debugger) to `ros2` or to its child are
    not forwarded and do not break the wrapper; a later Ctrl-C still reaches the child once."""
    proc = procs.start([*ros2_command(), "run", DEMO_PKG, "sleeper"], name="sleeper", env=env)
    child = _child_pid(proc)
    for pid in (child, proc.popen.pid):
        os.kill(pid, signal.SIGSTOP)
        os.kill(pid, signal.SIGCONT)
    assert proc.popen.poll() is None and pid_alive(child)
    proc.signal(signal.SIGINT)
    assert proc.wait_exit(20) == 0
    assert "child got SIGINT x1 SIGTERM x0" in proc.output
    assert_no_traceback(proc.output)
    assert not pid_alive(child)


def run_until(*args, env, condition, timeout=30.0):
    """Run `ros2 ARGS` again until ``condition(result)``: a fresh process discovers the DDS
    graph asynchronously (the real ros2cli relies on its daemon for that)."""
    deadline = time.monotonic() + timeout
    while True:
        result = run_ros2(*args, env=env)
        if condition(result) or time.monotonic() > deadline:
            return result


def test_run_real_node_appears_in_node_list(env, shared):
    result = run_until(
        "node", "list", env=env, condition=lambda r: "/demo_node" in r.stdout.splitlines()
    )
    assert result.returncode == 0, result.stderr
    nodes = result.stdout.splitlines()
    assert "/demo_node" in nodes
    assert not [n for n in nodes if "/_" in n], nodes  # hidden nodes (this tool's) not listed


# --- topics -------------------------------------------------------------------------------


def without_discovery_warning(stdout: str, topic: str) -> str:
    """The output less the real tool's warning, printed (as ros2cli does, on stdout) when the
    graph has not shown the topic within 3 s: on a loaded machine DDS discovery may take that."""
    warning = f"WARNING: topic [{topic}] does not appear to be published yet\n"
    return stdout.removeprefix(warning)


def test_pub_then_echo_once(env, shared):
    result = run_ros2("topic", "echo", "/chatter", "--once", env=env)
    assert result.returncode == 0, result.stderr
    assert without_discovery_warning(result.stdout, "/chatter") == "data: hi\n---\n"


def test_echo_field_and_explicit_type(env, shared):
    result = run_ros2(
        "topic", "echo", "/chatter", "std_msgs/msg/String", "--once", "--field", "data", env=env
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout == "hi\n---\n"


def test_topic_list(env, shared):
    plain = run_until(
        "topic", "list", env=env, condition=lambda r: "/demo_chatter" in r.stdout.splitlines()
    )
    assert plain.returncode == 0, plain.stderr
    assert {"/chatter", "/demo_chatter", "/rosout", "/parameter_events"} <= set(
        plain.stdout.splitlines()
    )
    typed = run_until("topic", "list", "-t", env=env, condition=lambda r: "/chatter [" in r.stdout)
    assert "/chatter [std_msgs/msg/String]" in typed.stdout.splitlines()
    assert "/demo_chatter [std_msgs/msg/String]" in typed.stdout.splitlines()


def test_echo_unknown_topic_times_out_with_message(env):
    start = time.monotonic()
    result = run_ros2("topic", "echo", "/no_such_topic", "--timeout", "2", env=env)
    assert result.returncode == 1
    assert "WARNING: topic [/no_such_topic] does not appear to be published yet" in result.stdout
    assert "Could not determine the type for the passed topic" in result.stderr
    assert_no_traceback(result.stderr)
    assert time.monotonic() - start < 20


def test_pub_malformed_yaml(env):
    result = run_ros2("topic", "pub", "--once", "/x", "std_msgs/msg/String", "{data: [hi", env=env)
    assert result.returncode != 0
    assert "The passed value is not valid YAML" in result.stderr
    assert_no_traceback(result.stderr)
    result = run_ros2("topic", "pub", "--once", "/x", "std_msgs/msg/String", "{nope: 1}", env=env)
    assert result.returncode != 0
    assert "Failed to populate field" in result.stderr
    assert_no_traceback(result.stderr)


def test_echo_ctrl_c_is_clean(env, shared, procs):
    proc = procs.start([*ros2_command(), "topic", "echo", "/demo_chatter"], name="echo", env=env)
    proc.wait_for(r"data: hello \d+\n---\n", count=2)
    proc.signal(signal.SIGINT)
    # the real ros2cli exits with code 2 (signal.SIGINT) on Ctrl-C
    assert proc.wait_exit(20) == 2
    assert_no_traceback(proc.output)


def test_hz(env, shared, procs):
    proc = procs.start([*ros2_command(), "topic", "hz", "/demo_chatter"], name="hz", env=env)
    match = proc.wait_for(
        r"average rate: (\d+\.\d{3})\n\tmin: \d+\.\d{3}s max: \d+\.\d{3}s "
        r"std dev: \d+\.\d{5}s window: \d+\n"
    )
    assert 5.0 < float(match.group(1)) < 15.0, proc.output
    proc.signal(signal.SIGINT)
    assert proc.wait_exit(20) == 2
    assert_no_traceback(proc.output)


# --- services and parameters ----------------------------------------------------------------


def test_service_call(env, shared):
    result = run_ros2("service", "call", "/demo_trigger", "std_srvs/srv/Trigger", env=env)
    assert result.returncode == 0, result.stderr
    assert "requester: making request: std_srvs.srv.Trigger_Request()\n" in result.stdout
    assert (
        "response:\nstd_srvs.srv.Trigger_Response(success=True, message='triggered')\n"
        in result.stdout
    )


def test_param_list_get_set(env, shared):
    listed = run_ros2("param", "list", "/demo_node", env=env)
    assert listed.returncode == 0, listed.stderr
    assert "  gain" in listed.stdout.splitlines()
    assert "  use_sim_time" in listed.stdout.splitlines()
    got = run_ros2("param", "get", "/demo_node", "gain", env=env)
    assert got.stdout == "Integer value is: 3\n", got.stderr
    changed = run_ros2("param", "set", "/demo_node", "gain", "5", env=env)
    assert changed.stdout == "Set parameter successful\n", changed.stderr
    got = run_ros2("param", "get", "/demo_node", "gain", env=env)
    assert got.stdout == "Integer value is: 5\n", got.stderr
    missing = run_ros2("param", "get", "/no_such_node", "gain", "--spin-time", "1", env=env)
    assert missing.returncode == 1
    assert missing.stderr.strip() == "Node not found"
