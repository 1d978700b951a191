"""MCAP files not written by rosbag2 (profile other than ``ros2``, e.g. ROS1 messages in
MCAP): read with the ``mcap`` package, messages decoded from their ``ros1msg`` schema with
rosbags' type system. MCAP files with the ``ros2`` profile go to the rosbags reader.

An MCAP file whose summary is missing or unreadable (cut off while recording: the summary
is written last) is read record after record in file order, whatever its profile (``cdr``
messages decoded from their ``ros2msg`` schema), up to the first record that cannot be read:
where that is is a counted warning."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

from dynslam_cli.errors import InputError, printable
from dynslam_cli.types import Scan
from dynslam_formats.base import ReaderOptions, ReadStats, RecordWalk
from dynslam_formats.damage import container_errors, first_line
from dynslam_formats.ros import MCAP_MAGIC, log_scans, tally, typestore_of
from dynslam_formats.source import Source

DEFINITION_ENCODINGS = ("ros1msg", "ros2msg")


def sniff(head: bytes) -> bool:
    return head.startswith(MCAP_MAGIC)


def _normalised(name: str) -> str:
    """ROS1 'pkg/Type' → 'pkg/msg/Type' as rosbags names types."""
    return name if "/msg/" in name else name.replace("/", "/msg/", 1)


def readable_summary(reader: Any) -> Any:
    """An MCAP file's summary; None when it has none, or it cannot be read (a file cut off
    while recording ends before it)."""
    try:
        return reader.get_summary()
    except Exception:  # (the mcap package's, on a damaged end: the records are read instead)
        return None


def stream_messages(path: Path, walk: RecordWalk) -> Iterator[tuple[Any, Any, Any]]:
    """An MCAP file's (schema, channel, message) in file order, read record after record
    without its summary, up to the first record that cannot be read (a channel naming a
    schema, or a message a channel, that no record before defines counts as such); ``walk``
    says how far it got and why it stopped early."""
    from mcap.exceptions import EndOfFile
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as f:
        records = StreamReader(f).records
        schemas: dict[int, Any] = {}
        channels: dict[int, Any] = {}
        while True:
            walk.stop = f.tell()
            try:
                record = next(records)
            except StopIteration:
                return
            except EndOfFile:
                walk.damage = "the file ends inside a record"
                return
            except Exception as e:  # (the mcap package's or a decompressor's, on damage)
                walk.damage = first_line(e)
                return
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                if record.schema_id != 0 and record.schema_id not in schemas:
                    walk.damage = (f"channel {printable(record.topic)} names schema "
                                   f"{record.schema_id}, which no record before defines")
                    return
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None:
                    walk.damage = (f"a message on channel {record.channel_id}, which no "
                                   "record before defines")
                    return
                walk.messages += 1
                yield schemas.get(channel.schema_id), channel, record


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
                reader = make_reader(f)
                profile = reader.get_header().profile
                summarised = readable_summary(reader) is not None
        except OSError as e:
            raise InputError(source.name, f"cannot read: {e.strerror}") from None
        if profile == "ros2" and summarised:
            from dynslam_formats.ros import RosbagsReader

            self._ros2 = RosbagsReader(source, options)
            self.stats = self._ros2.stats

    def scans(self) -> Iterator[Scan]:
        if self._ros2 is not None:
            yield from self._ros2.scans()
            self.topics = self._ros2.topics
            return
        from mcap.reader import make_reader

        with open(self.source.path, "rb") as f, container_errors(self.source.name,
                                                                  "MCAP file"):
            reader = make_reader(f)
            summary = readable_summary(reader)
            if summary is None:
                yield from self._stream_scans()
            else:
                yield from self._summary_scans(reader, summary)

    def _summary_scans(self, reader: Any, summary: Any) -> Iterator[Scan]:
        """The scans, the topics known from the summary, the messages in log time order."""
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        channels: dict[str, tuple[str, int]] = {}
        for cid, ch in summary.channels.items():
            schema = summary.schemas.get(ch.schema_id)
            if schema is None:  # (a damaged summary)
                raise InputError(self.source.name, f"cannot read this MCAP file: channel "
                                 f"{printable(ch.topic)} names schema {ch.schema_id}, which "
                                 "the file does not hold")
            tally(channels, ch.topic, _normalised(schema.name), counts.get(cid, 0))
        store = self._typestore(summary.schemas.values())

        def messages(wanted: set[str]) -> Iterator[tuple[str, str, Any]]:
            for schema, channel, message in reader.iter_messages(topics=sorted(wanted)):
                yield self._decoded(store, schema, channel, message)

        yield from log_scans(self, channels, messages)

    def _stream_scans(self) -> Iterator[Scan]:
        """The scans of a file without a usable summary: a first walk over its records finds
        the topics, a second decodes; where the records stop being readable is a warning."""
        name, path = self.source.name, Path(self.source.path)
        survey = RecordWalk()
        channels: dict[str, tuple[str, int]] = {}
        schemas: dict[int, Any] = {}
        for schema, channel, _ in stream_messages(path, survey):
            msgtype = _normalised(schema.name) if schema is not None else ""
            tally(channels, channel.topic, msgtype)
            if schema is not None:
                schemas[schema.id] = schema
        if survey.messages == 0 and survey.damage is not None:
            raise InputError(name, f"cannot read this MCAP file: no summary, and its records "
                             f"stop being readable at byte {survey.stop} ({survey.damage}); "
                             "'mcap recover' (the mcap CLI) may save what is left")
        survey.report(self.stats, self.source.size)
        store = self._typestore(schemas.values())

        def messages(wanted: set[str]) -> Iterator[tuple[str, str, Any]]:
            for schema, channel, message in stream_messages(path, RecordWalk()):
                if channel.topic in wanted:
                    yield self._decoded(store, schema, channel, message)

        yield from log_scans(self, channels, messages)

    @staticmethod
    def _typestore(schemas: Any) -> Any:
        """The types the file's ``ros1msg``/``ros2msg`` schemas define."""
        defined = [s for s in schemas if s.encoding in DEFINITION_ENCODINGS]
        return typestore_of({_normalised(s.name): s.data.decode() for s in defined},
                            ros2=any(s.encoding == "ros2msg" for s in defined))

    def _decoded(self, store: Any, schema: Any, channel: Any, message: Any
                 ) -> tuple[str, str, Any]:
        """(topic, message type, decoded message) of a ``ros1`` or ``cdr`` message."""
        msgtype = _normalised(schema.name) if schema is not None else ""
        if channel.message_encoding == "ros1":
            return channel.topic, msgtype, store.deserialize_ros1(message.data, msgtype)
        if channel.message_encoding == "cdr":
            return channel.topic, msgtype, store.deserialize_cdr(message.data, msgtype)
        raise InputError(self.source.name, f"topic {channel.topic}: message encoding "
                         f"{channel.message_encoding!r} is not supported")
