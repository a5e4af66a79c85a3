"""The live view ``ros2 run ops_sim_ros foxglove``: the ``ops/`` topics over the Foxglove
WebSocket protocol (foxglove-sdk), for Foxglove or Lichtblick (``ws://HOST:PORT``).

Every topic under ``topic_prefix`` (relative: ``ops/`` in the node's namespace) that has a
publisher is subscribed as raw CDR and advertised as a channel with its ``ros2msg`` schema, so the
viewer decodes the messages itself; topics appearing later are picked up (the graph is checked
every ``discovery_period_s``). docs/foxglove/ops_layout.json shows the trace, P_N and the delays.
"""

from __future__ import annotations

import importlib
import time

from ops_contract.node_params import ParamSpec, declare_all
from ops_contract.ros_interface import NodeFatalError, ParameterError, run_node
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

PARAMS = [
    ParamSpec("port", 8765, "WebSocket port (0: any free port, logged)", low=0, high=65535),
    ParamSpec("host", "127.0.0.1", "address to listen on (0.0.0.0: every interface)"),
    ParamSpec("topic_prefix", "ops/", "serve the topics under this prefix (relative: namespaced)"),
    ParamSpec(
        "discovery_period_s",
        1.0,
        "how often the graph is checked for new topics",
        low=0.1,
        high=60.0,
    ),
]


def _subscription_qos(infos) -> QoSProfile:
    """Reliable / transient-local when every publisher offers it (latched values arrive)."""
    qos = QoSProfile(depth=10)
    reliable = infos and all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
    latched = infos and all(
        i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos
    )
    qos.reliability = ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT
    qos.durability = DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE
    return qos


class FoxgloveNode(Node):
    def __init__(self):
        super().__init__("ops_foxglove")
        import foxglove

        v = declare_all(self, PARAMS)
        prefix = v["topic_prefix"].strip()
        if not prefix:
            raise ParameterError("topic_prefix must not be empty (e.g. ops/)")
        self._prefix = self.resolve_topic_name(prefix.rstrip("/")).rstrip("/") + "/"
        self._foxglove = foxglove
        try:
            self._server = foxglove.start_server(
                name="ops_foxglove", host=v["host"], port=v["port"]
            )
        except Exception as exc:  # the SDK raises its own error types for bind failures
            raise NodeFatalError(
                f"cannot serve on {v['host']}:{v['port']} ({exc}); choose another port with "
                "-p port:=N"
            ) from None
        self._channels: dict[str, object] = {}
        self._topic_subscriptions = []
        self.get_logger().info(
            f"Foxglove WebSocket server on ws://{v['host']}:{self._server.port} serving "
            f"{self._prefix}*"
        )
        self.create_timer(v["discovery_period_s"], self._discover)
        self._discover()

    def _discover(self):
        from ops_bag import interfaces

        for name, types in self.get_topic_names_and_types():
            if name in self._channels or not name.startswith(self._prefix) or len(types) != 1:
                continue
            infos = self.get_publishers_info_by_topic(name)
            if not infos:
                continue
            try:
                pkg, _, short = interfaces.split_type(types[0])
                msg_class = getattr(importlib.import_module(f"{pkg}.msg"), short)
                schema_text = interfaces.message_definition(types[0])
            except (ImportError, AttributeError, ValueError, LookupError) as exc:
                self.get_logger().warning(f"not serving {name}: {exc}")
                self._channels[name] = None
                continue
            channel = self._foxglove.Channel(
                name,
                message_encoding="cdr",
                schema=self._foxglove.Schema(
                    name=f"{pkg}/msg/{short}", encoding="ros2msg", data=schema_text.encode()
                ),
            )
            self._channels[name] = channel
            self._topic_subscriptions.append(
                self.create_subscription(
                    msg_class,
                    name,
                    lambda data, ch=channel: ch.log(data, log_time=time.time_ns()),
                    _subscription_qos(infos),
                    raw=True,
                )
            )
            self.get_logger().info(f"serving {name} [{types[0]}]")

    def destroy_node(self):
        server = getattr(self, "_server", None)
        if server is not None:
            server.stop()
            self._server = None
        return super().destroy_node()


def main(args=None):
    raise SystemExit(run_node(FoxgloveNode, args))


if __name__ == "__main__":
    main()
