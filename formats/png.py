"""Images written a band of rows at a time, so a map of any size is never held whole: binary
PGM (P5, as Pillow writes it) and PNG (8-bit grey, grey + alpha or RGB; each row with the
"Sub" filter, deflate level 1)."""

from __future__ import annotations

import struct
import zlib
from typing import BinaryIO

import numpy as np

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_COLOUR_TYPE = {1: 0, 2: 4, 3: 2}  # channels → grey, grey + alpha, RGB
IDAT_BYTES = 1 << 16  # compressed data per IDAT chunk


class PgmWriter:
    """``P5`` with a maximum of 255; rows from the top, fed by :meth:`add`."""

    def __init__(self, f: BinaryIO, width: int, height: int) -> None:
        self.f = f
        f.write(f"P5\n{width} {height}\n255\n".encode("ascii"))

    def add(self, rows: np.ndarray) -> None:
        self.f.write(np.ascontiguousarray(rows, dtype=np.uint8).tobytes())


class PngWriter:
    """An 8-bit PNG of ``channels`` channels; rows from the top, fed by :meth:`add`, then
    :meth:`finish`."""

    def __init__(self, f: BinaryIO, width: int, height: int, channels: int,
                 level: int = 1) -> None:
        self.f, self.channels = f, channels
        self._deflate = zlib.compressobj(level)
        self._pending = b""
        f.write(PNG_SIGNATURE)
        self._chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8,
                                         PNG_COLOUR_TYPE[channels], 0, 0, 0))

    def _chunk(self, kind: bytes, data: bytes) -> None:
        self.f.write(struct.pack(">I", len(data)) + kind + data
                     + struct.pack(">I", zlib.crc32(kind + data)))

    def add(self, rows: np.ndarray) -> None:
        """Rows (n × width, or n × width × channels) of uint8."""
        flat = np.ascontiguousarray(rows, dtype=np.uint8).reshape(len(rows), -1)
        filtered = np.empty((len(flat), flat.shape[1] + 1), np.uint8)
        filtered[:, 0] = 1  # Sub: each byte less the byte one pixel to its left
        filtered[:, 1:1 + self.channels] = flat[:, :self.channels]
        np.subtract(flat[:, self.channels:], flat[:, :-self.channels],
                    out=filtered[:, 1 + self.channels:])
        self._emit(self._deflate.compress(filtered.tobytes()))

    def _emit(self, data: bytes) -> None:
        self._pending += data
        while len(self._pending) >= IDAT_BYTES:
            self._chunk(b"IDAT", self._pending[:IDAT_BYTES])
            self._pending = self._pending[IDAT_BYTES:]

    def finish(self) -> None:
        self._pending += self._deflate.flush()
        if self._pending:
            self._chunk(b"IDAT", self._pending)
        self._chunk(b"IEND", b"")
