"""limit_blas_threads: one BLAS thread unless the user set a thread count (checked in fresh
interpreters, since the limit is process-wide and BLAS reads the variables when it loads)."""

import json
import os
import subprocess
import sys

import pytest
from ops_contract.threads import THREAD_VARIABLES

PROBE = """
import json, sys
import numpy
from threadpoolctl import threadpool_info
from ops_contract.threads import limit_blas_threads
limited = limit_blas_threads() if sys.argv[1] == "limit" else None
threads = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
print(json.dumps([limited, threads]))
"""


def probe(call: str, **env) -> tuple[bool | None, list[int]]:
    """(what limit_blas_threads returned, the BLAS libraries' thread counts) in a fresh
    interpreter with ``env`` and none of the user's thread variables."""
    clean = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    out = subprocess.run(
        [sys.executable, "-c", PROBE, call], env={**clean, **env}, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    limited, threads = json.loads(out.stdout)
    return limited, threads


def test_limits_every_blas_library_to_one_thread():
    limited, threads = probe("limit")
    assert limited
    assert threads and all(t == 1 for t in threads)


@pytest.mark.parametrize("name", THREAD_VARIABLES)
def test_a_thread_count_the_user_set_is_kept(name):
    limited, threads = probe("limit", **{name: "2"})
    assert limited is False
    assert threads == probe("none", **{name: "2"})[1]  # what BLAS made of it, untouched


TORCH_PROBE = """
import sys
from ops_contract.threads import limit_torch_threads
limited = limit_torch_threads()
import torch
print(limited, torch.get_num_threads())
"""


def test_torch_runs_on_one_thread_unless_the_user_set_a_count():
    pytest.importorskip("torch")
    clean = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    for env, expected in (({}, "True 1"), ({"OMP_NUM_THREADS": "2"}, "False 2")):
        out = subprocess.run(
            [sys.executable, "-c", TORCH_PROBE],
            env={**clean, **env},
            capture_output=True,
            text=True,
        )
        assert out.returncode == 0, out.stderr
        assert out.stdout.split() == expected.split()
