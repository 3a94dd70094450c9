"""Writing a run as a rosbag2 MCAP file, and repairing one whose writer was killed (ROS-free
apart from locating .msg files).

The file is what `ros2 bag record -s mcap` writes: profile "ros2", one schema per message type
with encoding "ros2msg" (the .msg text followed by every type it uses, each after a line of
80 '=' and "MSG: pkg/Type", as rosbag2 and Foxglove expect), one channel per topic with the
publishers' `offered_qos_profiles` (bag_qos) and CDR-serialized messages in zstd-compressed
chunks, with the chunk and message indexes and the summary that seeking readers (rosbag2,
rosbags, Foxglove) need.

Crash safety: messages wait in the open chunk, in memory, until `flush()` (the recorder calls
it on a timer) or the chunk size closes it; a closed chunk is written and handed to the OS at
once. A process killed with SIGKILL therefore leaves every message up to the last flush in
complete chunks, but no summary or footer, which seeking readers refuse ("File end magic is
invalid"). `repair` reads such a file record by record up to its last complete record and
rewrites it indexed, replacing the original only once the rewrite reads back with every
recovered message.
"""

from __future__ import annotations

import os
import re
import struct
import threading
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, DataEnd, Header, Message, Schema
from mcap.stream_reader import CRCValidationError, StreamReader
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory

from . import bag_qos

_BUILTIN = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
            "int32", "uint32", "int64", "uint64", "string", "wstring"}
_SEPARATOR = "=" * 80


def _msg_path(full_type: str) -> Path:
    """The .msg file of 'pkg/msg/Type' from the ament index."""
    pkg, _, name = full_type.split("/")
    return Path(get_package_share_directory(pkg)) / "msg" / f"{name}.msg"


def _field_types(text: str, package: str) -> list[str]:
    """'pkg/msg/Type' of every non-builtin field of a .msg text (constants skipped)."""
    out = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) < 2 or "=" in parts[1] or (len(parts) > 2 and parts[2].startswith("=")):
            continue  # a constant: TYPE NAME=VALUE
        base = re.sub(r"\[.*\]$", "", parts[0])
        base = re.sub(r"<=\d+$", "", base)
        if base in _BUILTIN:
            continue
        if "/" not in base:
            base = f"{package}/{base}"
        pkg, name = base.split("/")[0], base.split("/")[-1]
        out.append(f"{pkg}/msg/{name}")
    return out


def message_definition(full_type: str,
                       read: Callable[[str], str] = lambda t: _msg_path(t).read_text()) -> str:
    """rosbag2's 'ros2msg' schema text of `full_type` ('sensor_msgs/msg/Image')."""
    main = read(full_type)
    seen: list[str] = []
    todo = _field_types(main, full_type.split("/")[0])
    texts: dict[str, str] = {}
    while todo:
        dep = todo.pop(0)
        if dep in seen:
            continue
        seen.append(dep)
        texts[dep] = read(dep)
        todo += _field_types(texts[dep], dep.split("/")[0])
    parts = [main.rstrip("\n")]
    for dep in seen:
        pkg, _, name = dep.split("/")
        parts += [_SEPARATOR, f"MSG: {pkg}/{name}", texts[dep].rstrip("\n")]
    return "\n".join(parts) + "\n"


#: chunk size before compression: a camera frame or about a second of the other topics
CHUNK_SIZE = 1024 * 1024
LIBRARY = "katana_bringup recording"


def _writer(stream) -> Writer:
    """The writer of every recording: chunked, zstd, every index, summary and CRCs."""
    return Writer(stream, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)


