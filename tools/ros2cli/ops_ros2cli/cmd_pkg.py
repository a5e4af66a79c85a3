"""``ros2 pkg list|executables|prefix``: packages of the ament index (AMENT_PREFIX_PATH)."""

from __future__ import annotations

import os
import sys

from ops_ros2cli import run


def add_verbs(verbs):
    p = verbs.add_parser(
        "list",
        help="Output a list of available packages",
        description="Output a list of available packages",
    )
    p.set_defaults(_main=main_list)

    p = verbs.add_parser(
        "executables",
        help="Output a list of package specific executables",
        description="Output a list of package specific executables",
    )
    p.add_argument("package_name", nargs="?", help="Name of the ROS package")
    p.add_argument("--full-path", action="store_true", help="Show the full path of each executable")
    p.set_defaults(_main=main_executables)

    p = verbs.add_parser(
        "prefix",
        help="Output the prefix path of a package",
        description="Output the prefix path of a package",
    )
    p.add_argument("package_name", help="The package name")
    p.add_argument("--share", action="store_true", help="Show share directory for the package")
    p.set_defaults(_main=main_prefix)


def package_names():
    names = set()
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        index = os.path.join(prefix, "share", "ament_index", "resource_index", "packages")
        if prefix and os.path.isdir(index):
            names.update(n for n in os.listdir(index) if not n.startswith("."))
    return sorted(names)


def main_list(args):
    for name in package_names():
        print(name)
    return 0


def main_executables(args):
    names = [args.package_name] if args.package_name else package_names()
    for name in names:
        try:
            paths = run.get_executable_paths(name)
        except run.PackageNotFound:
            print(f"Package '{name}' not found", file=sys.stderr)
            return 1
        for path in sorted(paths, key=os.path.basename):
            print(path if args.full_path else f"{name} {os.path.basename(path)}")
    return 0


def main_prefix(args):
    prefix = run.get_prefix_path(args.package_name)
    if prefix is None:
        print("Package not found", file=sys.stderr)
        return 1
    print(os.path.join(prefix, "share", args.package_name) if args.share else prefix)
    return 0
