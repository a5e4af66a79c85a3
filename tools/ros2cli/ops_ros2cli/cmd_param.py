"""``ros2 param list|get|set`` over the node's rcl_interfaces parameter services."""

import re
import sys

from ops_ros2cli import graph

SERVICE_TIMEOUT = 5.0

_TYPE_NAMES = {
    1: "boolean",
    2: "integer",
    3: "double",
    4: "string",
    5: "byte array",
    6: "boolean array",
    7: "integer array",
    8: "double array",
    9: "string array",
    0: "not set",
}


def add_verbs(verbs):
    p = verbs.add_parser(
        "list",
        help="Output a list of available parameters",
        description="Output a list of available parameters",
    )
    graph.add_spin_time_argument(p)
    p.add_argument("node_name", nargs="?", help="Name of the ROS node")
    p.add_argument(
        "--filter",
        nargs=1,
        help="Only parameters matching the regex expression will be showed. "
        "Supports `re` regex syntax.",
    )
    p.add_argument(
        "--include-hidden-nodes", action="store_true", help="Consider hidden nodes as well"
    )
    p.add_argument(
        "--param-prefixes",
        nargs="+",
        default=[],
        help="Only list parameters with the provided prefixes",
    )
    p.add_argument(
        "--param-type", action="store_true", help="Print parameter types with parameter names"
    )
    p.set_defaults(_main=main_list)

    p = verbs.add_parser("get", help="Get parameter", description="Get parameter")
    graph.add_spin_time_argument(p)
    p.add_argument("node_name", help="Name of the ROS node")
    p.add_argument(
        "--include-hidden-nodes", action="store_true", help="Consider hidden nodes as well"
    )
    p.add_argument("parameter_name", help="Name of the parameter")
    p.add_argument("--hide-type", action="store_true", help="Hide the type information")
    p.set_defaults(_main=main_get)

    p = verbs.add_parser("set", help="Set parameter", description="Set parameter")
    graph.add_spin_time_argument(p)
    p.add_argument("node_name", help="Name of the ROS node")
    p.add_argument(
        "--include-hidden-nodes", action="store_true", help="Consider hidden nodes as well"
    )
    p.add_argument("parameter_name", help="Name of the parameter")
    p.add_argument("value", help="Value of the parameter")
    p.set_defaults(_main=main_set)


def _wait_for_node(cli, node_name, args):
    """Wait (up to the discovery timeout) for the node; True when it is in the graph."""
    include_hidden = args.include_hidden_nodes
    return bool(
        cli.wait_for(
            lambda: node_name in graph.get_node_names(cli.node, include_hidden),
            graph.discovery_timeout(args),
        )
    )


def _call(cli, srv_class, node_name, service, request):
    client = cli.node.create_client(srv_class, f"{node_name}/{service}")
    if not cli.wait_for(client.service_is_ready, SERVICE_TIMEOUT):
        raise RuntimeError("Wait for service timed out")
    future = client.call_async(request)
    cli.spin_until_future_complete(future)
    response = future.result()
    if response is None:
        raise RuntimeError(
            f"Exception while calling service of node '{node_name}': {future.exception()}"
        )
    return response


def main_list(args):
    from rcl_interfaces.srv import DescribeParameters, ListParameters

    regex = re.compile(args.filter[0]) if args.filter else None
    node_name = graph.absolute_node_name(args.node_name)
    with graph.CliNode(args) as cli:
        if node_name:
            if not _wait_for_node(cli, node_name, args):
                return "Node not found"
            node_names = [node_name]
        else:
            cli.settle_graph(graph.list_spin_time(args))
            node_names = sorted(set(graph.get_node_names(cli.node, args.include_hidden_nodes)))
        for name in node_names:
            try:
                request = ListParameters.Request()
                request.prefixes = list(args.param_prefixes)
                response = _call(cli, ListParameters, name, "list_parameters", request)
            except RuntimeError as exc:
                print(f"Exception while calling service of node '{name}': {exc}", file=sys.stderr)
                continue
            names = sorted(response.result.names)
            if regex is not None:
                names = [n for n in names if regex.match(n)]
            if not args.node_name and names:
                print(f"{name}:")
            types = {}
            if args.param_type and names:
                request = DescribeParameters.Request()
                request.names = names
                described = _call(cli, DescribeParameters, name, "describe_parameters", request)
                types = {
                    d.name: _TYPE_NAMES.get(d.type, str(d.type)) for d in described.descriptors
                }
            for n in names:
                if args.param_type:
                    print(f"  {n} (type: {types.get(n)})")
                else:
                    print(f"  {n}")
    return 0


def main_get(args):
    from rcl_interfaces.msg import ParameterType
    from rcl_interfaces.srv import GetParameters

    node_name = graph.absolute_node_name(args.node_name)
    with graph.CliNode(args) as cli:
        if not _wait_for_node(cli, node_name, args):
            return "Node not found"
        request = GetParameters.Request()
        request.names = [args.parameter_name]
        response = _call(cli, GetParameters, node_name, "get_parameters", request)
    if not response.values:
        return "Parameter not set"
    pvalue = response.values[0]
    labels = {
        ParameterType.PARAMETER_BOOL: ("Boolean value is:", pvalue.bool_value),
        ParameterType.PARAMETER_INTEGER: ("Integer value is:", pvalue.integer_value),
        ParameterType.PARAMETER_DOUBLE: ("Double value is:", pvalue.double_value),
        ParameterType.PARAMETER_STRING: ("String value is:", pvalue.string_value),
        ParameterType.PARAMETER_BYTE_ARRAY: ("Byte values are:", pvalue.byte_array_value),
        ParameterType.PARAMETER_BOOL_ARRAY: ("Boolean values are:", pvalue.bool_array_value),
        ParameterType.PARAMETER_INTEGER_ARRAY: ("Integer values are:", pvalue.integer_array_value),
        ParameterType.PARAMETER_DOUBLE_ARRAY: ("Double values are:", pvalue.double_array_value),
        ParameterType.PARAMETER_STRING_ARRAY: ("String values are:", pvalue.string_array_value),
        ParameterType.PARAMETER_NOT_SET: ("Parameter not set.", None),
    }
    if pvalue.type not in labels:
        return f"Unknown parameter type '{pvalue.type}'"
    label, value = labels[pvalue.type]
    if not args.hide_type:
        if value is not None:
            print(label, value)
        else:
            print(label)
    else:
        print(value)
    return 0


def _parameter_value(string_value):
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rclpy.parameter import get_parameter_value

    try:
        return get_parameter_value(string_value)
    except Exception:
        value = ParameterValue()
        value.type = ParameterType.PARAMETER_STRING
        value.string_value = string_value
        return value


def main_set(args):
    from rcl_interfaces.msg import Parameter
    from rcl_interfaces.srv import SetParameters

    node_name = graph.absolute_node_name(args.node_name)
    with graph.CliNode(args) as cli:
        if not _wait_for_node(cli, node_name, args):
            return "Node not found"
        parameter = Parameter()
        parameter.name = args.parameter_name
        parameter.value = _parameter_value(args.value)
        request = SetParameters.Request()
        request.parameters = [parameter]
        response = _call(cli, SetParameters, node_name, "set_parameters", request)
    result = response.results[0]
    if result.successful:
        msg = "Set parameter successful"
        if result.reason:
            msg += ": " + result.reason
        print(msg)
        return 0
    msg = "Setting parameter failed"
    if result.reason:
        msg += ": " + result.reason
    print(msg, file=sys.stderr)
    return 0
