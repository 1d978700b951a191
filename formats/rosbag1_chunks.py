"""ROS 1 bags read chunk after chunk, without their index.

A ROS 1 bag (format 2.0) is a bag header record, then chunks (connection and message records,
maybe bz2 or lz4 compressed), each followed by index data records, then the index proper
(connection and chunk info records) from the header's ``index_pos``. A recorder that crashed
leaves no index (``index_pos`` 0) and maybe a last chunk cut short; an early 2.0 writer
declared its index data records' lengths wrong (``handheld-hokuyo-old-index.bag``): rosbags
refuses both, and ``rosbag reindex`` would rebuild the index from the chunks. This reads the
chunks themselves, in file order, up to the first record that cannot be read. The records are
parsed with rosbags' own record functions.
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from rosbags.rosbag1.reader import (
    Header,
    ReaderError,
    RecordType,
    decompressors,
    normalize,
    read_bytes,
    read_uint32,
)
from rosbags.typesys.msg import normalize_msgtype

from dynslam_formats.base import RecordWalk
from dynslam_formats.damage import first_line

ROSBAG_V2 = b"#ROSBAG V2.0\n"
INDEX_ENTRY_BYTES = 12  # time (8) and offset (4) of one message, in an index data record
# What damaged records raise: rosbags' own error, short or garbled fields, an unknown
# compression (KeyError), bz2 (OSError, ValueError) and lz4 (RuntimeError) on bad data.
DAMAGE = (ReaderError, struct.error, KeyError, ValueError, OSError, RuntimeError, EOFError)


@dataclass(frozen=True)
class BagConnection:
    """A connection record: the topic, its message type (normalised, ``pkg/msg/Type``) and
    the message definition the recorder wrote."""

    topic: str
    msgtype: str
    msgdef: str


def chunk_messages(path: Path, walk: RecordWalk) -> Iterator[tuple[BagConnection, bytes]]:
    """The (connection, serialized message) pairs of a ROS 1 bag's chunks in file order, up
    to its index or to the first record that cannot be read; ``walk`` says how far it got and
    why it stopped early. A bag whose header cannot be read raises ``ReaderError``."""
    with open(path, "rb") as f:
        end = _data_end(f, os.fstat(f.fileno()).st_size)
        connections: dict[int, BagConnection] = {}
        while (start := f.tell()) < end:
            walk.stop = start
            try:
                messages = _record_messages(f, connections)
            except DAMAGE as e:
                walk.damage = first_line(e)
                return
            walk.messages += len(messages)
            yield from messages
        walk.stop = end


def _data_end(f: BinaryIO, size: int) -> int:
    """Reads the magic line and the bag header record; the byte where the chunks end (where
    the index starts, or the file's end when the header names no index inside the file)."""
    if f.readline() != ROSBAG_V2:
        raise ReaderError("not a ROS 1 bag of format 2.0")
    header = Header.read(f, RecordType.BAGHEADER)
    read_bytes(f, read_uint32(f))  # (padding)
    index_pos = header.get_uint64("index_pos")
    return index_pos if f.tell() < index_pos <= size else size


def _record_messages(src: BinaryIO, connections: dict[int, BagConnection]
                     ) -> list[tuple[BagConnection, bytes]]:
    """The messages one record holds (a chunk: those of the records inside it), learning the
    connections records define on the way; other records hold none."""
    header = Header.read(src)
    op = header.get_uint8("op")
    if op == RecordType.CONNECTION:
        about = Header.read(src)  # (its data is in the form of a header)
        connections[header.get_uint32("conn")] = BagConnection(
            normalize(header.get_string("topic")), normalize_msgtype(about.get_string("type")),
            about.get_string("message_definition"))
        return []
    size = read_uint32(src)
    if op == RecordType.IDXDATA and header.get_uint32("ver") == 1:
        size = INDEX_ENTRY_BYTES * header.get_uint32("count")  # (what the entries take)
    data = read_bytes(src, size)
    if op == RecordType.MSGDATA:
        conn = header.get_uint32("conn")
        if conn not in connections:
            raise ReaderError(f"a message on connection {conn}, which no record before defines")
        return [(connections[conn], data)]
    if op != RecordType.CHUNK:
        return []
    records = decompressors[header.get_string("compression")](data)
    chunk = io.BytesIO(records)
    messages = []
    while chunk.tell() < len(records):
        messages += _record_messages(chunk, connections)
    return messages
