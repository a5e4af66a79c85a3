"""``ros2 service call|list|type``."""

import time

import yaml

from ops_ros2cli import graph


def add_verbs(verbs):
    p = verbs.add_parser("call", help="Call a service", description="Call a service")
    p.add_argument("service_name", help="Name of the ROS service to call to (e.g. '/add_two_ints')")
    p.add_argument("service_type", help="Type of the ROS service (e.g. 'std_srvs/srv/Empty')")
    p.add_argument(
        "values",
        nargs="?",
        default="{}",
        help="Values to fill the service request with in YAML format "
        "(e.g. '{a: 1, b: 2}'), otherwise the service request will be "
        "published with default values",
    )
    p.add_argument(
        "-r", "--rate", metavar="N", type=float, help="Repeat the call at a specific rate in Hz"
    )
    p.set_defaults(_main=main_call)

    p = verbs.add_parser(
        "list",
        help="Output a list of available services",
        description="Output a list of available services",
    )
    graph.add_spin_time_argument(p)
    p.add_argument(
        "-t", "--show-types", action="store_true", help="Additionally show the service type"
    )
    p.add_argument(
        "-c",
        "--count-services",
        action="store_true",
        help="Only display the number of services discovered",
    )
    p.add_argument(
        "--include-hidden-services", action="store_true", help="Consider hidden services as well"
    )
    p.set_defaults(_main=main_list)

    p = verbs.add_parser(
        "type", help="Output a service's type", description="Output a service's type"
    )
    graph.add_spin_time_argument(p)
    p.add_argument("service_name", help="Name of the ROS service to get type (e.g. '/talker')")
    p.set_defaults(_main=main_type)


def _service_names_and_types(node, include_hidden):
    own = node.get_fully_qualified_name() + "/"
    result = []
    for name, types in sorted(node.get_service_names_and_types()):
        if name.startswith(own):
            continue
        if not include_hidden and graph.is_hidden_name(name):
            continue
        result.append((name, types))
    return result


def main_list(args):
    with graph.CliNode(args) as cli:
        cli.settle_graph(graph.list_spin_time(args))
        services = _service_names_and_types(cli.node, args.include_hidden_services)
    if args.count_services:
        print(len(services))
        return 0
    for name, types in services:
        if args.show_types:
            print(f"{name} [{', '.join(types)}]")
        else:
            print(name)
    return 0


def main_type(args):
    with graph.CliNode(args) as cli:
        name = args.service_name if args.service_name.startswith("/") else "/" + args.service_name
        found = cli.wait_for(
            lambda: dict(cli.node.get_service_names_and_types()).get(name),
            graph.discovery_timeout(args),
        )
    if not found:
        return 1
    for t in found:
        print(t)
    return 0


def main_call(args):
    from ops_ros2cli.msgutil import get_service, set_message_fields

    if args.rate is not None and args.rate <= 0:
        raise RuntimeError("rate must be greater than zero")
    period = 1.0 / args.rate if args.rate else None
    try:
        srv_class = get_service(args.service_type)
    except (AttributeError, ImportError, ValueError):
        raise RuntimeError("The passed service type is invalid") from None
    if not (hasattr(srv_class, "Request") and hasattr(srv_class, "Response")):
        raise RuntimeError("The passed type is not a service")
    try:
        values = yaml.safe_load(args.values)
    except yaml.YAMLError as exc:
        detail = " ".join(str(exc).split())
        raise RuntimeError(f"The passed value is not valid YAML: {detail}") from None
    if values is None:
        values = {}
    if not isinstance(values, dict):
        raise RuntimeError("The passed value needs to be a dictionary in YAML format")
    request = srv_class.Request()
    try:
        set_message_fields(request, values)
    except Exception as exc:
        raise RuntimeError(f"Failed to populate field: {exc}") from None

    package = args.service_type.split("/")[0]
    srv_name = args.service_type.split("/")[-1]
    node_name = f"{graph.NODE_NAME_PREFIX}_requester_{package}_{srv_name}"
    with graph.CliNode(args, node_name=node_name) as cli:
        client = cli.node.create_client(srv_class, args.service_name)
        if not client.service_is_ready():
            print("waiting for service to become available...")
            cli.wait_for(client.service_is_ready, None)
        while True:
            print(f"requester: making request: {request!r}\n")
            last_call = time.monotonic()
            future = client.call_async(request)
            cli.spin_until_future_complete(future)
            if future.result() is None:
                raise RuntimeError(f"Exception while calling service: {future.exception()!r}")
            print(f"response:\n{future.result()!r}\n")
            if period is None:
                break
            wait = last_call + period - time.monotonic()
            if wait > 0:
                cli.spin_for(wait)
    return 0
