"""What every reader shares: opening a source, the reader interface, counted skips."""

from __future__ import annotations

import gzip
import io
import sys
import zlib
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, ClassVar, Protocol

from dynslam_cli.errors import InputError
from dynslam_cli.types import Scan

GZIP_MAGIC = b"\x1f\x8b"
SNIFF_BYTES = 65536


@dataclass(frozen=True)
class ReaderOptions:
    """Reader choices a user can make on the command line."""

    laser: str = "front"
    """Which laser: Carmen ``front``/``rear``/``3``/``4``; Player a device index."""
    topic: str | None = None
    """ROS: the LaserScan topic (needed when a bag has several)."""
    fov_deg: float | None = None
    """Field of view for records that carry no beam angles (old Carmen FLASER)."""


@dataclass
class ReadStats:
    """Counts of what a reader saw, skipped and warned about, for summary.json and stderr."""

    records: Counter[str] = field(default_factory=Counter)
    skipped: Counter[str] = field(default_factory=Counter)
    warnings: Counter[str] = field(default_factory=Counter)
    first_line: dict[str, int] = field(default_factory=dict)
    scans: int = 0

    def skip(self, reason: str, line: int = 0) -> None:
        """A record was dropped for ``reason`` (counted, reported once with its first line)."""
        self.skipped[reason] += 1
        self.first_line.setdefault(reason, line)

    def warn(self, reason: str, line: int = 0, count: int = 1) -> None:
        """Something odd that did not drop a record (counted, reported once)."""
        self.warnings[reason] += count
        self.first_line.setdefault(reason, line)

    def to_dict(self) -> dict[str, object]:
        return {
            "records": dict(sorted(self.records.items())),
            "scans": self.scans,
            "skipped": dict(sorted(self.skipped.items())),
            "warnings": dict(sorted(self.warnings.items())),
            "first_line": dict(sorted(self.first_line.items())),
        }


class Source:
    """An input: a path (gzip by suffix or magic bytes) or ``-`` for standard input.

    ``head`` holds the first (decompressed) bytes for format sniffing; :meth:`open` returns a
    binary stream positioned at the start. :meth:`progress` reports compressed bytes consumed.
    """

    def __init__(self, path: str) -> None:
        self.path = path
        self.name = "<stdin>" if path == "-" else path
        if path == "-":
            stdin = sys.stdin.buffer
            self._raw: BinaryIO = io.BufferedReader(getattr(stdin, "raw", stdin), 1 << 20)
            self.size = 0
        else:
            p = Path(path)
            if p.is_dir():
                self._raw = None  # type: ignore[assignment]
                self.size = 0
                self.gzipped = False
                self.head = b""
                return
            try:
                self._raw = open(p, "rb")  # noqa: SIM115 - closed by close()
            except OSError as e:
                raise InputError(self.name, f"cannot open: {e.strerror}") from None
            self.size = p.stat().st_size
        magic = self._raw.peek(2)[:2] if hasattr(self._raw, "peek") else b""
        self.gzipped = magic == GZIP_MAGIC or path.endswith(".gz")
        self.head = self._peek_head()

    @property
    def is_dir(self) -> bool:
        return self._raw is None

    def _peek_head(self) -> bytes:
        data = self._raw.peek(SNIFF_BYTES)
        if not self.gzipped:
            return data[:SNIFF_BYTES]
        try:
            return zlib.decompressobj(zlib.MAX_WBITS | 16).decompress(data, SNIFF_BYTES)
        except zlib.error:
            raise InputError(self.name, "not a valid gzip file") from None

    def open(self) -> BinaryIO:
        """The (decompressed) byte stream."""
        if self.gzipped:
            return gzip.GzipFile(fileobj=self._raw, mode="rb")  # type: ignore[return-value]
        return self._raw

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


def text_lines(source: Source) -> Iterator[tuple[int, str, bool]]:
    """(line number, line without its end, whether the line was terminated) for a text log.

    Decoding errors are replaced, never fatal; a damaged gzip stream is an :class:`InputError`.
    """
    stream = io.TextIOWrapper(source.open(), encoding="utf-8", errors="replace", newline=None)
    lineno = 0
    try:
        for lineno, line in enumerate(stream, 1):
            if line.endswith("\n"):
                yield lineno, line[:-1], True
            else:
                yield lineno, line, False
    except (EOFError, gzip.BadGzipFile, zlib.error) as e:
        raise InputError(source.name, f"compressed data is damaged or truncated ({e})",
                         lineno + 1) from None


class LogReader(Protocol):
    """The interface every reader plugin implements.

    A reader is built from a :class:`Source` and :class:`ReaderOptions`, yields :class:`Scan`
    records in time order from :meth:`scans` (streaming: memory must not grow with the log),
    and counts what it skipped in ``stats``. Bad input raises :class:`InputError`.
    """

    format_name: ClassVar[str]
    stats: ReadStats

    def scans(self) -> Iterator[Scan]: ...
