"""One log through the whole tool: read, run the pipeline, write the output folder
atomically; and an output folder scored. Used by ``dynslam process`` (with a progress bar),
``dynslam evaluate`` and ``dynslam batch`` (in worker processes or on a Dask cluster), so
all honour the same output contract and score it alike; and a run that takes the maps at
given times, for the benches that score change detection."""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import statistics
import sys
import time
from array import array
from collections.abc import Callable, Iterable
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from dynslam_cli import __version__
from dynslam_cli.config import Config
from dynslam_cli.localization.beams import (
    CHECK_SCANS,
    SpacingCheck,
    check_spacing,
    converter_spacing,
)
from dynslam_cli.localization.frontend import ScanMeasurer
from dynslam_cli.mapping.changes import KINDS
from dynslam_cli.mapping.grid import OccupancyMap
from dynslam_cli.pipeline import DynamicSlam, run
from dynslam_cli.prior import PriorMap, PriorSession
from dynslam_cli.readahead import ForkedFrontEnd, FrontEnd, Rewound, open_front_end
from dynslam_cli.result import SlamResult
from dynslam_cli.types import Pose2D, Scan
from dynslam_formats.source import COMPRESSED_SUFFIXES

LOG_SUFFIXES = (*COMPRESSED_SUFFIXES, ".clf", ".log", ".gfs", ".bag", ".db3", ".mcap")


def default_output(log: str) -> Path:
    """``./<log stem>_dynslam`` for a log path (``stdin_dynslam`` for ``-``)."""
    if log == "-":
        return Path("stdin_dynslam")
    name = Path(log.rstrip("/")).name
    changed = True
    while changed:
        changed = False
        for suffix in LOG_SUFFIXES:
            if name.endswith(suffix) and len(name) > len(suffix):
                name, changed = name[: -len(suffix)], True
    return Path(f"{name}_dynslam")


def process_log(log: str, target: Path, force: bool, options: Any, config: Config,
                format_name: str | None = None, snapshot_every: float | None = None,
                on_progress: Callable[[int, int, int], None] | None = None,
                read_ahead: bool = True,
                on_phase: Callable[[str, int, int], None] | None = None,
                prior: PriorSession | None = None) -> tuple[dict[str, Any], Any]:
    """Process ``log`` into ``target``; returns (summary, the reader's ReadStats).
    ``on_progress(bytes_done, bytes_total, scans)`` is called every few scans, then
    ``on_phase(what, done, total)`` through the final work. ``read_ahead``: read
    and measure the scans in a second process (on Linux; see dynslam_cli.readahead);
    ``prior``: start from an earlier session's map (see :func:`open_prior`)."""
    from dynslam_formats import open_log
    from dynslam_formats.guard import timed_by_order
    from dynslam_formats.outdir import (
        OUTPUT_FILES,
        atomic_output_dir,
        atomic_output_file,
        recording_destination,
        write_results,
    )
    from dynslam_formats.picture import SnapshotWriter
    from dynslam_formats.recording import Recording
    from dynslam_formats.tum import clock_stopped

    start = time.perf_counter()
    spacing = None
    if log != "-" and options.beam_step_deg is None and config.laser.check_beam_step:
        spacing = checked_spacing(log, options, format_name, config, on_phase)
        if spacing is not None and spacing.convincing:
            options = dataclasses.replace(options, beam_step_deg=math.degrees(spacing.own))
    elsewhere = (recording_destination(config.record.file, target) if config.record.file
                 else None)
    source, entry, reader = open_log(log, options, format_name)
    with (atomic_output_file(elsewhere, force, log) if elsewhere else nullcontext()
          ) as recording_file, atomic_output_dir(target, force, log) as tmp:
        snapshots = (SnapshotWriter(tmp / "snapshots", snapshot_every,
                                    config.map.occupied_threshold) if snapshot_every else None)
        recording = (Recording(recording_file or tmp / Path(config.record.file).name,
                               config.record.period_s, config.map, config.laser.min_range_m)
                     if config.record.file else None)
        ticks = array("d")
        measure = ScanMeasurer.configured(config.ekf, config.match, config.corners)
        front: FrontEnd | ForkedFrontEnd | Rewound = open_front_end(reader, source, measure,
                                                                    read_ahead)
        forked = isinstance(front, ForkedFrontEnd)
        try:
            if prior is not None:  # placed from the log's first scans, then run over them
                if on_phase is not None:
                    on_phase("placing the log in the prior map", 0, 0)
                front = Rewound(front)
                prior.place((scan, m.motion if measure.matches else None)
                            for scan, m in front.take())
            def on_scan(i: int, scan: Any, slam: Any) -> None:
                ticks.append(time.perf_counter())
                if on_progress is not None and i % 20 == 0:
                    on_progress(*front.progress(), i + 1)
                if snapshots is not None:
                    snapshots.maybe_take(scan.stamp, slam.current)
                if recording is not None:
                    recording.add(scan, slam)

            result = run(front.scans(), config, on_scan, front,
                         online_dynamic=snapshots is not None or recording is not None,
                         on_phase=on_phase, prior=prior)
            if snapshots is not None:
                snapshots.finish(result)
            recorded = recording.finish(result) if recording is not None else None
            if recorded and elsewhere:
                recorded["file"] = str(elsewhere.absolute())
        finally:
            front.close()
            source.close()
            if recording is not None:
                recording.close()
        if spacing is not None and spacing.convincing:
            front.stats.warn(spacing.notice())
        stamps = result.trajectory[:, 0]
        timeless = clock_stopped(stamps)  # (a clock that stopped after the first scans)
        if timeless:
            front.stats.warn("time stamps carry no time (most scans repeat one): "
                             "trajectory.tum numbers the scans 0, 1, 2, … s, and no "
                             "data duration is given")
        settings = run_settings(log, options, config, format_name, snapshot_every)
        summary = {
            "tool": {"name": "dynslam", "version": __version__},
            "input": {"path": source.name, "format": entry.name, **settings["input"],
                      "options": settings["options"],
                      "beam_spacing": None if spacing is None else spacing.to_dict()},
            "snapshots_s": settings["snapshots_s"],
            "reader": front.stats.to_dict(),
            "scans_processed": len(stamps),
            "first_stamp": float(stamps[0]) if len(stamps) else None,
            "data_duration_s": (None if timeless or timed_by_order(front.stats)
                                else float(stamps.max() - stamps.min()) if len(stamps)
                                else 0.0),
            "map": {"rows": result.static.shape[0], "cols": result.static.shape[1],
                    "resolution_m": result.static.resolution,
                    "origin": [result.static.origin_x, result.static.origin_y],
                    **result.grid_memory},
            "localization": result.localization,
            "changes": {"counts": {k: sum(e.kind == k for e in result.changes) for k in KINDS},
                        "events": [dataclasses.asdict(e) for e in result.changes]},
            "config": settings["config"],
            "outputs": list(OUTPUT_FILES) + (["snapshots/"] if snapshots else [])
            + ([recorded["file"]] if recorded else []),
            **({"recording": recorded} if recorded else {}),
            "wall_time_s": round(time.perf_counter() - start, 3),
            "scan_time_ms": _scan_times(ticks),
            "peak_rss_mb": _peak_rss_mb(children=False),
            "peak_rss_mb_read_ahead": _peak_rss_mb(children=True) if forked else None,
        }
        if on_phase is not None:
            on_phase("writing the outputs", 0, 0)
        write_results(tmp, result, config.map, summary)
    return summary, front.stats


