"""Interface definitions (.msg / .srv files) of the installed ROS 2 packages.

Finds ``share/PKG/{msg,srv}/NAME.{msg,srv}`` under the ament prefixes (AMENT_PREFIX_PATH, the
Python environment's prefix, where the ROS 2 wheels put them, and /opt/ros/jazzy), and builds the
``ros2msg`` schema text rosbag2 stores in MCAP: the type's own definition followed by each type it
uses, once, after a line of 80 ``=`` and ``MSG: pkg/Name``.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

PRIMITIVES = {
    "bool",
    "byte",
    "char",
    "float32",
    "float64",
    "int8",
    "uint8",
    "int16",
    "uint16",
    "int32",
    "uint32",
    "int64",
    "uint64",
    "string",
    "wstring",
}
SEPARATOR = "=" * 80


class InterfaceNotFound(LookupError):
    """No definition file for an interface type."""


def prefixes() -> list[Path]:
    """The ament prefixes to search, in order, without duplicates."""
    found = []
    for entry in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if entry:
            found.append(Path(entry))
    found += [Path(sys.prefix), Path("/opt/ros/jazzy")]
    unique = []
    for p in found:
        if p not in unique:
            unique.append(p)
    return unique


def split_type(identifier: str, default_kind: str = "msg") -> tuple[str, str, str]:
    """``pkg/msg/Name`` or ``pkg/Name`` -> (pkg, kind, Name)."""
    parts = identifier.split("/")
    if len(parts) == 3 and parts[1] in ("msg", "srv", "action") and parts[0] and parts[2]:
        return parts[0], parts[1], parts[2]
    if len(parts) == 2 and parts[0] and parts[1]:
        return parts[0], default_kind, parts[1]
    raise ValueError(f"Invalid interface type '{identifier}' (expected pkg/msg/Name)")


def definition_path(identifier: str, default_kind: str = "msg") -> Path:
    pkg, kind, name = split_type(identifier, default_kind)
    for prefix in prefixes():
        path = prefix / "share" / pkg / kind / f"{name}.{kind}"
        if path.is_file():
            return path
    raise InterfaceNotFound(f"Unknown {kind} type '{pkg}/{kind}/{name}'")


def definition_text(identifier: str, default_kind: str = "msg") -> str:
    return definition_path(identifier, default_kind).read_text()


def field_types(package: str, text: str) -> list[str]:
    """The non-primitive field types (``pkg/msg/Name``) used by a .msg text, in order."""
    used = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        tokens = line.split()
        if len(tokens) < 2:
            continue
        # constants (TYPE NAME=VALUE) have primitive types, so they are skipped below too
        base = tokens[0].split("[", 1)[0].split("<=", 1)[0]
        if base in PRIMITIVES:
            continue
        parts = base.split("/")
        if len(parts) == 1:
            full = f"{package}/msg/{parts[0]}"
        elif len(parts) == 2:
            full = f"{parts[0]}/msg/{parts[1]}"
        else:
            full = base
        if full not in used:
            used.append(full)
    return used


def message_definition(type_name: str) -> str:
    """The full ``ros2msg`` schema text of a message type (with its dependencies)."""
    pkg, _, name = split_type(type_name)
    root = f"{pkg}/msg/{name}"
    text = definition_text(root)
    parts = [text.rstrip("\n")]
    seen = {root}
    queue = field_types(pkg, text)
    while queue:
        dep = queue.pop(0)
        if dep in seen:
            continue
        seen.add(dep)
        dep_pkg, _, dep_name = split_type(dep)
        dep_text = definition_text(dep)
        parts.append(f"{SEPARATOR}\nMSG: {dep_pkg}/{dep_name}\n{dep_text.rstrip(chr(10))}")
        queue += [t for t in field_types(dep_pkg, dep_text) if t not in seen]
    return "\n".join(parts) + "\n"


def type_hash(type_name: str) -> str:
    """The RIHS01 type description hash of a type, from its ``.json`` (empty when unknown)."""
    pkg, kind, name = split_type(type_name)
    full = f"{pkg}/{kind}/{name}"
    for prefix in prefixes():
        path = prefix / "share" / pkg / kind / f"{name}.json"
        if path.is_file():
            try:
                hashes = json.loads(path.read_text()).get("type_hashes", [])
            except (OSError, ValueError):
                return ""
            for entry in hashes:
                if entry.get("type_name") == full:
                    return str(entry.get("hash_string", ""))
    return ""


def packages_with_interfaces() -> dict[str, list[str]]:
    """{package: ['msg/Name', 'srv/Name', ...]} from the ament index of every prefix."""
    result: dict[str, list[str]] = {}
    for prefix in prefixes():
        index = prefix / "share" / "ament_index" / "resource_index" / "rosidl_interfaces"
        if not index.is_dir():
            continue
        for entry in sorted(index.iterdir()):
            if entry.name in result:
                continue
            names = []
            for line in entry.read_text().splitlines():
                line = line.strip()
                if line.endswith((".msg", ".srv", ".action")):
                    names.append(line.rsplit(".", 1)[0])
            result[entry.name] = sorted(set(names))
    return result
