"""Writing a rosbag2 bag: a new directory with one ``.mcap`` file and ``metadata.yaml``.

The MCAP container is written by the ``mcap`` library (profile ``ros2``, zstd chunks); each
channel carries ``offered_qos_profiles`` and ``topic_type_hash`` metadata and a ``ros2msg``
schema (checked with ``mcap-ros2-support``'s parser), as rosbag2's MCAP storage plugin writes.

Losing little on failure: the current chunk is written out at least every ``flush_period_s``
seconds (0.25 s by default; :meth:`BagWriter.flush_if_due` lets a recorder flush while no
message comes) and whenever it holds ``chunk_size`` bytes (32 KiB: a bag written faster than
real time, by an evaluation, is many chunks too), and ``metadata.yaml`` is rewritten then
(describing only what is on disk), so a recorder killed outright leaves a readable bag of
everything up to the last flush, and a file cut anywhere keeps every chunk before the cut.
A write error (disk full, file too large) stops writing with :class:`BagWriteError`; what was
flushed before stays readable (the reader recovers an MCAP file without its summary).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

from . import interfaces, metadata
from . import qos as qos_io

LIBRARY = "ops_bag 0.1.0"


class BagExistsError(FileExistsError):
    """The output directory already exists (a bag is never overwritten)."""


class BagWriteError(OSError):
    """Writing the bag failed; what was written before the failure is kept."""


@dataclass
class _Topic:
    info: metadata.TopicInfo
    channel_id: int
    flushed_count: int = 0


class _File:
    """An unbuffered output file for the MCAP writer, which buffers whole records and chunks
    itself: every record it hands over reaches the OS at once (nothing waits in a buffer that a
    crash or a failed write would lose or leave half-written later)."""

    def __init__(self, path: Path):
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self._pos = 0

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        while view:
            n = os.write(self._fd, view)
            self._pos += n
            view = view[n:]
        return len(data)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)


def check_schema(type_name: str, text: str) -> None:
    """Raise ValueError unless mcap-ros2-support can build a CDR codec from the schema."""
    from mcap_ros2._dynamic import generate_dynamic

    try:
        generate_dynamic(type_name, text)
    except Exception as exc:  # the parser raises several kinds
        raise ValueError(f"the definition of {type_name} cannot be parsed: {exc}") from None


class BagWriter:
    def __init__(
        self,
        path,
        *,
        flush_period_s: float = 0.25,
        chunk_size: int = 32 * 1024,
        compression: str = "zstd",
        custom_data: dict[str, str] | None = None,
    ):
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        if self.path.exists():
            raise BagExistsError(f"Output folder '{self.path}' already exists.")
        try:
            self.path.mkdir(parents=True)
        except FileExistsError:
            raise BagExistsError(f"Output folder '{self.path}' already exists.") from None
        self.file_name = f"{self.path.name}_0.mcap"
        self.file_path = self.path / self.file_name
        self.custom_data = dict(custom_data or {})
        self.flush_period_s = flush_period_s
        self._stream = _File(self.file_path)
        self._writer = Writer(
            self._stream,
            chunk_size=chunk_size,
            compression=CompressionType[compression.upper()]
            if compression
            else CompressionType.NONE,
        )
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, _Topic] = {}
        self._start_ns: int | None = None
        self._end_ns = 0
        self._flushed_end_ns = 0
        self._last_flush = time.monotonic()
        self._failed: OSError | None = None
        self.closed = False
        self._guard(self._writer.start, profile="ros2", library=LIBRARY)
        self._write_metadata(flushed_only=True)

    # ---------------------------------------------------------------------------- topics
    @property
    def topics(self) -> list[metadata.TopicInfo]:
        return [t.info for t in self._topics.values()]

    def has_topic(self, name: str) -> bool:
        return name in self._topics

    def add_topic(self, name: str, type_name: str, offered_qos: list[dict] | None = None):
        """Register a topic (its schema once per type); ValueError for an unknown type."""
        if name in self._topics:
            return
        pkg, _, short = interfaces.split_type(type_name)
        full_type = f"{pkg}/msg/{short}"
        schema_id = self._schemas.get(full_type)
        if schema_id is None:
            try:
                text = interfaces.message_definition(full_type)
            except interfaces.InterfaceNotFound as exc:
                raise ValueError(f"cannot record {name}: {exc}") from None
            check_schema(full_type, text)
            schema_id = self._guard(
                self._writer.register_schema, name=full_type, encoding="ros2msg", data=text.encode()
            )
            self._schemas[full_type] = schema_id
        profiles = list(offered_qos or [])
        type_hash = interfaces.type_hash(full_type)
        channel_id = self._guard(
            self._writer.register_channel,
            topic=name,
            message_encoding="cdr",
            schema_id=schema_id,
            metadata={
                "offered_qos_profiles": qos_io.dumps(profiles),
                "topic_type_hash": type_hash,
            },
        )
        info = metadata.TopicInfo(
            name=name,
            type=full_type,
            offered_qos_profiles=profiles,
            type_description_hash=type_hash,
        )
        self._topics[name] = _Topic(info=info, channel_id=channel_id)

    # ---------------------------------------------------------------------------- messages
    def write(self, topic: str, data: bytes, log_time_ns: int | None = None) -> None:
        """Append one CDR-serialized message of a registered topic."""
        if self.closed:
            raise BagWriteError(f"bag {self.path} is closed")
        t = self._topics[topic]
        stamp = time.time_ns() if log_time_ns is None else int(log_time_ns)
        t.info.count += 1
        if self._start_ns is None or stamp < self._start_ns:
            self._start_ns = stamp
        self._end_ns = max(self._end_ns, stamp)
        self._guard(
            self._writer.add_message,
            channel_id=t.channel_id,
            log_time=stamp,
            publish_time=stamp,
            data=bytes(data),
            sequence=t.info.count,
        )
        self.flush_if_due()

    def flush_if_due(self) -> None:
        """Flush when ``flush_period_s`` has passed since the last flush (and data waits)."""
        if self.closed or self._failed is not None:
            return
        if time.monotonic() - self._last_flush < self.flush_period_s:
            return
        if all(t.flushed_count == t.info.count for t in self._topics.values()):
            self._last_flush = time.monotonic()  # nothing new: no rewrite of metadata.yaml
            return
        self.flush()

    def flush(self) -> None:
        """Write the open chunk and ``metadata.yaml`` describing everything on disk."""
        self._guard(self._writer.flush)
        self._last_flush = time.monotonic()
        for t in self._topics.values():
            t.flushed_count = t.info.count
        self._flushed_end_ns = self._end_ns
        self._write_metadata(flushed_only=True)

    @property
    def message_count(self) -> int:
        return sum(t.info.count for t in self._topics.values())

    # ---------------------------------------------------------------------------- closing
    def close(self) -> None:
        """Finish the MCAP file (summary and index) and write the final ``metadata.yaml``."""
        if self.closed:
            return
        self.closed = True
        if self._failed is None:
            try:
                self._writer.finish()
            except OSError as exc:
                self._failed = exc
        self._stream.close()
        if self._failed is None:
            self._write_metadata(flushed_only=False)
        else:
            raise self._error(self._failed)

    def _write_metadata(self, flushed_only: bool) -> None:
        topics = []
        for t in self._topics.values():
            info = metadata.TopicInfo(**vars(t.info))
            if flushed_only:
                info.count = t.flushed_count
            topics.append(info)
        end = self._flushed_end_ns if flushed_only else self._end_ns
        data = metadata.build(
            topics, [self.file_name], self._start_ns or 0, end, custom_data=self.custom_data
        )
        try:
            metadata.write(self.path, data)
        except OSError as exc:
            if self._failed is None:
                self._failed = exc
                raise self._error(exc) from None

    # ---------------------------------------------------------------------------- errors
    def _error(self, exc: OSError) -> BagWriteError:
        flushed = sum(t.flushed_count for t in self._topics.values())
        return BagWriteError(
            exc.errno,
            f"writing bag {self.path} failed ({exc.strerror or exc}); recording stopped. The "
            f"{flushed} messages written before stay readable: ros2 bag info {self.path}",
        )

    def _guard(self, fn, *args, **kwargs):
        if self._failed is not None:
            raise self._error(self._failed)
        try:
            return fn(*args, **kwargs)
        except OSError as exc:
            self._failed = exc
            self.closed = True
            self._stream.close()
            raise self._error(exc) from None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
