"""Reading and measuring ahead: the log's scans, each with what the filter measures from it
alone (dynslam_cli.localization.frontend), read and measured in a second process.

Reading the log and measuring depend on nothing the filter, the pose graph or the maps
compute, so on Linux (:func:`can_fork`) :class:`ForkedFrontEnd` does both in a forked child
process on another core and sends the scans with their measurements through a pipe, in log
order, a batch at a time, which a thread of this process takes off the pipe as they come;
this process runs the rest. The results are those of one process,
byte for byte. An error in the child (a malformed line, say) is raised here once the scans
before it have been processed, as it would be without the child. :class:`FrontEnd` does the
same work in this process.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import queue
import signal
import sys
import threading
import traceback
from collections import deque
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, BinaryIO

from dynslam_cli.errors import DynslamError
from dynslam_cli.localization.frontend import Measurement, ScanMeasurer
from dynslam_cli.types import Scan

if TYPE_CHECKING:
    from dynslam_formats.base import LogReader, ReadStats
    from dynslam_formats.source import Source

BATCH = 16  # scans per message from the child
PIPE_BYTES = 1 << 20
QUEUE_BATCHES = 64  # messages taken off the pipe ahead of their use (1024 scans)


class FrontEnd:
    """The scans of ``reader``, each with what ``measure`` makes of it, in this process.
    Iterate :meth:`scans`; :meth:`measurement` gives the measurement of the scan last
    yielded, :meth:`progress` the bytes read so far and ``stats`` the reader's counts."""

    def __init__(self, reader: LogReader, source: Source, measure: ScanMeasurer) -> None:
        self._reader = reader
        self._source = source
        self._measure = measure
        self._scan: Scan | None = None
        self._measurement: Measurement | None = None

    @property
    def stats(self) -> ReadStats:
        return self._reader.stats

    def scans(self) -> Iterator[Scan]:
        for scan in self._reader.scans():
            self._scan, self._measurement = scan, self._measure(scan)
            yield scan

    def measurement(self, scan: Scan) -> Measurement:
        assert scan is self._scan and self._measurement is not None, "not the last scan"
        return self._measurement

    def progress(self) -> tuple[int, int]:
        return self._source.progress()

    def close(self) -> None:
        pass


class ForkedFrontEnd:
    """:class:`FrontEnd` in a forked child process, running ahead (same interface). Call
    :meth:`close` when done: it stops the child if it is still running."""

    def __init__(self, reader: LogReader, source: Source, measure: ScanMeasurer) -> None:
        self.stats: ReadStats = reader.stats
        self._progress = (0, 0)
        self._scans: list[Scan] = []
        self._measurements: list[Measurement] = []
        self._next = 0
        read_end, write_end = os.pipe()
        _widen(write_end)
        try:
            self._pid = os.fork()
        except OSError:
            os.close(read_end)
            os.close(write_end)
            raise
        self._running = True
        if self._pid == 0:  # the child: never returns
            os.close(read_end)
            _child(FrontEnd(reader, source, measure), write_end)
        os.close(write_end)
        self._pipe: BinaryIO | None = os.fdopen(read_end, "rb")
        self._batches: queue.Queue[tuple[str, Any]] = queue.Queue(QUEUE_BATCHES)
        self._stop = threading.Event()
        self._drain = threading.Thread(target=self._drain_pipe, args=(self._pipe,),
                                       name="dynslam-read-ahead", daemon=True)
        self._drain.start()

    def _drain_pipe(self, pipe: BinaryIO) -> None:
        """Take the child's messages off the pipe as they come, into a queue of
        QUEUE_BATCHES (this thread): while this process is busy elsewhere (placing the log
        in a prior map, a loop closure), the child goes on rather than wait on a full pipe.
        Ends after the last message, or ("eof", None) if the child ended without one."""
        while True:
            try:
                message = pickle.load(pipe)
            except Exception:  # EOFError, or a message cut off: the child has gone
                message = ("eof", None)
            while not self._stop.is_set():
                try:
                    self._batches.put(message, timeout=0.1)
                    break
                except queue.Full:
                    continue
            if message[0] != "scans" or self._stop.is_set():
                return

    def scans(self) -> Iterator[Scan]:
        while True:
            kind, payload = self._batches.get()
            if kind == "eof":
                raise RuntimeError(f"the front-end process ended unexpectedly "
                                   f"({self._reap()})")
            if kind == "scans":
                scans, self._measurements, self._progress = payload
                self._scans = scans
                for self._next, scan in enumerate(scans):
                    yield scan
            elif kind == "end":
                self.stats = payload
                return
            else:
                raise payload

    def measurement(self, scan: Scan) -> Measurement:
        assert scan is self._scans[self._next], "not the last scan"
        return self._measurements[self._next]

    def progress(self) -> tuple[int, int]:
        return self._progress

    def close(self) -> None:
        """Stop the child if it still runs, and the thread that takes its messages (it
        ends on the pipe's end), then close the pipe: no thread is left running."""
        self._stop.set()
        if self._running:
            with contextlib.suppress(ProcessLookupError):  # stopped, if it still runs
                os.kill(self._pid, signal.SIGKILL)
            self._reap()
        self._drain.join()
        if self._pipe is not None:
            self._pipe.close()
            self._pipe = None

    def _reap(self) -> str:
        """Wait for the child to end (once: its process id may be reused after)."""
        self._running = False
        _, status = os.waitpid(self._pid, 0)
        return f"wait status {status}"


