"""Moved to :mod:`ops_gym_bridge.table1.bench_worker`; this name stays so that a benchmark started
before the move (whose scheduler runs ``python -m ops_gym_bridge.bench_worker``) can go on."""

from .table1.bench_worker import main

if __name__ == "__main__":
    main()
