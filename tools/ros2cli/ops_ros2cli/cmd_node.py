"""``ros2 node list|info``."""

import sys

from ops_ros2cli import graph


def add_verbs(verbs):
    p = verbs.add_parser(
        "list",
        help="Output a list of available nodes",
        description="Output a list of available nodes",
    )
    graph.add_spin_time_argument(p)
    p.add_argument("-a", "--all", action="store_true", help="Display all nodes even hidden ones")
    p.add_argument(
        "-c",
        "--count-nodes",
        action="store_true",
        help="Only display the number of nodes discovered",
    )
    p.set_defaults(_main=main_list)

    p = verbs.add_parser(
        "info",
        help="Output information about a node",
        description="Output information about a node",
    )
    graph.add_spin_time_argument(p)
    p.add_argument("node_name", help="Node name to request information")
    p.add_argument(
        "--include-hidden", action="store_true", help="Display hidden topics, services, and actions"
    )
    p.set_defaults(_main=main_info)


def main_list(args):
    with graph.CliNode(args) as cli:
        cli.settle_graph(graph.list_spin_time(args))
        names = graph.get_node_names(cli.node, include_hidden_nodes=args.all)
    if len(names) != len(set(names)):
        print(
            "WARNING: Be aware that there are nodes in the graph that share an exact name, "
            "which can have unintended side effects.",
            file=sys.stderr,
        )
    if args.count_nodes:
        print(len(names))
    elif names:
        print(*sorted(names), sep="\n")
    return 0


def main_info(args):
    node_name = graph.absolute_node_name(args.node_name)
    with graph.CliNode(args) as cli:
        found = cli.wait_for(
            lambda: node_name in graph.get_node_names(cli.node, True),
            graph.discovery_timeout(args),
        )
        if not found:
            print(f"Unable to find node '{args.node_name}'", file=sys.stderr)
            return 1
        namespace, _, name = node_name.rpartition("/")
        namespace = namespace or "/"
        # the node's endpoints arrive with or just after the node itself
        cli.spin_for(0.5)
        node = cli.node
        sections = (
            ("Subscribers", node.get_subscriber_names_and_types_by_node(name, namespace)),
            ("Publishers", node.get_publisher_names_and_types_by_node(name, namespace)),
            ("Service Servers", node.get_service_names_and_types_by_node(name, namespace)),
            ("Service Clients", node.get_client_names_and_types_by_node(name, namespace)),
        )
    print(node_name)
    for title, entries in sections:
        print(f"  {title}:")
        for topic, types in sorted(entries):
            if not args.include_hidden and graph.is_hidden_name(topic):
                continue
            print(f"    {topic}: {', '.join(types)}")
    print("  Action Servers:\n\n  Action Clients:\n")
    return 0