def open_prior(folder: Path, config: Config, initial: Pose2D | None = None) -> PriorSession:
    """An earlier session's output folder as the start of a run (``--prior``): its static
    and dynamic maps, and ``initial``, where the user says the log starts in it (or None)."""
    from dynslam_cli.errors import InputError
    from dynslam_cli.mapping.changes import standing_at_end
    from dynslam_formats.changes import read_changes
    from dynslam_formats.mapfile import read_map

    if not (folder / "static.yaml").is_file():
        raise InputError(str(folder), "not a dynslam output folder (no static.yaml)")
    s = read_map(folder / "static.yaml")
    d = read_map(folder / "dynamic.yaml").grid if (folder / "dynamic.yaml").is_file() else None
    events = (_read_table(folder / "changes.csv", read_changes)
              if (folder / "changes.csv").is_file() else [])
    prior = PriorMap(str(folder), s.grid, s.free_thresh, s.occupied_thresh, d,
                     standing_at_end(events))
    return PriorSession(prior, config.map, config.prior, config.match, config.ekf.noise,
                        initial)


def score_output(target: Path, truth: Path | None = None, relations: Path | None = None,
                 frame: tuple[float, float] = (0.0, 0.0)) -> dict[str, Any]:
    """The scores of an output folder (``trajectory.tum`` alone is enough for relations)
    against a simulation's ``truth.json`` and the benchmark's relations (of the robot's
    poses at ``frame``: see :func:`dynslam_cli.evaluate.relation_errors`): what ``dynslam
    evaluate`` prints and ``dynslam batch`` keeps, {"target", "truth"?, "relations"?}."""
    from dynslam_cli.errors import InputError
    from dynslam_cli.evaluate import (
        MapThresholds,
        relation_errors,
        score_changes,
        score_run,
        score_sessions,
    )
    from dynslam_formats.changes import read_changes
    from dynslam_formats.landmarks import read_landmarks
    from dynslam_formats.mapfile import read_map
    from dynslam_formats.relations import read_relations
    from dynslam_formats.truth import read_truth
    from dynslam_formats.tum import read_tum

    if not target.exists():
        raise InputError(str(target), "no such output folder or trajectory file")
    folder = target if target.is_dir() else None
    tum = folder / "trajectory.tum" if folder else target
    report: dict[str, Any] = {"target": str(target)}
    if truth is not None:
        if folder is None:
            raise InputError(str(target), "--truth needs an output folder, not a file")
        static, dynamic = read_map(folder / "static.yaml"), read_map(folder / "dynamic.yaml")
        landmarks = _read_table(folder / "landmarks.csv", read_landmarks)
        true, trajectory = read_truth(truth), read_tum(tum)
        report["truth"] = score_run(
            static.grid, dynamic.grid, trajectory, landmarks, true,
            MapThresholds(static.free_thresh, static.occupied_thresh))
        if (folder / "changes.csv").exists():  # (not in folders of older versions)
            events = _read_table(folder / "changes.csv", read_changes)
            report["truth"]["changes"] = score_changes(events, trajectory, true)
            if true.get("session", 1) > 1:
                report["truth"]["sessions"] = score_sessions(events, trajectory, true)
    if relations is not None:
        report["relations"] = relation_errors(read_tum(tum), read_relations(relations),
                                              frame=frame)
    return report


