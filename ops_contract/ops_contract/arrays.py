"""Small array helpers for the per-step hot paths (single environments are call-bound)."""

from __future__ import annotations

import numpy as np

_maximum, _minimum = np.maximum, np.minimum


def clip(a, low, high, out=None):
    """``np.clip`` as two bare ufunc calls: cheaper than its wrapper on small arrays."""
    if out is None:
        return _minimum(_maximum(a, low), high)
    _maximum(a, low, out=out)
    return _minimum(out, high, out=out)
