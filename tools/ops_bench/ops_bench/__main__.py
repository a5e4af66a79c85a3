"""``python -m ops_bench ...``: the same as ``ops-bench ...``."""

import sys

from ops_bench.cli import main

sys.exit(main())
