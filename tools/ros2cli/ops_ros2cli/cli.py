# PYTHON_ARGCOMPLETE_OK
"""``ros2`` entry point: argument parsing, dispatch and signal handling."""

import argparse
import contextlib
import os
import signal
import sys

PROGRAM = "ros2"

# The commands this subset provides, with the real tool's one-line descriptions.
COMMANDS = {
    "bag": "Various rosbag related sub-commands",
    "interface": "Show information about ROS interfaces",
    "node": "Various node related sub-commands",
    "param": "Various param related sub-commands",
    "pkg": "Various package related sub-commands",
    "run": "Run a package specific executable",
    "service": "Various service related sub-commands",
    "topic": "Various topic related sub-commands",
}

# Commands of a full ROS 2 Jazzy install that this subset does not provide.
MISSING_COMMANDS = (
    "action",
    "component",
    "control",
    "daemon",
    "doctor",
    "extension_points",
    "extensions",
    "launch",
    "lifecycle",
    "multicast",
    "security",
    "wtf",
)

# Verbs of the provided commands that only the full ros2cli has.
MISSING_VERBS = {
    "bag": ("convert", "list", "reindex"),
    "interface": ("proto",),
    "param": ("delete", "describe"),
    "pkg": ("create", "xml"),
    "service": ("echo", "find", "info"),
    "topic": ("bw", "delay", "find"),
}

PROVIDED_SUMMARY = (
    "run, topic (list, echo, hz, pub, type, info), node (list, info), service (call, list, "
    "type), param (list, get, set, dump, load), bag (record, info, play), interface (show, "
    "list, packages, package), pkg (list, executables, prefix)"
)

EPILOG = (
    "This is the ros2 command line of this project (ops_ros2cli): a subset of ros2cli\n"
    "for machines where ROS 2 Jazzy comes from the PyPI wheels, which ship no ros2cli.\n"
    "It provides " + PROVIDED_SUMMARY + ",\n"
    "with the syntax and output of the real tool. Other commands (launch, bag, ...) need\n"
    "a full ROS 2 installation (e.g. ROS 2 Jazzy in /opt/ros/jazzy)."
)


class Interrupted(BaseException):
    """Raised in the main thread by SIGINT / SIGTERM."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


def _raise_interrupted(signum, frame):
    # one clean shutdown: ignore further signals while cleaning up
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise Interrupted(signum)


def exit_code_for_signal(signum):
    # Like the real ros2cli, Ctrl-C (SIGINT) ends a command with exit code 2
    # (it returns signal.SIGINT); SIGTERM gives 143 (128 + 15), what a shell reports for
    # a process terminated by SIGTERM.
    if signum == signal.SIGINT:
        return int(signal.SIGINT)
    return 128 + int(signum)


def not_provided(what):
    print(
        f"{PROGRAM}: '{PROGRAM} {what}' is not provided by this ros2 command line: it is the "
        "small ros2cli subset of this project (ops_ros2cli) for installs from the ROS 2 "
        f"Jazzy wheels, which ship no ros2cli. It provides {PROVIDED_SUMMARY}. "
        f"A full ROS 2 installation (e.g. ROS 2 Jazzy in /opt/ros/jazzy) provides '{PROGRAM} "
        f"{what}'.",
        file=sys.stderr,
    )
    return 1


def _first_positional(argv):
    for index, arg in enumerate(argv):
        if arg == "--":
            return None
        if not arg.startswith("-"):
            return index
    return None


def _build_parser():
    from ops_ros2cli import (
        cmd_bag,
        cmd_interface,
        cmd_node,
        cmd_param,
        cmd_pkg,
        cmd_service,
        cmd_topic,
    )

    parser = argparse.ArgumentParser(
        prog=PROGRAM,
        description=f"{PROGRAM} is an extensible command-line tool for ROS 2.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--use-python-default-buffering",
        action="store_true",
        default=False,
        help="Do not force line buffering in stdout and instead use the python default "
        "buffering, which might be affected by PYTHONUNBUFFERED/-u and depends on "
        "whatever stdout is interactive or not",
    )
    subparsers = parser.add_subparsers(
        title="Commands",
        dest="_command",
        metavar=f"Call `{PROGRAM} <command> -h` for more detailed usage.",
    )
    # 'run' is parsed by ops_ros2cli.run itself; this entry is for the help text only
    run_parser = subparsers.add_parser("run", help=COMMANDS["run"])
    _add_run_completion(run_parser)
    for name, module in (
        ("bag", cmd_bag),
        ("interface", cmd_interface),
        ("node", cmd_node),
        ("param", cmd_param),
        ("pkg", cmd_pkg),
        ("service", cmd_service),
        ("topic", cmd_topic),
    ):
        sub = subparsers.add_parser(
            name,
            help=COMMANDS[name],
            description=COMMANDS[name],
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        verbs = sub.add_subparsers(
            title="Commands",
            dest="_verb",
            metavar=f"Call `{PROGRAM} {name} <command> -h` for more detailed usage.",
        )
        module.add_verbs(verbs)
        sub.set_defaults(_command_parser=sub)
    return parser


def _add_run_completion(parser):
    """Positionals of ``run`` for tab completion only (ops_ros2cli.run parses the real call)."""

    def packages(**kwargs):
        from ops_ros2cli.cmd_pkg import package_names

        return package_names()

    def executables(parsed_args, **kwargs):
        from ops_ros2cli import run

        try:
            return [os.path.basename(p) for p in run.get_executable_paths(parsed_args.package)]
        except run.PackageNotFound:
            return []

    parser.add_argument("package", nargs="?").completer = packages
    parser.add_argument("executable", nargs="?").completer = executables


def _autocomplete():
    """Tab completion (argcomplete): answers and exits when the shell asks, else returns."""
    if "_ARGCOMPLETE" not in os.environ:
        return
    try:
        import argcomplete
    except ImportError:
        return
    argcomplete.autocomplete(_build_parser())


def main(argv=None):
    if argv is None:
        _autocomplete()
        argv = sys.argv[1:]
    argv = list(argv)

    index = _first_positional(argv)
    command = argv[index] if index is not None else None
    if command == "run":
        from ops_ros2cli import run

        return run.main(argv[index + 1 :])
    if command in MISSING_COMMANDS:
        return not_provided(command)
    if command in MISSING_VERBS:
        rest = argv[index + 1 :]
        verb_index = _first_positional(rest)
        if verb_index is not None and rest[verb_index] in MISSING_VERBS[command]:
            return not_provided(f"{command} {rest[verb_index]}")

    parser = _build_parser()
    args = parser.parse_args(argv)
    if not args.use_python_default_buffering:
        with contextlib.suppress(AttributeError):
            sys.stdout.reconfigure(line_buffering=True)

    if args._command is None:
        parser.print_help()
        return 0
    if getattr(args, "_verb", None) is None:
        args._command_parser.print_help()
        return 0

    signal.signal(signal.SIGINT, _raise_interrupted)
    signal.signal(signal.SIGTERM, _raise_interrupted)
    try:
        return args._main(args)
    except Interrupted as exc:
        return exit_code_for_signal(exc.signum)
    except (RuntimeError, ValueError) as exc:
        print(str(exc), file=sys.stderr)
        return 1
    except BrokenPipeError:
        # e.g. `ros2 topic echo /x | head -n 3`: stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
