"""A minimal reader plugin, as a lab would ship it in its own package (see README):
one scan a line, ``stamp x y theta max_range angle_min angle_step r1 r2 ...``."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from dynslam_cli.errors import InputError
from dynslam_cli.types import Pose2D, Scan
from dynslam_formats import ReaderEntry, ReaderOptions, ReadStats, Source
from dynslam_formats.source import text_lines


class LineScanReader:
    format_name = "linescan"

    def __init__(self, source: Source, options: ReaderOptions) -> None:
        self.source, self.stats = source, ReadStats()

    def scans(self) -> Iterator[Scan]:
        for lineno, line, _ in text_lines(self.source):
            if not line.strip() or line.startswith("%"):
                continue
            try:
                v = np.array(line.split(), dtype=float)
            except ValueError:
                raise InputError(self.source.name, "not a number", lineno) from None
            n = len(v) - 7
            self.stats.scans += 1
            yield Scan(v[0], v[7:], v[5] + v[6] * np.arange(n), v[4], Pose2D(*v[1:4]),
                       source_line=lineno)


ENTRY = ReaderEntry("linescan", "one scan a line (example plugin)", (".linescan",),
                    lambda head: head.startswith(b"%linescan"),
                    lambda source, options: LineScanReader(source, options))
