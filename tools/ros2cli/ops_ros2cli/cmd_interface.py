"""``ros2 interface show|list|packages|package``: the .msg / .srv files of the installed packages.

Needs no ROS graph (and no rclpy): the definitions are read from ``share/PKG/{msg,srv}`` of the
ament prefixes (ops_bag.interfaces).
"""

from __future__ import annotations

import sys

from ops_bag import interfaces


def add_verbs(verbs):
    p = verbs.add_parser(
        "show",
        help="Output the interface definition",
        description="Output the interface definition",
    )
    p.add_argument(
        "type", help="Show an interface definition (e.g. 'example_interfaces/msg/String')"
    )
    group = p.add_mutually_exclusive_group()
    group.add_argument(
        "--all-comments",
        action="store_true",
        help="Show all comments, including for nested interface definitions",
    )
    group.add_argument("--no-comments", action="store_true", help="Show no comments or whitespace")
    p.set_defaults(_main=main_show)

    p = verbs.add_parser(
        "list",
        help="List all interface types available",
        description="List all interface types available",
    )
    p.add_argument("-m", "--only-msgs", action="store_true", help="Print out only the messages")
    p.add_argument("-s", "--only-srvs", action="store_true", help="Print out only the services")
    p.set_defaults(_main=main_list)

    p = verbs.add_parser(
        "packages",
        help="Output a list of packages that provide interfaces",
        description="Output a list of packages that provide interfaces",
    )
    p.set_defaults(_main=main_packages)

    p = verbs.add_parser(
        "package",
        help="Output a list of available interface types within one package",
        description="Output a list of available interface types within one package",
    )
    p.add_argument("package_name", help="Name of the ROS package")
    p.set_defaults(_main=main_package)


def _strip(line):
    return line.split("#", 1)[0].rstrip()


def _render(pkg, text, depth, comments):
    """Lines of a definition; nested types expanded below their field, one tab deeper."""
    out = []
    indent = "\t" * depth
    for raw in text.splitlines():
        code = _strip(raw)
        if comments:
            line = raw.rstrip()
        else:
            line = code
            if not line.strip():
                continue
        out.append(indent + line if line else line)
        if not code.strip() or code.strip() == "---":
            continue
        used = interfaces.field_types(pkg, code)
        for full in used:
            dep_pkg = full.split("/")[0]
            out += _render(dep_pkg, interfaces.definition_text(full), depth + 1, comments == "all")
    return out


def main_show(args):
    try:
        pkg, kind, name = interfaces.split_type(args.type)
        if kind == "action":
            raise RuntimeError("actions are not provided by this subset")
        text = interfaces.definition_text(f"{pkg}/{kind}/{name}", kind)
    except (ValueError, interfaces.InterfaceNotFound) as exc:
        print(exc, file=sys.stderr)
        return 1
    if args.all_comments:
        mode = "all"
    elif args.no_comments:
        mode = None
    else:
        mode = "top"
    lines = []
    for part_index, part in enumerate(text.split("\n---\n") if kind == "srv" else [text]):
        if part_index:
            lines.append("---")
        lines += _render(pkg, part, 0, mode if mode else None)
    while lines and not lines[-1].strip():
        lines.pop()
    print("\n".join(lines))
    return 0


def main_list(args):
    groups = {"msg": "Messages", "srv": "Services"}
    found = interfaces.packages_with_interfaces()
    for kind, title in groups.items():
        if (kind == "msg" and args.only_srvs) or (kind == "srv" and args.only_msgs):
            continue
        print(f"{title}:")
        for pkg in sorted(found):
            for name in found[pkg]:
                if name.startswith(kind + "/"):
                    print(f"    {pkg}/{name}")
    return 0


def main_packages(args):
    for pkg in sorted(interfaces.packages_with_interfaces()):
        print(pkg)
    return 0


def main_package(args):
    found = interfaces.packages_with_interfaces()
    if args.package_name not in found:
        print(f"Unknown package '{args.package_name}'", file=sys.stderr)
        return 1
    for name in found[args.package_name]:
        print(f"{args.package_name}/{name}")
    return 0
