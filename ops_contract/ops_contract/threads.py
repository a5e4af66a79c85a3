"""One BLAS thread per process unless the user asks for more.

The physics, the tracker's fits and the policies' numpy work are small matrix products: a second
BLAS thread gains nothing there, and on a busy machine (a node beside another node, a training
beside a rig) an OpenBLAS thread that waits for a core stalls the product it belongs to: with
two busy processes on a 2-core machine the tracker's slowest readings took about three times as
long with one BLAS thread per core as with one thread (docs/results/tracker/notes.md).
Every node (``run_node``) and the ``train`` / ``evaluate`` CLIs call :func:`limit_blas_threads`
first; a user who sets ``OPENBLAS_NUM_THREADS`` (or ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS``)
keeps that choice. The policy node runs torch's small networks on one thread likewise
(:func:`limit_torch_threads`): on the loaded 2-core machine the n5_hard_switch model's action
took 1.3 ms at the median either way, but 48 ms at the 90th percentile with torch's default of a
thread per core against 5.5 ms with one (1000 actions in process, load 5).
"""

from __future__ import annotations

import os

THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def limit_blas_threads(threads: int = 1) -> bool:
    """Limit the BLAS libraries loaded in this process to ``threads`` threads, unless one of
    :data:`THREAD_VARIABLES` is set (the user's choice is kept). Returns whether it limited."""
    if any(os.environ.get(name) for name in THREAD_VARIABLES):
        return False
    import numpy  # noqa: F401  (loads the BLAS library that the limit applies to)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=threads, user_api="blas")
    return True


def limit_torch_threads(threads: int = 1) -> bool:
    """Run torch's operators on ``threads`` threads (importing torch), unless one of
    :data:`THREAD_VARIABLES` is set (the user's choice is kept). Returns whether it limited."""
    if any(os.environ.get(name) for name in THREAD_VARIABLES):
        return False
    import torch

    torch.set_num_threads(threads)
    return True
