"""``ros2 run PKG EXE [args...]``: find an executable in the ament index and run it.

The lookup is the one of ros2run / ros2pkg: the first prefix in AMENT_PREFIX_PATH that
has ``share/ament_index/resource_index/packages/PKG`` is the package's prefix, and the
executables are the executable files under ``PREFIX/lib/PKG`` (hidden folders skipped).

This module does not import rclpy, so ``ros2 run`` starts fast.
"""

import argparse
import contextlib
import ctypes
import os
import shlex
import signal
import subprocess
import sys

PR_SET_PDEATHSIG = 1
FORWARDED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


class PackageNotFound(Exception):
    pass


def get_prefix_path(package_name):
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if not prefix:
            continue
        marker = os.path.join(
            prefix, "share", "ament_index", "resource_index", "packages", package_name
        )
        if os.path.isfile(marker):
            return prefix
    return None


def get_executable_paths(package_name):
    prefix = get_prefix_path(package_name)
    if prefix is None:
        raise PackageNotFound(package_name)
    base_path = os.path.join(prefix, "lib", package_name)
    paths = []
    for dirpath, dirnames, filenames in os.walk(base_path):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for filename in sorted(filenames):
            path = os.path.join(dirpath, filename)
            if os.access(path, os.X_OK):
                paths.append(path)
    return paths


def get_executable_path(package_name, executable_name):
    matches = [
        p for p in get_executable_paths(package_name) if os.path.basename(p) == executable_name
    ]
    if len(matches) > 1:
        raise RuntimeError("Multiple executables found:" + "".join(f"\n- {p}" for p in matches))
    return matches[0] if matches else None


def _parser():
    parser = argparse.ArgumentParser(
        prog="ros2 run", description="Run a package specific executable"
    )
    parser.add_argument(
        "--prefix",
        metavar="PREFIX",
        help="Prefix command, which should go before the executable. Command must be "
        "wrapped in quotes if it contains spaces (e.g. --prefix 'gdb -ex run --args').",
    )
    parser.add_argument("package_name", help="Name of the ROS package")
    parser.add_argument("executable_name", help="Name of the executable")
    parser.add_argument(
        "argv",
        nargs="*",
        help="Pass arbitrary arguments to the executable (use '--' before these arguments "
        "to ensure they are not handle by this command)",
    )
    return parser


def _parse(argv):
    """Split ``[options] PKG EXE [args...]``; everything after EXE goes to the executable."""
    parser = _parser()
    options = []
    positionals = []
    i = 0
    while i < len(argv) and len(positionals) < 2:
        arg = argv[i]
        if arg in ("-h", "--help"):
            parser.print_help()
            sys.exit(0)
        if arg == "--prefix":
            if i + 1 >= len(argv):
                parser.error("argument --prefix: expected one argument")
            options.append(argv[i + 1])
            i += 2
            continue
        if arg.startswith("--prefix="):
            options.append(arg.split("=", 1)[1])
        elif arg == "--":
            pass
        elif arg.startswith("-"):
            parser.error(f"unrecognized arguments: {arg}")
        else:
            positionals.append(arg)
        i += 1
    if len(positionals) < 2:
        missing = ["package_name", "executable_name"][len(positionals) :]
        parser.error("the following arguments are required: " + ", ".join(missing))
    rest = argv[i:]
    if rest[:1] == ["--"]:
        rest = rest[1:]
    prefix = shlex.split(options[-1]) if options else None
    return positionals[0], positionals[1], rest, prefix


def _foreground_tty():
    """The terminal's fd when this process is in its foreground process group, else None."""
    try:
        fd = sys.stdin.fileno()
        if os.isatty(fd) and os.tcgetpgrp(fd) == os.getpgrp():
            return fd
    except (AttributeError, OSError, ValueError):
        pass
    return None


def _child_setup(old_mask, tty_fd, parent_pid):
    """Runs in the child between fork and exec."""
    # own process group: a signal sent to the group of `ros2` reaches the child once,
    # through this process, never twice
    os.setpgid(0, 0)
    if tty_fd is not None:
        # like a shell's job control: the child gets the terminal (and Ctrl-C from it)
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTTOU})
        os.tcsetpgrp(tty_fd, os.getpgrp())
    # if `ros2` is killed (SIGKILL), the child gets SIGTERM instead of living on
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM))
    except (AttributeError, OSError):
        pass
    if os.getppid() != parent_pid:
        os.kill(os.getpid(), signal.SIGTERM)
    signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)


def run_executable(cmd):
    """Run ``cmd``; forward SIGINT/SIGTERM/SIGHUP/SIGQUIT to it; return its exit code.

    The child runs in its own process group. With a terminal, it is made the terminal's
    foreground group while it runs (as a shell does for a job), so Ctrl-C reaches it
    directly and exactly once; a signal sent to ``ros2`` itself (or to its process group)
    is forwarded to the child exactly once.
    """
    if not hasattr(signal, "sigtimedwait"):  # pragma: no cover - not Linux
        process = subprocess.Popen(cmd)
        while process.returncode is None:
            with contextlib.suppress(KeyboardInterrupt):
                process.wait()
        return process.returncode

    waited = {*FORWARDED, signal.SIGCHLD}
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, waited)
    tty_fd = _foreground_tty()
    parent_pid = os.getpid()
    try:
        try:
            process = subprocess.Popen(
                cmd, preexec_fn=lambda: _child_setup(old_mask, tty_fd, parent_pid)
            )
        except OSError as exc:
            raise RuntimeError(f"Failed to run '{cmd[0]}': {exc.strerror}") from None
        try:
            while True:
                returncode = process.poll()
                if returncode is not None:
                    return returncode
                info = signal.sigtimedwait(waited, 0.5)
                # Only the signals we wait for to forward; SIGCHLD (also when the child is
                # stopped or continued) just means "poll again".
                if info is None or info.si_signo not in FORWARDED:
                    continue
                with contextlib.suppress(ProcessLookupError):
                    process.send_signal(info.si_signo)
        finally:
            if tty_fd is not None:
                signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTTOU})
                with contextlib.suppress(OSError):
                    os.tcsetpgrp(tty_fd, os.getpgrp())
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)


def main(argv):
    package_name, executable_name, rest, prefix = _parse(argv)
    try:
        path = get_executable_path(package_name, executable_name)
    except PackageNotFound:
        print(f"Package '{package_name}' not found", file=sys.stderr)
        return 1
    except RuntimeError as exc:
        print(str(exc), file=sys.stderr)
        return 1
    if path is None:
        print("No executable found", file=sys.stderr)
        return 1
    cmd = (prefix or []) + [path] + rest
    try:
        returncode = run_executable(cmd)
    except RuntimeError as exc:
        print(str(exc), file=sys.stderr)
        return 1
    if returncode < 0:
        # killed by a signal: report it the way a shell does
        return 128 - returncode
    return returncode
