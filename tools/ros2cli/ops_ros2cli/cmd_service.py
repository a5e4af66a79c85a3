"""``ros2 service call|list|type``."""

import time

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


def main_list(args):
    return graph.print_list(
        args,
        lambda node: node.get_service_names_and_types(),
        args.include_hidden_services,
        args.count_services,
        skip_own=True,
    )


def main_type(args):
    name = args.service_name if args.service_name.startswith("/") else "/" + args.service_name
    return graph.print_type(
        args, lambda node: name, lambda node: node.get_service_names_and_types()
    )


def main_call(args):
    from ops_ros2cli.msgutil import fill_from_yaml, get_service

    if args.rate is not None and args.rate <= 0:
        raise RuntimeError("rate must be greater than zero")
    period = 1.0 / args.rate if args.rate else None
    try:
        srv_class = get_service(args.service_type)
    except (AttributeError, ImportError, ValueError):
        raise RuntimeError("The passed service type is invalid") from None
    if not (hasattr(srv_class, "Request") and hasattr(srv_class, "Response")):
        raise RuntimeError("The passed type is not a service")
    request = fill_from_yaml(srv_class.Request(), args.values)

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