def _read_table(path: Path, read: Callable[[Any], Any]) -> Any:
    """A CSV output file through its reader; what cannot be read is an InputError."""
    from dynslam_cli.errors import InputError

    try:
        with open(path, encoding="utf-8") as f:
            return read(f)
    except (OSError, KeyError, ValueError) as e:
        raise InputError(str(path), f"cannot read: {e}") from None


def checked_spacing(log: str, options: Any, format_name: str | None, config: Config,
                    on_phase: Callable[[str, int, int], None] | None = None
                    ) -> SpacingCheck | None:
    """The log's first scans, read apart, matched at their stated spacing and at their
    laser's own where they look spread by a converter (dynslam_cli.localization.beams;
    ``on_phase`` is told when they do)."""
    from dynslam_formats import open_log

    source, _, reader = open_log(log, options, format_name)
    try:
        scans = reader.scans()
        first = next(scans, None)
        if first is None or converter_spacing(np.asarray(first.angles)) is None:
            return None  # (read no further)
        if on_phase is not None:
            on_phase("checking the spacing of the beams", 0, 0)
        first_scans = [*itertools.chain([first], itertools.islice(scans, CHECK_SCANS - 1))]
    finally:
        source.close()
    return check_spacing(first_scans, config.match, config.ekf.noise)


def run_settings(log: str, options: Any, config: Config, format_name: str | None,
                 snapshot_every: float | None) -> dict[str, Any]:
    """What a run's outputs depend on besides the program: the input (its absolute path and
    size; None for standard input), the reader options, the effective configuration and the
    snapshot period. Stored in summary.json; ``dynslam batch`` compares them to tell a
    finished output from a stale one."""
    path = None if log == "-" else os.path.abspath(log)
    try:
        size = os.path.getsize(path) if path and os.path.isfile(path) else None
    except OSError:
        size = None
    return {"input": {"absolute_path": path, "bytes": size},
            "options": {"laser": options.laser, "topic": options.topic,
                        "odom_topic": options.odom_topic, "format": format_name,
                        "start_s": options.start_s, "end_s": options.end_s,
                        "max_scans": options.max_scans},
            "config": config.to_dict(), "snapshots_s": snapshot_every}


def _peak_rss_mb(children: bool) -> float | None:
    """Peak resident memory of this process, or of its largest finished child (None where
    the system does not say: Windows)."""
    try:
        import resource
    except ImportError:
        return None
    rss = resource.getrusage(resource.RUSAGE_CHILDREN if children else resource.RUSAGE_SELF)
    per_mb = 1024 * 1024 if sys.platform == "darwin" else 1024  # macOS counts bytes, Linux KiB
    return round(rss.ru_maxrss / per_mb, 1)


def _scan_times(ticks: array) -> dict[str, float | None]:
    """Median per-scan time (ms) of the first, the middle and the last 10% of scans: does a
    long log slow down? (statistics.median: numpy's imports numpy.ma, 7 ms.)"""
    dt = [1000.0 * (b - a) for a, b in itertools.pairwise(ticks)]
    k = len(dt) // 10
    parts = {"first": dt[:k], "middle": dt[(len(dt) - k) // 2:(len(dt) + k) // 2],
             "last": dt[len(dt) - k:]}
    return {f"{name}_10pct_median": round(statistics.median(part), 3) if k else None
            for name, part in parts.items()}


def snapshots_at(scans: Iterable[Scan], config: Config, times: list[float]
                 ) -> tuple[SlamResult, list[tuple[float, OccupancyMap, OccupancyMap]]]:
    """Run the pipeline and take (time, S, D) just before the first scan at or after each of
    ``times``, and at the end (for dynslam_cli.evaluate.score_events: the benches)."""
    slam = DynamicSlam(config)
    pending = sorted(times)
    snaps: list[tuple[float, OccupancyMap, OccupancyMap]] = []
    last = 0.0
    for scan in scans:
        while pending and scan.stamp >= pending[0]:
            snaps.append((pending.pop(0), slam.grids.snapshot("static").dense(),
                          slam.grids.snapshot("dynamic").dense()))
        slam.step(scan)
        last = scan.stamp
    snaps.append((last + 1.0, slam.grids.snapshot("static"), slam.grids.snapshot("dynamic")))
    return slam.result(), snaps
