"""Writing a run as a rosbag2 MCAP file (ROS-free apart from locating .msg files).

The file is what `ros2 bag record -s mcap` writes: profile "ros2", one schema per message type
with encoding "ros2msg" (the .msg text followed by every type it uses, each after a line of
80 '=' and "MSG: pkg/Type", as rosbag2 and Foxglove expect) and CDR-serialized messages, so
rosbag2, Foxglove and the `mcap` library read it. Records are written unchunked and flushed
message by message: a process killed with SIGKILL leaves every message written so far
readable (the summary at the end, which only speeds up seeking, is then missing);
`read_recording` reads both kinds.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Callable
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory

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


class McapRecording:
    """One MCAP file, written as messages arrive (thread-safe)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed by close()
        self._writer = Writer(self._file, use_chunking=False,
                              compression=CompressionType.NONE)
        self._writer.start(profile="ros2", library="katana_bringup recording")
        self._file.flush()
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._lock = threading.Lock()
        self._closed = False
        self.counts: dict[str, int] = {}

    def add_topic(self, topic: str, full_type: str, definition: str | None = None) -> None:
        with self._lock:
            if full_type not in self._schemas:
                text = definition if definition is not None else message_definition(full_type)
                self._schemas[full_type] = self._writer.register_schema(
                    name=full_type, encoding="ros2msg", data=text.encode())
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=self._schemas[full_type])
            self.counts[topic] = 0
            self._file.flush()

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
            self._file.flush()

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._writer.finish()
            self._file.close()


def read_recording(path: str | Path):
    """Yield (topic, type name, log time ns, decoded message) of every message in the file.

    A complete file is read through its summary; one whose writer was killed (no summary, a
    record cut short at the end) is scanned from the start up to the last complete record.
    """
    with open(path, "rb") as fh:
        try:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
        except (McapError, EOFError, ValueError):
            summary = None
        if summary is not None and summary.statistics is not None:
            for schema, channel, message, decoded in reader.iter_decoded_messages():
                yield channel.topic, schema.name, message.log_time, decoded
            return
        fh.seek(0)
        scan = NonSeekingReader(fh, decoder_factories=[DecoderFactory()])
        try:
            for schema, channel, message, decoded in scan.iter_decoded_messages(
                    log_time_order=False):
                yield channel.topic, schema.name, message.log_time, decoded
        except (McapError, EOFError):
            return  # the writer was killed: everything before the cut has been read
