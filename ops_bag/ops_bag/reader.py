"""Reading a rosbag2 MCAP bag (a bag directory, or one ``.mcap`` file), damaged ones included.

A complete file is read through its summary and index (the ``mcap`` library's seeking reader).
A file without a summary - a recorder killed outright, a full disk - is scanned record by record
up to the first incomplete or damaged record: everything before it is recovered, and
:attr:`BagReader.problem` says what is missing.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

from . import metadata
from . import qos as qos_io


class BagReadError(RuntimeError):
    """The path is not a readable bag."""


class BagMessage(NamedTuple):
    topic: str
    type: str
    data: bytes
    log_time_ns: int


class BagReader:
    def __init__(self, path):
        self.path = Path(path)
        if not self.path.exists():
            raise BagReadError(f"Bag '{self.path}' does not exist")
        self.info: dict | None = None
        if self.path.is_dir():
            self.file_path = self._find_file()
        else:
            self.file_path = self.path
            if self.path.suffix != ".mcap":
                raise BagReadError(f"'{self.path}' is neither a bag directory nor an .mcap file")
        self.problem: str | None = None
        self.topics: list[metadata.TopicInfo] = []
        self.start_ns = 0
        self.end_ns = 0
        self.complete = False
        self._scan()

    # ---------------------------------------------------------------------------- opening
    def _find_file(self) -> Path:
        meta_path = self.path / metadata.FILE_NAME
        if meta_path.is_file():
            try:
                self.info = metadata.read(self.path)
            except (OSError, ValueError) as exc:
                self.info = None
                self._meta_problem = str(exc)
        files = []
        if self.info:
            files = [self.path / f for f in self.info.get("relative_file_paths") or []]
            files = [f for f in files if f.is_file()]
            storage = self.info.get("storage_identifier")
            if storage and storage != "mcap":
                raise BagReadError(
                    f"Bag '{self.path}' uses the storage '{storage}'; this reader reads mcap only"
                )
        if not files:
            files = sorted(self.path.glob("*.mcap"))
        if not files:
            what = "metadata.yaml names no file that exists" if self.info else "no metadata.yaml"
            raise BagReadError(f"'{self.path}' is not a readable bag: {what} and no .mcap file")
        if len(files) > 1:
            raise BagReadError(f"Bag '{self.path}' is split into {len(files)} files; not supported")
        return files[0]

    def _open(self):
        try:
            return open(self.file_path, "rb")
        except OSError as exc:
            raise BagReadError(f"cannot open {self.file_path}: {exc.strerror}") from None

    def _scan(self) -> None:
        from mcap.exceptions import McapError
        from mcap.reader import SeekingReader

        if self.file_path.stat().st_size == 0:
            raise BagReadError(f"'{self.file_path}' is empty: the recording wrote nothing")
        with self._open() as f:
            try:
                reader = SeekingReader(f)
            except McapError as exc:
                raise BagReadError(f"'{self.file_path}' is not an MCAP file ({exc})") from None
            except Exception as exc:
                raise BagReadError(f"'{self.file_path}' is not an MCAP file ({exc})") from None
            try:
                summary = reader.get_summary()
            except Exception:
                summary = None
            if summary is not None and summary.statistics is not None:
                self.complete = True
                stats = summary.statistics
                counts = stats.channel_message_counts
                channels = summary.channels
                schemas = summary.schemas
                self.start_ns = stats.message_start_time
                self.end_ns = stats.message_end_time
                self._set_topics(channels, schemas, counts)
                return
        self._scan_records()

    def _scan_records(self) -> None:
        channels, schemas, counts = {}, {}, {}
        start, end = None, 0
        for record in self._records():
            kind = type(record).__name__
            if kind == "Schema":
                schemas[record.id] = record
            elif kind == "Channel":
                channels[record.id] = record
            elif kind == "Message":
                counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
                start = record.log_time if start is None else min(start, record.log_time)
                end = max(end, record.log_time)
        self.start_ns, self.end_ns = start or 0, end
        self._set_topics(channels, schemas, counts)

    def _records(self):
        """Records in file order up to the end or the first damaged record (sets problem)."""
        from mcap.records import Footer
        from mcap.stream_reader import StreamReader

        with self._open() as f:
            reader = StreamReader(f)
            it = reader.records
            while True:
                try:
                    record = next(it)
                except StopIteration:
                    return
                except Exception as exc:
                    detail = str(exc) or type(exc).__name__
                    self.problem = (
                        f"'{self.file_path}' is truncated or damaged ({detail}); "
                        "the messages before the damage were recovered"
                    )
                    return
                if isinstance(record, Footer):
                    return
                yield record

    def _set_topics(self, channels, schemas, counts) -> None:
        known = {}
        if self.info:
            known = {t.name: t for t in metadata.topics_of(self.info)}
        topics = []
        for cid, channel in sorted(channels.items()):
            schema = schemas.get(channel.schema_id)
            type_name = schema.name if schema is not None else known.get(channel.topic)
            if not isinstance(type_name, str):
                type_name = getattr(type_name, "type", "") or ""
            profiles = qos_io.loads(channel.metadata.get("offered_qos_profiles"))
            if not profiles and channel.topic in known:
                profiles = known[channel.topic].offered_qos_profiles
            topics.append(
                metadata.TopicInfo(
                    name=channel.topic,
                    type=type_name,
                    count=int(counts.get(cid, 0)),
                    offered_qos_profiles=profiles,
                    type_description_hash=channel.metadata.get("topic_type_hash", ""),
                    serialization_format=channel.message_encoding,
                )
            )
        self.topics = topics
        self._channel_topics = {cid: c.topic for cid, c in channels.items()}
        self._types = {t.name: t.type for t in topics}

    # ---------------------------------------------------------------------------- contents
    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics)

    @property
    def duration_ns(self) -> int:
        return max(0, self.end_ns - self.start_ns) if self.message_count else 0

    @property
    def size_bytes(self) -> int:
        return self.file_path.stat().st_size

    def messages(self, topics=None) -> Iterator[BagMessage]:
        """Messages (raw CDR) in log-time order (file order for a damaged file)."""
        wanted = None if topics is None else set(topics)
        if self.complete:
            from mcap.reader import SeekingReader

            with self._open() as f:
                reader = SeekingReader(f)
                for _, channel, message in reader.iter_messages(
                    topics=None if wanted is None else list(wanted), log_time_order=True
                ):
                    yield BagMessage(
                        channel.topic,
                        self._types.get(channel.topic, ""),
                        bytes(message.data),
                        message.log_time,
                    )
            return
        for record in self._records():
            if type(record).__name__ != "Message":
                continue
            topic = self._channel_topics.get(record.channel_id)
            if topic is None or (wanted is not None and topic not in wanted):
                continue
            yield BagMessage(topic, self._types.get(topic, ""), bytes(record.data), record.log_time)
