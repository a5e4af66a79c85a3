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
    add_dump_load_verbs(verbs)


def add_dump_load_verbs(verbs):
    p = verbs.add_parser(
        "dump",
        help="Show all of the parameters of a node in a YAML file format",
        description="Show all of the parameters of a node in a YAML file format",
    )
    graph.add_spin_time_argument(p)
    p.add_argument("node_name", help="Name of the ROS node")
    p.add_argument(
        "--include-hidden-nodes", action="store_true", help="Consider hidden nodes as well"
    )
    p.set_defaults(_main=main_dump)

    p = verbs.add_parser(
        "load",
        help="Load parameter file for a node",
        description="Load parameter file for a node",
    )
    graph.add_spin_time_argument(p)
    p.add_argument("node_name", help="Name of the ROS node")
    p.add_argument("parameter_file", help="Parameter file")
    p.add_argument(
        "--no-use-wildcard",
        action="store_true",
        help="Do not load parameters in the '/**' namespace into the node",
    )
    p.add_argument(
        "--include-hidden-nodes", action="store_true", help="Consider hidden nodes as well"
    )
    p.set_defaults(_main=main_load)


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


# dump / load ---------------------------------------------------------------------------------


def _python_value(pvalue):
    from rcl_interfaces.msg import ParameterType

    kinds = {
        ParameterType.PARAMETER_BOOL: lambda v: bool(v.bool_value),
        ParameterType.PARAMETER_INTEGER: lambda v: int(v.integer_value),
        ParameterType.PARAMETER_DOUBLE: lambda v: float(v.double_value),
        ParameterType.PARAMETER_STRING: lambda v: str(v.string_value),
        ParameterType.PARAMETER_BYTE_ARRAY: lambda v: [bytes(b)[0] for b in v.byte_array_value],
        ParameterType.PARAMETER_BOOL_ARRAY: lambda v: [bool(b) for b in v.bool_array_value],
        ParameterType.PARAMETER_INTEGER_ARRAY: lambda v: [int(b) for b in v.integer_array_value],
        ParameterType.PARAMETER_DOUBLE_ARRAY: lambda v: [float(b) for b in v.double_array_value],
        ParameterType.PARAMETER_STRING_ARRAY: lambda v: [str(b) for b in v.string_array_value],
    }
    fn = kinds.get(pvalue.type)
    return None if fn is None else fn(pvalue)


def main_dump(args):
    import yaml
    from rcl_interfaces.srv import GetParameters, ListParameters

    node_name = graph.absolute_node_name(args.node_name)
    with graph.CliNode(args) as cli:
        if not _wait_for_node(cli, node_name, args):
            return "Node not found"
        listed = _call(cli, ListParameters, node_name, "list_parameters", ListParameters.Request())
        names = sorted(listed.result.names)
        request = GetParameters.Request()
        request.names = names
        got = _call(cli, GetParameters, node_name, "get_parameters", request)
    params = {}
    for name, pvalue in zip(names, got.values, strict=False):
        value = _python_value(pvalue)
        if value is None:
            continue
        # dotted names nest, as in the real tool
        target = params
        parts = name.split(".")
        for part in parts[:-1]:
            target = target.setdefault(part, {})
        target[parts[-1]] = value
    print(yaml.dump({node_name: {"ros__parameters": params}}, default_flow_style=False), end="")
    return 0


def _flatten(prefix, value, out):
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
    else:
        out[prefix] = value


def _to_parameter_value(value):
    from rcl_interfaces.msg import ParameterType, ParameterValue

    pv = ParameterValue()
    if isinstance(value, bool):
        pv.type, pv.bool_value = ParameterType.PARAMETER_BOOL, value
    elif isinstance(value, int):
        pv.type, pv.integer_value = ParameterType.PARAMETER_INTEGER, value
    elif isinstance(value, float):
        pv.type, pv.double_value = ParameterType.PARAMETER_DOUBLE, value
    elif isinstance(value, str):
        pv.type, pv.string_value = ParameterType.PARAMETER_STRING, value
    elif isinstance(value, list) and value and all(isinstance(v, bool) for v in value):
        pv.type, pv.bool_array_value = ParameterType.PARAMETER_BOOL_ARRAY, value
    elif isinstance(value, list) and value and all(isinstance(v, int) for v in value):
        pv.type, pv.integer_array_value = ParameterType.PARAMETER_INTEGER_ARRAY, value
    elif isinstance(value, list) and value and all(isinstance(v, (int, float)) for v in value):
        pv.type = ParameterType.PARAMETER_DOUBLE_ARRAY
        pv.double_array_value = [float(v) for v in value]
    elif isinstance(value, list) and all(isinstance(v, str) for v in value):
        pv.type, pv.string_array_value = ParameterType.PARAMETER_STRING_ARRAY, value
    else:
        raise RuntimeError(f"Unsupported parameter value {value!r}")
    return pv


def main_load(args):
    import yaml
    from rcl_interfaces.msg import Parameter
    from rcl_interfaces.srv import SetParameters

    node_name = graph.absolute_node_name(args.node_name)
    try:
        with open(args.parameter_file) as f:
            document = yaml.safe_load(f)
    except OSError as exc:
        raise RuntimeError(f"cannot read '{args.parameter_file}': {exc.strerror}") from None
    except yaml.YAMLError as exc:
        detail = " ".join(str(exc).split())
        raise RuntimeError(f"'{args.parameter_file}' is not valid YAML: {detail}") from None
    if not isinstance(document, dict):
        raise RuntimeError(f"'{args.parameter_file}' is not a parameter file (no node entries)")
    values = {}
    keys = ([] if args.no_use_wildcard else ["/**"]) + [node_name, node_name.lstrip("/")]
    matched = False
    for key in keys:
        entry = document.get(key)
        if isinstance(entry, dict) and isinstance(entry.get("ros__parameters"), dict):
            matched = True
            _flatten("", entry["ros__parameters"], values)
    if not matched:
        raise RuntimeError(f"Param file does not contain parameters for {node_name}")
    with graph.CliNode(args) as cli:
        if not _wait_for_node(cli, node_name, args):
            return "Node not found"
        request = SetParameters.Request()
        request.parameters = [
            Parameter(name=name, value=_to_parameter_value(value)) for name, value in values.items()
        ]
        response = _call(cli, SetParameters, node_name, "set_parameters", request)
    for name, result in zip(values, response.results, strict=False):
        if result.successful:
            msg = f"Set parameter {name} successful"
            if result.reason:
                msg += ": " + result.reason
            print(msg)
        else:
            msg = f"Set parameter {name} failed"
            if result.reason:
                msg += ": " + result.reason
            print(msg, file=sys.stderr)
    return 0
