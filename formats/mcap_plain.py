"""MCAP files not written by rosbag2 (profile other than ``ros2``, e.g. ROS1 messages in
MCAP): read with the ``mcap`` package, messages decoded from their ``ros1msg`` schema with
rosbags' type system. MCAP files with the ``ros2`` profile go to the rosbags reader."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, ClassVar

from dynslam_cli.errors import InputError, printable
from dynslam_cli.types import Scan
from dynslam_formats.base import ReaderOptions, ReadStats, Source, container_errors
from dynslam_formats.ros import MCAP_MAGIC, TF_TYPES, RosMessages, choose_topics


def sniff(head: bytes) -> bool:
    return head.startswith(MCAP_MAGIC)


def _normalised(name: str) -> str:
    """ROS1 'pkg/Type' → 'pkg/msg/Type' as rosbags names types."""
    return name if "/msg/" in name else name.replace("/", "/msg/", 1)


class McapReader:
    format_name: ClassVar[str] = "mcap"

    def __init__(self, source: Source, options: ReaderOptions) -> None:
        self.source = source
        self.options = options
        self.stats = ReadStats()
        self._ros2 = None
        self.topics: tuple[str | None, str | None] | None = None
        if source.path == "-":
            raise InputError(source.name, "MCAP files cannot be read from standard input")
        from mcap.reader import make_reader

        try:
            with open(source.path, "rb") as f, container_errors(source.name, "MCAP file"):
                profile = make_reader(f).get_header().profile
        except OSError as e:
            raise InputError(source.name, f"cannot read: {e.strerror}") from None
        if profile == "ros2":
            from dynslam_formats.ros import RosbagsReader

            self._ros2 = RosbagsReader(source, options)
            self.stats = self._ros2.stats

    def scans(self) -> Iterator[Scan]:
        if self._ros2 is not None:
            yield from self._ros2.scans()
            self.topics = self._ros2.topics
            return
        from mcap.reader import make_reader

        name = self.source.name
        with open(self.source.path, "rb") as f, container_errors(name, "MCAP file"):
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                raise InputError(name, "MCAP file has no summary (truncated?)")
            yield from self._read(reader, summary)

    def _read(self, reader: Any, summary: Any) -> Iterator[Scan]:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        types, channels = {}, {}
        for cid, ch in summary.channels.items():
            schema = summary.schemas.get(ch.schema_id)
            if schema is None:  # (a damaged summary)
                raise InputError(self.source.name, f"cannot read this MCAP file: channel "
                                 f"{printable(ch.topic)} names schema {ch.schema_id}, which "
                                 "the file does not hold")
            types[ch.topic] = _normalised(schema.name)
            channels[ch.topic] = (types[ch.topic], counts.get(cid, 0))
            self.stats.records[f"{ch.topic} ({types[ch.topic]})"] += counts.get(cid, 0)
        name = self.source.name
        scan_topic, odom_topic = choose_topics(channels, self.options, name)
        self.topics = (scan_topic, odom_topic)
        store = get_typestore(Stores.EMPTY)
        for schema in summary.schemas.values():
            if schema.encoding != "ros1msg":
                continue
            store.register(get_types_from_msg(schema.data.decode(), _normalised(schema.name)))
        handler = RosMessages(self.stats, scan_topic, odom_topic, name)
        wanted = [t for t, m in types.items()
                  if t in (scan_topic, odom_topic) or m in TF_TYPES]
        for schema, channel, message in reader.iter_messages(topics=wanted):
            if channel.message_encoding != "ros1":
                raise InputError(name, f"topic {channel.topic}: message encoding "
                                 f"{channel.message_encoding!r} is not supported")
            msgtype = _normalised(schema.name)
            msg = store.deserialize_ros1(message.data, msgtype)
            yield from handler.feed(channel.topic, msgtype, msg)
        yield from handler.finish()
        if self.stats.scans == 0:
            raise InputError(name, f"no scans on {scan_topic}")
