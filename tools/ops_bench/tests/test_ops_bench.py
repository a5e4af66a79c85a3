"""ops_bench (tools/ops_bench): the ``ops-bench`` command's table, every subcommand's options,
and the helpers the integration tests import from it."""

from __future__ import annotations

import ast
import importlib
import pkgutil
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import ops_bench
from ops_bench import cli

PACKAGE = Path(ops_bench.__file__).resolve().parent
NAMES = [n for n in cli.TOOLS if n != "figures"]
FIGURES = list(cli.FIGURES)


def test_repo_is_the_checkout_the_package_lives_in():
    assert (ops_bench.REPO / "setup.bash").is_file()
    assert (ops_bench.REPO / "docs" / "benchmarks.md").is_file()


def test_every_module_has_a_subcommand_or_is_a_helper():
    modules = {m.name for m in pkgutil.iter_modules([str(PACKAGE)])}
    tools = {t.module for t in [*cli.TOOLS.values(), *cli.FIGURES.values()] if t.module}
    helpers = {"cli", "__main__", "docs", "hosts", "observer", "processes", "ray_cluster"}
    helpers |= {"rate_sweep_report", "soak_report"}  # their figures and pages
    assert tools <= modules
    assert modules - tools == helpers


@pytest.mark.parametrize("name", NAMES)
def test_subcommand_help(name, capsys):
    with pytest.raises(SystemExit) as done:
        cli.main([name, "--help"])
    assert done.value.code == 0
    assert f"usage: ops-bench {name}" in capsys.readouterr().out


@pytest.mark.parametrize("kind", FIGURES)
def test_figures_help(kind, capsys):
    with pytest.raises(SystemExit) as done:
        cli.main(["figures", kind, "--help"])
    assert done.value.code == 0
    assert f"usage: ops-bench figures {kind}" in capsys.readouterr().out


def test_help_lists_every_subcommand_with_a_line():
    exe = shutil.which("ops-bench")
    assert exe, "no ops-bench on PATH: scripts/setup.sh installs tools/ops_bench"
    done = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    listed = {line.split()[0] for line in done.stdout.split("subcommands:")[1].splitlines() if line}
    assert set(NAMES) | set(FIGURES) | {"all"} <= listed
    assert all(tool.summary for tool in [*cli.TOOLS.values(), *cli.FIGURES.values()])


