"""Controller nodes built in this process on the default context, with ``-p`` overrides (no
simulator needed): for tests of what a node builds and refuses before it spins."""

from __future__ import annotations


class NodesInProcess:
    """Starts nodes (each on a fresh ``rclpy.init``) and destroys them all in :meth:`close`."""

    def __init__(self):
        self.nodes = []

    def start(self, node_cls, *overrides: str):
        import rclpy

        rclpy.init(args=["node", "--ros-args", *[a for o in overrides for a in ("-p", o)]])
        node = node_cls()
        self.nodes.append(node)
        return node

    def close(self) -> None:
        import rclpy

        for node in self.nodes:
            node.destroy_node()
        rclpy.try_shutdown()
