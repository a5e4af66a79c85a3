"""scripts/uv_sources.py: pip's package sources as the uv options setup.sh installs with."""

from __future__ import annotations

import runpy
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "uv_sources.py"
uv_options = runpy.run_path(str(SCRIPT))["uv_options"]


def test_every_source_of_pip_config_list_becomes_a_uv_option_once():
    pip_config = "\n".join(
        [
            ":env:.find-links='/opt/wheels'",
            ":env:.index-url='https://mirror.example/simple'",
            "global.cert='/etc/ssl/certs/ca.crt'",
            "global.constraint='/etc/pip/constraints.txt'",
            "global.extra-index-url='file:///a/simple file:///b/simple'",
            "global.find-links='/opt/wheels'",
            "global.index-url='https://pypi.org/simple'",
            "user.timeout='60'",
        ]
    )
    assert uv_options(pip_config) == [
        "--index-url", "https://mirror.example/simple",  # the environment's, as in pip
        "--find-links", "/opt/wheels",  # named twice, passed once
        "--constraint", "/etc/pip/constraints.txt",
        "--extra-index-url", "file:///a/simple",
        "--extra-index-url", "file:///b/simple",
    ]  # fmt: skip
    assert uv_options("") == []


def test_the_script_reads_this_machines_pip_configuration():
    done = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    words = done.stdout.split()
    assert len(words) % 2 == 0
    assert set(words[::2]) <= {"--index-url", "--extra-index-url", "--find-links", "--constraint"}
