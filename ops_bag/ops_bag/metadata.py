"""``metadata.yaml`` of a rosbag2 bag, version 9 (what ROS 2 Jazzy's rosbag2 writes)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import yaml

from . import qos as qos_io

VERSION = 9
FILE_NAME = "metadata.yaml"


@dataclass
class TopicInfo:
    name: str
    type: str
    count: int = 0
    offered_qos_profiles: list[dict] = field(default_factory=list)
    type_description_hash: str = ""
    serialization_format: str = "cdr"


def build(
    topics: list[TopicInfo],
    files: list[str],
    start_ns: int,
    end_ns: int,
    custom_data: dict[str, str] | None = None,
) -> dict:
    count = sum(t.count for t in topics)
    duration = max(0, end_ns - start_ns) if count else 0
    start = start_ns if count else 0
    return {
        "rosbag2_bagfile_information": {
            "version": VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": t.name,
                        "type": t.type,
                        "serialization_format": t.serialization_format,
                        "offered_qos_profiles": list(t.offered_qos_profiles),
                        "type_description_hash": t.type_description_hash,
                    },
                    "message_count": t.count,
                }
                for t in topics
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": list(files),
            "files": [
                {
                    "path": f,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": count,
                }
                for f in files
            ],
            "custom_data": dict(custom_data) if custom_data else None,
            "ros_distro": "jazzy",
        }
    }


def write(directory: Path, metadata: dict) -> Path:
    """Write ``metadata.yaml`` atomically (a half-written file never replaces a good one)."""
    path = Path(directory) / FILE_NAME
    tmp = path.with_name(FILE_NAME + ".tmp")
    tmp.write_text(yaml.safe_dump(metadata, default_flow_style=False, sort_keys=False))
    tmp.replace(path)
    return path


def read(directory: Path) -> dict:
    """The ``rosbag2_bagfile_information`` mapping (ValueError when it is not one)."""
    path = Path(directory) / FILE_NAME
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"{path} is not valid YAML: {' '.join(str(exc).split())}") from None
    info = data.get("rosbag2_bagfile_information") if isinstance(data, dict) else None
    if not isinstance(info, dict):
        raise ValueError(f"{path} has no rosbag2_bagfile_information")
    return info


def topics_of(info: dict) -> list[TopicInfo]:
    topics = []
    for entry in info.get("topics_with_message_count") or []:
        meta = entry.get("topic_metadata", {})
        topics.append(
            TopicInfo(
                name=str(meta.get("name", "")),
                type=str(meta.get("type", "")),
                count=int(entry.get("message_count", 0)),
                offered_qos_profiles=qos_io.loads(meta.get("offered_qos_profiles")),
                type_description_hash=str(meta.get("type_description_hash", "")),
                serialization_format=str(meta.get("serialization_format", "cdr")),
            )
        )
    return topics
