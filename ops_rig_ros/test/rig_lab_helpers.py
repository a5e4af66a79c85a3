"""Helpers of the rig's unit tests (a module name of its own: every package's tests share one
pytest run)."""

from __future__ import annotations

import yaml


def write_rig_yaml(lab, path, **changes):
    """The simulated lab's rig YAML at ``path``, with top-level keys replaced by ``changes``."""
    data = lab.rig_yaml()
    data.update(changes)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path
