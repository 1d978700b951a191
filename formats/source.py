"""Opening an input: a file (gzip, bzip2 or xz by magic bytes or suffix), a folder (a bag), or
standard input; and a text log's lines, read to where its compressed data stops being
readable."""

from __future__ import annotations

import bz2
import io
import lzma
import os
import stat
import sys
import zlib
from collections.abc import Callable, Iterator
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from dynslam_cli.errors import InputError
from dynslam_formats.base import ReadStats

SNIFF_BYTES = 65536
BINARY_SNIFF_BYTES = 8000  # a NUL byte among the first this many: binary (as git and grep)
MAX_LINE_CHARS = 4_000_000  # a text log's line: 20000 beams with remissions fit 10 times


@dataclass(frozen=True)
class Compression:
    """A compression a text log may come in, read by Python's standard library."""

    name: str
    suffix: str
    magic: bytes
    decompressor: Callable[[], Any]
    """A new incremental decompressor (``decompress(data, max_length)``), for the head."""
    opener: Callable[[BinaryIO], BinaryIO]
    """The decompressed stream of a binary file object."""
    damaged: tuple[type[Exception], ...]
    """What its decompressor or stream raises on damaged or truncated data (gzip's stream
    raises nothing: it ends where the damage starts and says where,
    :class:`GzipUntilDamaged`)."""


COMPRESSIONS = (
    Compression("gzip", ".gz", b"\x1f\x8b", lambda: zlib.decompressobj(GZIP_WBITS),
                lambda raw: io.BufferedReader(GzipUntilDamaged(raw), GZIP_PIECE),  # type: ignore[return-value]
                (zlib.error,)),
    Compression("bzip2", ".bz2", b"BZh", bz2.BZ2Decompressor,
                lambda raw: bz2.BZ2File(raw),  # type: ignore[return-value]
                (EOFError, OSError)),  # ("Invalid data stream" is an OSError)
    Compression("xz", ".xz", b"\xfd7zXZ\x00", lzma.LZMADecompressor,
                lambda raw: lzma.LZMAFile(raw),  # type: ignore[return-value]  # noqa: SIM115
                (EOFError, lzma.LZMAError)),
)


COMPRESSED_SUFFIXES = tuple(c.suffix for c in COMPRESSIONS)


def compression_of(head: bytes, path: str) -> Compression | None:
    """The compression whose magic bytes start ``head``, else whose suffix ends ``path``."""
    return (next((c for c in COMPRESSIONS if head.startswith(c.magic)), None)
            or next((c for c in COMPRESSIONS if path.endswith(c.suffix)), None))


GZIP_WBITS = zlib.MAX_WBITS | 16  # a gzip header and trailer around the deflate stream
GZIP_PIECE = 16384  # compressed bytes fed at a time: the damage is found within this many


class GzipUntilDamaged(io.RawIOBase):
    """A gzip file's decompressed bytes up to where its compressed data ends early (a log cut
    off while written: a robot that crashed) or stops being readable (a bad copy). There the
    stream ends as if the file did, and :attr:`damage` says where and why. Members written
    one after another read as one stream, and zero bytes after a member are padding, as
    ``gzip.GzipFile`` reads them; anything else after a member is damage."""

    def __init__(self, raw: BinaryIO) -> None:
        super().__init__()
        self._raw = raw
        self._member = zlib.decompressobj(GZIP_WBITS)
        self._pending = b""
        self._offset = 0  # compressed bytes read so far
        self._ended = False
        self.damage: str | None = None

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: bytearray | memoryview) -> int:  # type: ignore[override]
        while not self._pending and not self._ended:
            self._pending = self._inflate_more()
        n = min(len(buffer), len(self._pending))
        buffer[:n] = self._pending[:n]
        self._pending = self._pending[n:]
        return n

    def _inflate_more(self) -> bytes:
        """The next decompressed bytes (maybe none yet); at the end, or at damage, none and
        ``_ended`` set."""
        member = self._member
        if member.eof:  # a member ended: zero padding, then maybe a next member
            data = member.unused_data.lstrip(b"\0")
            while not data and (piece := self._read()):
                data = piece.lstrip(b"\0")
            if not data:
                self._ended = True
                return b""
            member = self._member = zlib.decompressobj(GZIP_WBITS)
        else:
            data = member.unconsumed_tail or self._read()
            if not data:
                self._ended = True
                self.damage = (f"compressed data ends at byte {self._offset} before its "
                               "end-of-stream marker (cut off while written?): read up to there")
                return b""
        try:
            return member.decompress(data, GZIP_PIECE * 4)
        except zlib.error as e:
            self._ended = True  # (data is a tail of what was read: it starts here)
            self.damage = (f"compressed data damaged between bytes {self._offset - len(data)} "
                           f"and {self._offset} ({e}): read up to there")
            return b""

    def _read(self) -> bytes:
        piece = self._raw.read(GZIP_PIECE)
        self._offset += len(piece)
        return piece


