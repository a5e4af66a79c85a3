"""Helpers of test_ros2cli.py: the `ros2` command under test and a throw-away ament prefix.

The prefix holds a package ``demo_pkg`` with executables in ``lib/demo_pkg``, found by
``ros2 run`` through AMENT_PREFIX_PATH exactly like the packages colcon installs.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DEMO_PKG = "demo_pkg"

# An rclpy node: publishes std_msgs/String on demo_chatter at 10 Hz, serves std_srvs/Trigger
# on demo_trigger, declares the parameter gain (3).
DEMO_NODE = """
import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from std_msgs.msg import String
from std_srvs.srv import Trigger


def main():
    rclpy.init(args=sys.argv)
    node = rclpy.create_node("demo_node")
    node.declare_parameter("gain", 3)
    pub = node.create_publisher(String, "demo_chatter", 10)
    count = [0]

    def tick():
        count[0] += 1
        pub.publish(String(data=f"hello {count[0]}"))

    def trigger(request, response):
        response.success = True
        response.message = "triggered"
        return response

    node.create_timer(0.1, tick)
    node.create_service(Trigger, "demo_trigger", trigger)
    print("ready", flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


main()
"""

# Prints its arguments (one line of repr) and exits with the code given as first argument.
EXIT_WITH = """
import sys

print(repr(sys.argv[1:]), flush=True)
sys.exit(int(sys.argv[1]))
"""

# Waits for signals: counts SIGINTs (exit 0 after a short grace that would catch a duplicate),
# exits 5 on SIGTERM. Prints its pid first.
SLEEPER = """
import os
import signal
import sys
import time

received = []


def on_signal(signum, frame):
    received.append(signum)


signal.signal(signal.SIGINT, on_signal)
signal.signal(signal.SIGTERM, on_signal)
print(f"ready pid={os.getpid()}", flush=True)
while not received:
    time.sleep(0.02)
time.sleep(0.5)  # a second (duplicate) signal would arrive by now
ints = received.count(signal.SIGINT)
terms = received.count(signal.SIGTERM)
print(f"child got SIGINT x{ints} SIGTERM x{terms}", flush=True)
sys.exit(5 if terms else 0)
"""


def make_ament_prefix(root: Path) -> Path:
    """Create ``root`` as an ament prefix with demo_pkg and its executables."""
    marker = root / "share" / "ament_index" / "resource_index" / "packages" / DEMO_PKG
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.write_text("")
    lib = root / "lib" / DEMO_PKG
    lib.mkdir(parents=True, exist_ok=True)
    for name, body in (("demo_node", DEMO_NODE), ("exit_with", EXIT_WITH), ("sleeper", SLEEPER)):
        path = lib / name
        path.write_text(f"#!{sys.executable}\n{body}")
        path.chmod(0o755)
    # not executable: must not be found
    (lib / "not_executable").write_text("#!/bin/sh\nexit 0\n")
    return root


def env_with_prefix(prefix: Path) -> dict[str, str]:
    env = dict(os.environ)
    paths = [str(prefix)] + [p for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(paths)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is dead for our purpose
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False
