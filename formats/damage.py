"""Damaged containers: the one place a container library's own exceptions on damaged data
(rosbags, mcap, zstd, sqlite, struct) become a one-line InputError naming the file."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from dynslam_cli.errors import InputError

_OURS = (str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parent.parent /
                                                  "dynslam_cli"))


def _raised_by_library(e: BaseException) -> bool:
    """Whether the innermost frame of ``e``'s traceback is outside dynslam (a container
    library's own error on damaged data, not a bug of ours)."""
    tb = e.__traceback__
    if tb is None:
        return False
    while tb.tb_next is not None:
        tb = tb.tb_next
    return not tb.tb_frame.f_code.co_filename.startswith(_OURS)


@contextmanager
def container_errors(name: str, what: str) -> Iterator[None]:
    """The one place a container library's exceptions (rosbags, mcap, zstd, sqlite, struct,
    ...) on damaged data become a one-line :class:`InputError` naming the file; its message
    is cut to its first line (some quote a whole message definition)."""
    try:
        yield
    except InputError:
        raise
    except Exception as e:
        if not (isinstance(e, UnicodeDecodeError | struct.error | EOFError)
                or _raised_by_library(e)):
            raise
        raise InputError(name, f"cannot read this {what}: {first_line(e)}") from None


def first_line(e: BaseException) -> str:
    """An exception's message cut to its first line (some quote a whole message definition),
    or its type's name when it has none (an ``AssertionError``)."""
    lines = str(e).strip().splitlines()
    return lines[0] if lines else type(e).__name__
