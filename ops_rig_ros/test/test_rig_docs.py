"""docs/rig.md lists the node's parameters exactly as they are declared."""

from __future__ import annotations

import re
from pathlib import Path

from ops_rig_ros.params import markdown_table

DOC = Path(__file__).resolve().parents[2] / "docs" / "rig.md"


def test_parameter_table_is_the_declaration():
    text = DOC.read_text()
    table = re.search(r"<!-- params:begin -->\n(.*?)<!-- params:end -->", text, re.S).group(1)
    assert table == markdown_table(), "regenerate with ops_rig_ros.params.markdown_table()"
