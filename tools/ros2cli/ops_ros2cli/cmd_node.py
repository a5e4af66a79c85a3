"""``ros2 node list``."""

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