class Source:
    """An input: a path (gzip, bzip2 or xz by magic bytes or suffix: :data:`COMPRESSIONS`)
    or ``-`` for standard input.

    ``head`` holds the first (decompressed) bytes for format sniffing; :meth:`open` returns a
    binary stream positioned at the start. :meth:`progress` reports compressed bytes consumed.
    """

    def __init__(self, path: str) -> None:
        self.path = path
        self.name = "<stdin>" if path == "-" else path
        self._opened: BinaryIO | None = None  # the decompressed stream, once opened
        if path == "-":
            stdin = sys.stdin.buffer
            self._raw: BinaryIO = io.BufferedReader(getattr(stdin, "raw", stdin), 1 << 20)
            self.size = 0
        else:
            p = Path(path)
            try:  # stat first: a folder is a bag; a missing or unreadable path says why
                if stat.S_ISDIR(p.stat().st_mode):
                    self._raw = None  # type: ignore[assignment]
                    self.size = 0
                    self.compression: Compression | None = None
                    self.head = b""
                    return
                self._raw = open(p, "rb")  # noqa: SIM115 - closed by close()
                self.size = os.fstat(self._raw.fileno()).st_size
            except OSError as e:
                raise InputError(self.name, f"cannot open: {e.strerror}") from None
        self.compression = compression_of(self._raw.peek(SNIFF_BYTES), path)
        self.head = self._peek_head()

    @property
    def is_dir(self) -> bool:
        return self._raw is None

    @property
    def plain_path(self) -> str:
        """The path without its compression's suffix (``run.log.bz2``: ``run.log``)."""
        c = self.compression
        return self.path.removesuffix(c.suffix) if c is not None else self.path

    def _peek_head(self) -> bytes:
        data = self._raw.peek(SNIFF_BYTES)
        c = self.compression
        if c is None:
            return data[:SNIFF_BYTES]
        decompressor = c.decompressor()
        try:
            head = decompressor.decompress(data, SNIFF_BYTES)
        except c.damaged:
            raise InputError(self.name, f"not a valid {c.name} file") from None
        if not head and data and len(data) == self.size and not decompressor.eof:
            raise InputError(self.name, f"{c.name} data damaged or cut short before its "
                             "first readable bytes")
        return head

    def open(self) -> BinaryIO:
        """The (decompressed) byte stream. A gzip stream ends where its compressed data
        stops being readable; :attr:`damage` then says where and why."""
        c = self.compression
        if c is None:
            return self._raw
        self._opened = c.opener(self._raw)
        return self._opened

    @property
    def damage(self) -> str | None:
        """Where and why a gzip source's compressed data stopped being readable (None: it
        did not, or the source is not gzip)."""
        return getattr(getattr(self._opened, "raw", None), "damage", None)

    def progress(self) -> tuple[int, int]:
        """(bytes consumed, total bytes) of the file on disk; total 0 when unknown."""
        if self.size == 0 or self._raw is None:
            return 0, 0
        try:
            return self._raw.tell(), self.size
        except (OSError, ValueError):
            return 0, self.size

    def close(self) -> None:
        if self._raw is not None and self.path != "-":
            self._raw.close()


def read_text_lines(path: Path | str) -> list[str]:
    """All lines of a small text file (TUM, relations); unreadable or binary is an error."""
    try:
        return Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise InputError(str(path), f"cannot read: {e.strerror}") from None
    except UnicodeDecodeError:
        raise InputError(str(path), "not a text file") from None


def text_lines(source: Source, stats: ReadStats | None = None
               ) -> Iterator[tuple[int, str, bool]]:
    """(line number, line without its end, whether the line was terminated) for a text log.

    Decoding errors are replaced, never fatal. A compressed stream cut short or damaged ends
    the lines where it stops being readable (gzip's: the line it stops in comes
    unterminated; bzip2's and xz's: the lines their decoder had given): a counted warning in
    ``stats`` saying where, or an :class:`InputError` without ``stats``. Binary data (a NUL
    byte in the first ``BINARY_SNIFF_BYTES``: an image, a program, a bag read with
    ``--format carmen``) and a line longer than ``MAX_LINE_CHARS`` (``/dev/zero``) are an
    :class:`InputError`.
    """
    if b"\0" in source.head[:BINARY_SNIFF_BYTES]:
        raise InputError(source.name, "not a text log: binary data (NUL bytes) near the start")
    damaged = source.compression.damaged if source.compression is not None else ()
    stream = io.TextIOWrapper(source.open(), encoding="utf-8", errors="replace", newline=None)
    lineno, terminated = 0, True
    try:
        while line := stream.readline(MAX_LINE_CHARS + 1):
            lineno += 1
            terminated = line.endswith("\n")
            if terminated:
                yield lineno, line[:-1], True
            elif len(line) > MAX_LINE_CHARS:
                raise InputError(source.name, f"a line longer than {MAX_LINE_CHARS} characters: "
                                 "not a text log?", lineno)
            else:
                yield lineno, line, False
        if source.damage is not None:
            where = lineno + terminated  # the line the damage cuts short, or the next
            if stats is None:
                raise InputError(source.name, source.damage, where)
            stats.warn(source.damage, where)
    except damaged as e:  # bzip2, xz: the lines before it were read
        message = f"compressed data is damaged or truncated ({e}): read up to there"
        if stats is None:
            raise InputError(source.name, message, lineno + 1) from None
        stats.warn(message, lineno + 1)
    finally:  # the source owns the file (and closes it): let go of it, leave it open
        with suppress(ValueError):  # (already closed by the source)
            stream.detach()
