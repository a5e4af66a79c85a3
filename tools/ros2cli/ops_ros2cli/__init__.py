"""A small ``ros2`` command line for ROS 2 Jazzy installs without ros2cli.

It provides ``ros2 run``, ``ros2 topic list|echo|hz|pub|type``, ``ros2 node list``,
``ros2 service call|list|type`` and ``ros2 param list|get|set`` with the syntax and the
output of the real ros2cli of ROS 2 Jazzy. See README.md next to this package.
"""

__version__ = "0.1.0"