def test_python_m_ops_bench_is_the_same_command():
    done = subprocess.run(
        [sys.executable, "-m", "ops_bench", "--help"], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0 and "ops-bench" in done.stdout, done.stderr


def test_bad_names_are_refused(capsys):
    with pytest.raises(SystemExit) as done:
        cli.main(["no-such-tool"])
    assert done.value.code == 2
    assert cli.main(["figures", "no-such-kind"]) == 2
    assert cli.main(["all", "no-such-tool"]) == 2
    assert cli.main([]) == 2


def test_all_runs_the_benchmarks_of_docs_benchmarks_md_in_order():
    assert list(cli.ALL) == ["physics", "closed-loop", "bridge"]
    assert set(cli.ALL) <= set(cli.TOOLS)


def test_a_tool_sees_its_own_command_line(monkeypatch):
    seen = {}

    def fake_main(argv):
        seen["argv"], seen["sys.argv"] = argv, list(sys.argv)
        return 3

    monkeypatch.setattr(importlib.import_module("ops_bench.first_run"), "main", fake_main)
    assert cli.main(["first-run", "--seeds", "1"]) == 3
    assert seen == {
        "argv": ["--seeds", "1"],
        "sys.argv": ["ops-bench first-run", "--seeds", "1"],
    }


def test_helpers_of_the_tests_import_from_the_package():
    from ops_bench.hosts import (  # noqa: F401
        NetnsUnavailable,
        RelayedHosts,
        TwoHosts,
        make_two_hosts,
        netns_unavailable_reason,
    )
    from ops_bench.observer import TopicObserver  # noqa: F401
    from ops_bench.processes import (  # noqa: F401
        PYTHON,
        REPO,
        Process,
        ProcessGroup,
        assert_no_traceback,
        executable,
        ros2_command,
        run_ros2,
        sim_command,
        start_sim,
    )
    from ops_bench.ray_cluster import RayCluster  # noqa: F401
    from ops_bench.reference_actions import model_env  # noqa: F401
    from ops_bench.relay import main  # noqa: F401


def test_process_group_starts_waits_and_stops(tmp_path):
    from ops_bench.processes import ProcessGroup

    group = ProcessGroup(tmp_path)
    quick = group.start([sys.executable, "-c", "print('ready', flush=True)"], name="quick")
    slow = group.start([sys.executable, "-c", "import time; time.sleep(60)"], name="slow")
    quick.wait_for("ready", timeout=30)
    assert quick.wait_exit(30) == 0
    group.stop_all()
    assert slow.popen.returncode is not None
    assert (tmp_path / "00_quick.log").read_text().strip() == "ready"


def test_write_section_replaces_its_own_section_only(tmp_path):
    from ops_bench.docs import write_section

    doc = tmp_path / "bench.md"
    doc.write_text("# Benchmarks\n\n## A\n\nold a\n\n## B\n\nb stays\n")
    write_section("## A", "## A\n\nnew a", doc)
    write_section("## C", "## C\n\nc", doc)
    assert doc.read_text() == "# Benchmarks\n\n## A\n\nnew a\n\n## B\n\nb stays\n\n## C\n\nc\n"


def test_write_section_keeps_a_hand_written_sub_section(tmp_path):
    from ops_bench.docs import write_section

    doc = tmp_path / "bench.md"
    doc.write_text("## A\n\nold a\n\n### By hand\n\nkept\n\n## B\n\nb\n")
    write_section("## A", "## A\n\nnew a", doc)
    assert doc.read_text() == "## A\n\nnew a\n\n### By hand\n\nkept\n\n## B\n\nb\n"


def test_sizes_and_no_path_hacks():
    """No function over 80 lines, no module over 600; nothing put on sys.path by hand."""
    for path in PACKAGE.glob("*.py"):
        text = path.read_text()
        assert len(text.splitlines()) <= 600, path.name
        assert "sys.path" not in text, path.name
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                assert node.end_lineno - node.lineno < 80, f"{path.name}: {node.name}"


def test_first_run_starts_spgd_as_the_readme_does_and_the_tracker_with_its_seed():
    from ops_bench.first_run import controller_command

    assert controller_command("spgd", 3) == ["ros2", "run", "ops_controller_ros", "spgd"]
    tracker = controller_command("tracker", 3)
    assert tracker[:4] == ["ros2", "run", "ops_controller_ros", "tracker"]
    assert tracker[-2:] == ["-p", "seed:=3"]


def test_first_run_writes_its_controllers_section_and_counts_the_goal(monkeypatch):
    import numpy as np

    from ops_bench.first_run import SECTIONS, parse_args, section

    args = parse_args(["--controller", "tracker", "--stage", "5", "--echo", "none"])
    monkeypatch.setattr(sys, "argv", ["ops-bench first-run", "--controller", "tracker"])
    text = section(args, [0, 1, 2], np.array([2.0, 12.0, np.inf]))
    assert text.startswith(SECTIONS["tracker"] + "\n")
    assert "**1 of 3 seeds within 10 s**" in text and "`sim -p stage:=5`" in text
    assert "topic echo" not in text
    assert "`ops-bench first-run --controller tracker`" in text
    args = parse_args([])
    assert (args.controller, args.stage, args.echo) == ("spgd", 3, "power")
    assert "`ros2 topic echo /ops/power`" in section(args, [7], np.array([1.0]))


@pytest.mark.parametrize("argv", [["--controller", "policy"], ["--seeds", "0"]])
def test_first_run_refuses_bad_options(argv, capsys):
    from ops_bench.first_run import parse_args

    with pytest.raises(SystemExit) as done:
        parse_args(argv)
    assert done.value.code == 2
    assert ("--controller" if "--controller" in argv else "--seeds") in capsys.readouterr().err


def test_controller_speed_under_a_vibration_runs_the_lab_rig_in_physical_time(capsys):
    from ops_bench.controller_speed import config_for, main, parse_args

    config = config_for(5, parse_args(["--vibration", "lab", "--rate", "100"]))
    assert (config.time_base, config.vibration, config.step_s) == ("seconds", "lab", 0.01)
    assert config_for(5, parse_args([])).time_base == "step"
    argv = ["--stages", "3", "--controllers", "tracker", "--vibration", "lab", "--rate", "100"]
    assert main([*argv, "--steps", "20", "--seeds", "1", "--repeats", "1"]) == 0
    out = capsys.readouterr().out
    assert "## Compute per reading, by controller, the lab vibration at 100 Hz" in out
    assert "| tracker | 3 |" in out


def test_controller_speed_refuses_a_rate_of_nothing(capsys):
    from ops_bench.controller_speed import parse_args

    with pytest.raises(SystemExit) as stop:
        parse_args(["--vibration", "lab", "--rate", "0"])
    assert stop.value.code == 2 and "--rate" in capsys.readouterr().err