class McapRecording:
    """One MCAP file, written as messages arrive (thread-safe); `flush()` bounds what a kill
    loses to the messages since the last call."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed by close()
        self._writer = _writer(self._file)
        self._writer.start(profile="ros2", library=LIBRARY)
        self._file.flush()
        self._last_tell = self._file.tell()
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._lock = threading.Lock()
        self._closed = False
        self._pending = 0
        self.counts: dict[str, int] = {}
        #: messages handed to the OS in complete chunks: what a kill cannot take away
        self.flushed = 0

    def add_topic(self, topic: str, full_type: str, definition: str | None = None,
                  offered_qos: list[dict] | None = None) -> None:
        """A channel for `topic` (once: a second call is ignored); `offered_qos` are the
        publishers' profiles (bag_qos)."""
        with self._lock:
            if topic in self._channels:
                return
            if full_type not in self._schemas:
                text = definition if definition is not None else message_definition(full_type)
                self._schemas[full_type] = self._writer.register_schema(
                    name=full_type, encoding="ros2msg", data=text.encode())
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=self._schemas[full_type],
                metadata={"offered_qos_profiles": bag_qos.dump(offered_qos or [])})
            self.counts[topic] = 0

    def has_topic(self, topic: str) -> bool:
        return topic in self._channels

    def write(self, topic: str, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        with self._lock:
            if self._closed:
                return
            self._writer.add_message(
                channel_id=self._channels[topic], log_time=log_time_ns, data=data,
                publish_time=log_time_ns if publish_time_ns is None else publish_time_ns,
                sequence=self.counts[topic])
            self.counts[topic] += 1
            self._pending += 1
            if self._writer_closed_a_chunk():
                self._hand_over()

    def _writer_closed_a_chunk(self) -> bool:
        """The writer closes a chunk by itself at CHUNK_SIZE: its bytes then reach the file."""
        return self._file.tell() != self._last_tell

    def _hand_over(self) -> None:
        self._file.flush()
        self._last_tell = self._file.tell()
        self.flushed += self._pending
        self._pending = 0

    def flush(self) -> None:
        """Close the open chunk and hand it to the OS: a kill after this loses none of it."""
        with self._lock:
            if self._closed or self._pending == 0:
                return
            self._writer.flush()
            self._hand_over()

    def close(self) -> None:
        """Write the last chunk, the indexes and the summary."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._writer.finish()
            self.flushed += self._pending
            self._pending = 0
            self._file.close()


#: what a record cut short or a damaged chunk raises while scanning
_SCAN_ERRORS = (McapError, EOFError, CRCValidationError, ValueError, struct.error, zlib.error,
                KeyError, IndexError)


def is_indexed(path: str | Path) -> bool:
    """Whether the file ends with a footer and a whole summary (a finished writer's file)."""
    with open(path, "rb") as fh:
        try:
            summary = make_reader(fh).get_summary()
        except (*_SCAN_ERRORS, OSError):
            return False
    return summary is not None and summary.statistics is not None


def scan_records(path: str | Path) -> Iterator[Header | Schema | Channel | Message]:
    """The header, schemas, channels and messages of the file in order, records inside
    complete chunks included, up to the end of the data section or the first record cut
    short or damaged."""
    with open(path, "rb") as fh:
        records = StreamReader(fh, validate_crcs=True).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except _SCAN_ERRORS:
                return  # the writer was killed: everything before the cut has been read
            except Exception as err:  # zstd's own error class is not importable by name
                if type(err).__module__.startswith("zstandard"):
                    return
                raise
            if isinstance(record, DataEnd):
                return  # the summary repeats what came before
            if isinstance(record, Header | Schema | Channel | Message):
                yield record


@dataclass(frozen=True)
class RepairReport:
    """What `repair` did: `repaired` False when the file was already indexed."""

    repaired: bool
    messages: int
    topics: dict[str, int]


def repair(path: str | Path) -> RepairReport:
    """Make a killed writer's file indexed, keeping every complete message.

    The rewrite goes to a temporary file beside it, is read back through its summary and must
    hold exactly the messages scanned; only then does it replace the original (an atomic
    rename), so a failure at any point leaves the original as it was."""
    path = Path(path)
    if is_indexed(path):
        return RepairReport(False, *_indexed_counts(path))
    tmp = path.with_name(path.name + ".repair")
    counts: dict[str, int] = {}
    try:
        with open(tmp, "wb") as out:
            writer = _writer(out)
            schemas: dict[int, int] = {}
            channels: dict[int, tuple[int, str]] = {}
            started = False
            for record in scan_records(path):
                if isinstance(record, Header):
                    writer.start(profile=record.profile, library=record.library)
                    started = True
                    continue
                if not started:
                    writer.start(profile="ros2", library=LIBRARY)
                    started = True
                if isinstance(record, Schema) and record.id not in schemas:
                    schemas[record.id] = writer.register_schema(
                        name=record.name, encoding=record.encoding, data=record.data)
                elif isinstance(record, Channel) and record.id not in channels:
                    channels[record.id] = (writer.register_channel(
                        topic=record.topic, message_encoding=record.message_encoding,
                        schema_id=schemas.get(record.schema_id, 0),
                        metadata=dict(record.metadata)), record.topic)
                    counts.setdefault(record.topic, 0)
                elif isinstance(record, Message) and record.channel_id in channels:
                    new_id, topic = channels[record.channel_id]
                    writer.add_message(channel_id=new_id, log_time=record.log_time,
                                       data=record.data, publish_time=record.publish_time,
                                       sequence=record.sequence)
                    counts[topic] += 1
            if not started:
                raise McapError(f"{path} is no MCAP file (no header)")
            writer.finish()
            out.flush()
            os.fsync(out.fileno())
        got = _indexed_counts(tmp)
        if got != (sum(counts.values()), counts):
            raise McapError(f"the rewrite of {path} reads back {got}, expected {counts}")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return RepairReport(True, sum(counts.values()), counts)


def _indexed_counts(path: Path) -> tuple[int, dict[str, int]]:
    """(messages, topic -> messages) from an indexed file's summary."""
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    stats = summary.statistics
    counts: dict[str, int] = {}
    for cid, channel in summary.channels.items():
        counts[channel.topic] = counts.get(channel.topic, 0) + stats.channel_message_counts.get(
            cid, 0)
    return stats.message_count, counts


def read_recording(path: str | Path):
    """Yield (topic, type name, log time ns, decoded message) of every message in the file.

    An indexed file is read through its summary, in log-time order; one whose writer was
    killed is scanned in file order up to its last complete record (`scan_records`).
    """
    if is_indexed(path):
        with open(path, "rb") as fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            for schema, channel, message, decoded in reader.iter_decoded_messages():
                yield channel.topic, schema.name, message.log_time, decoded
        return
    factory = DecoderFactory()
    schemas: dict[int, Schema] = {}
    channels: dict[int, tuple[str, str, Callable]] = {}
    for record in scan_records(path):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel) and record.schema_id in schemas:
            schema = schemas[record.schema_id]
            channels[record.id] = (record.topic, schema.name,
                                   factory.decoder_for(record.message_encoding, schema))
        elif isinstance(record, Message) and record.channel_id in channels:
            topic, type_name, decode = channels[record.channel_id]
            yield topic, type_name, record.log_time, decode(record.data)