def _child(front: FrontEnd, fd: int) -> None:
    """Run the front end, sending batches of (scans, measurements, progress), then ("end",
    stats) or ("error", exception); exit without running the parent's clean-up."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    code = 0
    scans: list[Scan] = []
    measurements: list[Measurement] = []
    try:
        with os.fdopen(fd, "wb") as pipe:
            try:
                for scan in front.scans():
                    scans.append(scan)
                    measurements.append(front.measurement(scan))
                    if len(scans) == BATCH:
                        _send(pipe, "scans", (scans, measurements, front.progress()))
                        scans, measurements = [], []
                end: tuple[str, object] = ("end", front.stats)
            except Exception as e:
                end = ("error", _picklable(e))
            if scans:  # the scans before the end (or the error)
                _send(pipe, "scans", (scans, measurements, front.progress()))
            _send(pipe, *end)
    except BaseException:  # the parent has gone (broken pipe) or the child was stopped
        code = 1
    finally:
        os._exit(code)


def _widen(fd: int) -> None:
    """Let the pipe hold ~300 scans (1 MiB; 64 KiB by default): the child can then run
    ahead through the stretches where this process is slow (loop closures) and need not
    fall behind where it is fast. Where pipes cannot be resized, the default it is."""
    with contextlib.suppress(ImportError, AttributeError, OSError):
        import fcntl  # (POSIX only)

        fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, PIPE_BYTES)  # (Linux only)


def _send(pipe: BinaryIO, kind: str, payload: object) -> None:
    pickle.dump((kind, payload), pipe, protocol=pickle.HIGHEST_PROTOCOL)
    pipe.flush()


def _picklable(e: Exception) -> Exception:
    """The exception, cut from its chain (the cause, a library's own exception, may not
    pickle); a RuntimeError with its text if it still does not pickle. An unexpected error
    (not the user's input: see dynslam_cli.errors) gets the child's traceback as a note."""
    where = "".join(traceback.format_exception(e))
    e.__cause__ = e.__context__ = e.__traceback__ = None
    try:
        pickle.loads(pickle.dumps(e))
    except Exception:
        e = RuntimeError(f"{type(e).__name__}: {e}")
    if not isinstance(e, DynslamError):
        e.add_note("in the front-end process:\n" + where)
    return e


class Rewound:
    """A front end whose first scans are taken before the run (to place the log in a prior
    map from them, :meth:`take`): :meth:`scans` yields those again with their measurements,
    then the rest, so the log is read and measured once. Same interface as the front end."""

    def __init__(self, front: FrontEnd | ForkedFrontEnd) -> None:
        self._front = front
        self._scans = front.scans()
        self._taken: deque[tuple[Scan, Measurement]] = deque()
        self._replayed: tuple[Scan, Measurement] | None = None

    @property
    def stats(self) -> ReadStats:
        return self._front.stats

    def take(self) -> Iterator[tuple[Scan, Measurement]]:
        """The scans from the log's start with their measurements, each kept to be yielded
        again by :meth:`scans` (call before it; stop taking at any scan)."""
        for scan in self._scans:
            taken = (scan, self._front.measurement(scan))
            self._taken.append(taken)
            yield taken

    def scans(self) -> Iterator[Scan]:
        while self._taken:
            self._replayed = self._taken.popleft()
            yield self._replayed[0]
        self._replayed = None
        yield from self._scans

    def measurement(self, scan: Scan) -> Measurement:
        if self._replayed is not None:
            assert scan is self._replayed[0], "not the last scan"
            return self._replayed[1]
        return self._front.measurement(scan)

    def progress(self) -> tuple[int, int]:
        return self._front.progress()

    def close(self) -> None:
        self._front.close()


def open_front_end(reader: LogReader, source: Source, measure: ScanMeasurer,
                   read_ahead: bool = True) -> FrontEnd | ForkedFrontEnd:
    """A :class:`ForkedFrontEnd` if ``read_ahead`` and it can be used, else a
    :class:`FrontEnd`."""
    if read_ahead and can_fork():
        with contextlib.suppress(OSError):  # no process to spare (a ulimit): work here
            return ForkedFrontEnd(reader, source, measure)
    return FrontEnd(reader, source, measure)


def can_fork() -> bool:
    """Whether :class:`ForkedFrontEnd` may be used: on Linux (macOS system libraries are not
    safe to use in a forked child; Windows cannot fork), in a process that runs no other
    Python thread (a Dask worker's, say) that the child would inherit in mid-work."""
    if not sys.platform.startswith("linux"):
        return False
    threading = sys.modules.get("threading")
    return threading is None or threading.active_count() == 1
