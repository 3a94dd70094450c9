"""katana-play's command line and timing (ROS-free; katana_bringup.play is the ROS side).

    katana-play FILE.mcap [--rate R] [--loop] [--topics T ...] [--delay S]
    katana-play --repair FILE.mcap

Plays a recording as `ros2 bag play --clock` does: each message at its recorded log time,
the gaps scaled by 1/rate, and the playback time on /clock between and with the messages.
A file left by a killed recorder (no summary) is repaired first (recording.repair), since
playback needs its channels and counts; `--repair` only repairs.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from katana_common.cli_args import (
    CommandLineError,
    non_negative_seconds,
    parse_command_line,
    positive_number,
    readable_file,
)
from mcap.reader import make_reader
from mcap.records import Channel, Schema

from . import bag_qos
from .recording import is_indexed, scan_records

#: /clock publications per second of wall time between messages (ros2 bag play --clock's)
CLOCK_HZ = 40.0


@dataclass(frozen=True)
class Topic:
    """A recorded topic: its type, the QoS to offer (bag_qos) and how many messages."""

    name: str
    type_name: str
    qos: dict
    count: int


def recorded_topics(path: str | Path) -> dict[str, Topic]:
    """The file's topics: from the summary, or by a scan of a file not yet repaired."""
    channels: list[tuple[str, str, str]] = []
    counts: dict[str, int] = {}
    if is_indexed(path):
        with open(path, "rb") as fh:
            summary = make_reader(fh).get_summary()
        for cid, ch in summary.channels.items():
            schema = summary.schemas.get(ch.schema_id)
            channels.append((ch.topic, schema.name if schema else "",
                             ch.metadata.get("offered_qos_profiles", "")))
            counts[ch.topic] = counts.get(ch.topic, 0) + \
                summary.statistics.channel_message_counts.get(cid, 0)
    else:
        schemas: dict[int, str] = {}
        for record in scan_records(path):
            if isinstance(record, Schema):
                schemas[record.id] = record.name
            elif isinstance(record, Channel):
                channels.append((record.topic, schemas.get(record.schema_id, ""),
                                 record.metadata.get("offered_qos_profiles", "")))
    topics = {}
    for name, type_name, qos_text in channels:
        try:
            offered = bag_qos.parse(qos_text)
        except bag_qos.QosFormatError:
            offered = []
        topics[name] = Topic(name, type_name, bag_qos.playback_profile(offered),
                             counts.get(name, 0))
    return topics


def topic_name(text: str) -> str:
    """A topic as recorded: absolute ('memory/blocks' is '/memory/blocks')."""
    if not text.strip("/") or any(c.isspace() for c in text):
        raise argparse.ArgumentTypeError(f"expected a topic name, got {text!r}")
    return "/" + text.lstrip("/")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="katana-play", description="Play a recording (katana-run --record) back: every "
        "topic with its recorded type and QoS, and /clock, at the recorded timing.")
    parser.add_argument("file", type=readable_file, metavar="FILE.mcap",
                        help="the MCAP recording")
    parser.add_argument("--rate", type=positive_number, default=1.0,
                        help="playback speed, a multiple of the recorded (default 1)")
    parser.add_argument("--loop", action="store_true", help="play again from the start, "
                        "until stopped")
    parser.add_argument("--topics", type=topic_name, nargs="+", default=None, metavar="TOPIC",
                        help="play only these recorded topics (default: all)")
    parser.add_argument("--delay", type=non_negative_seconds, default=0.0,
                        help="wall seconds to wait before playing (each loop), so that "
                        "subscribers can connect (default 0)")
    parser.add_argument("--repair", action="store_true", help="only make a file left by a "
                        "killed recorder indexed (no playback)")
    return parser


def _repair_alone(args: argparse.Namespace) -> None:
    if args.repair:
        given = [opt for opt, on in (("--rate", args.rate != 1.0), ("--loop", args.loop),
                                     ("--topics", args.topics is not None),
                                     ("--delay", args.delay != 0.0)) if on]
        if given:
            raise CommandLineError(given[0], "not allowed with --repair (it plays nothing)")


def _an_mcap_file(args: argparse.Namespace) -> None:
    with open(args.file, "rb") as fh:
        if fh.read(8) != b"\x89MCAP0\r\n":
            raise CommandLineError("FILE.mcap", f"{args.file} is not an MCAP file")


def _known_topics(args: argparse.Namespace) -> None:
    if args.topics is None:
        return
    known = recorded_topics(args.file)
    unknown = [t for t in args.topics if t not in known]
    if unknown:
        raise CommandLineError("--topics", f"not recorded in {args.file}: "
                               f"{', '.join(unknown)}; recorded: {', '.join(sorted(known))}")


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line, every check done (exit 2 with the usage on a bad one)."""
    return parse_command_line(build_parser(), argv,
                              (_repair_alone, _an_mcap_file, _known_topics))


@dataclass(frozen=True)
class Recorded:
    """One message to play: its topic, recorded log time and CDR bytes."""

    topic: str
    log_time_ns: int
    data: bytes


def recorded_messages(path: str | Path, topics: Iterable[str] | None = None
                      ) -> Iterator[Recorded]:
    """The messages of an indexed file in log-time order (of `topics` only, if given)."""
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        for _schema, channel, message in reader.iter_messages(
                topics=list(topics) if topics is not None else None, log_time_order=True):
            yield Recorded(channel.topic, message.log_time, message.data)


def play(messages: Callable[[], Iterable[Recorded]], rate: float, loop: bool,
         publish: Callable[[Recorded], None], publish_clock: Callable[[int], None],
         now: Callable[[], float], wait_until: Callable[[float], bool],
         delay_s: float = 0.0, clock_hz: float = CLOCK_HZ) -> int:
    """Publish `messages()` at their recorded timing scaled by 1/rate, and the playback time
    (ns, on the recording's clock) on /clock at `clock_hz` of wall time and with each message.

    `now()` is wall seconds; `wait_until(t)` waits until now() >= t and returns False when
    playback must stop. Returns how many messages were published."""
    published = 0
    while True:
        if delay_s > 0.0 and not wait_until(now() + delay_s):
            return published
        start_wall: float | None = None
        start_ns = 0
        for msg in messages():
            if start_wall is None:
                start_wall, start_ns = now(), msg.log_time_ns
            due = start_wall + (msg.log_time_ns - start_ns) / 1e9 / rate
            while True:  # /clock ticks in the gap, then the message's own time
                tick = now() + 1.0 / clock_hz
                if tick >= due:
                    break
                if not wait_until(tick):
                    return published
                publish_clock(min(msg.log_time_ns,
                                  start_ns + int((now() - start_wall) * rate * 1e9)))
            if not wait_until(due):
                return published
            publish_clock(msg.log_time_ns)
            publish(msg)
            published += 1
        if not loop or start_wall is None:
            return published
