"""Batch reprocessing: many logs (each possibly with its own config and truth), on local
processes or a Dask distributed cluster, resumable, one failure never stopping the rest.

Each log gets ``OUTROOT/<stem>`` (``<stem>-<hash>`` when two logs share a stem), written with
the same atomic contract as ``dynslam process``; a folder that already holds a complete
output (its ``summary.json``) made with the same settings is skipped unless ``force``. The
batch summary goes to ``OUTROOT/batch.csv`` and ``OUTROOT/batch.json``.
"""

from __future__ import annotations

import csv
import glob
import hashlib
import io
import json
import os
import signal
import tempfile
import time
import tomllib
from collections import Counter
from collections.abc import Callable, Generator, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from dynslam_cli.errors import ConfigError, DynslamError, InputError
from dynslam_cli.job import LOG_SUFFIXES, default_output

CSV_FIELDS = ("log", "output", "status", "error", "format", "scans", "data_duration_s",
              "wall_time_s", "x_real_time", "ate_rmse_m", "odometry_ate_rmse_m",
              "relation_translational_m", "relation_rotational_deg")


@dataclass(frozen=True)
class BatchItem:
    """One log of a batch. Picklable: it travels to worker processes and Dask workers."""

    log: str
    output: str
    config: str | None = None
    truth: str | None = None
    relations: str | None = None
    overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    force: bool = False
    reader: dict[str, Any] = field(default_factory=dict)
    """ReaderOptions fields (the command line's reader options and part of the log)."""
    format_name: str | None = None
    snapshots: float | None = None
    read_ahead: bool = True
    """Read and scan-match in a second process (see dynslam_cli.readahead); off when the
    batch already runs one worker per core."""
    redo: str | None = None
    """Why a complete earlier output is made again (it was made with other settings)."""


def expand_logs(items: Iterable[str]) -> list[str]:
    """Paths, folders (searched recursively for logs and ROS2 bag folders) and globs."""
    out: list[str] = []
    for item in items:
        matches = sorted(glob.glob(item, recursive=True)) if glob.has_magic(item) else [item]
        if not matches:
            raise InputError(item, "no file matches this pattern")
        for m in matches:
            p = Path(m)
            if p.is_dir() and not (p / "metadata.yaml").exists():
                found = sorted(str(f) for f in p.rglob("*") if _is_log(f))
                if not found:
                    raise InputError(m, "folder holds no logs")
                out += found
            elif p.exists():
                out.append(m)
            else:
                raise InputError(m, "no such file")
    return list(dict.fromkeys(out))


def _is_log(path: Path) -> bool:
    if path.is_dir():
        return (path / "metadata.yaml").exists()
    if path.name == "metadata.yaml" or path.parent.joinpath("metadata.yaml").exists():
        return False
    return path.name.endswith(LOG_SUFFIXES)


def read_manifest(path: Path) -> list[dict[str, str | None]]:
    """Rows {log, config, truth, relations} from a CSV (header with at least ``log``) or a
    TOML file (``[[log]]`` tables with ``path`` and optional keys); relative paths are taken
    from the manifest's folder."""
    base = path.parent
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(str(path), f"cannot read: {e.strerror}") from None
    rows: list[dict[str, Any]]
    if path.suffix == ".toml":
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise InputError(str(path), f"not valid TOML: {e}") from None
        rows = [{"log": r.get("path"), **{k: r.get(k) for k in ("config", "truth",
                                                                  "relations")}}
                for r in data.get("log", [])]
    else:
        reader = csv.DictReader(io.StringIO(text))
        if reader.fieldnames is None or "log" not in reader.fieldnames:
            raise InputError(str(path), "a CSV manifest needs a header with a 'log' column", 1)
        rows = [dict(r) for r in reader]
    out = []
    for i, row in enumerate(rows, 2 if path.suffix != ".toml" else 1):
        if not row.get("log"):
            raise InputError(str(path), "a row without a log path", i)
        out.append({k: (str(base / v) if v and not os.path.isabs(v) else v or None)
                    for k, v in ((k, row.get(k)) for k in ("log", "config", "truth",
                                                           "relations"))})
    if not out:
        raise InputError(str(path), "the manifest lists no logs")
    return out


def output_names(runs: list[tuple[str, str | None]]) -> list[str]:
    """Folder names under OUTROOT for (log, config) pairs: the log's stem, made unique by a
    short hash of the log's absolute path, and of the configuration's too where one log
    runs with several (a parameter sweep)."""
    stems = [default_output(log).name.removesuffix("_dynslam") for log, _ in runs]
    per_stem, per_log = Counter(stems), Counter(os.path.abspath(log) for log, _ in runs)
    return [s if per_stem[s] == 1 else
            f"{s}-{_short_hash(log, config if per_log[os.path.abspath(log)] > 1 else None)}"
            for s, (log, config) in zip(stems, runs, strict=True)]


def _short_hash(log: str, config: str | None) -> str:
    key = os.path.abspath(log) + ("" if config is None else "\n" + os.path.abspath(config))
    return hashlib.sha1(key.encode()).hexdigest()[:8]


def stale_reason(job: BatchItem) -> str | None:
    """Why the complete output in ``job.output`` does not answer ``job`` (another input, other
    reader options, configuration or snapshot period made it), or None when it does. An
    unreadable configuration is left for the run to report."""
    from dynslam_cli.config import load_config
    from dynslam_cli.job import run_settings
    from dynslam_formats import ReaderOptions

    try:
        config = load_config(Path(job.config) if job.config else None, job.overrides)
    except (ConfigError, DynslamError):
        return None
    options = ReaderOptions(**job.reader, **config.laser.reader_options())
    wanted = json.loads(json.dumps(run_settings(job.log, options, config, job.format_name,
                                                job.snapshots)))
    try:
        summary = json.loads((Path(job.output) / "summary.json").read_text(encoding="utf-8"))
        made = {"input": {k: summary["input"].get(k) for k in wanted["input"]},
                "options": summary["input"]["options"], "config": summary["config"],
                "snapshots_s": summary.get("snapshots_s")}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return "its summary.json is unreadable"
    wanted, made = _flat(wanted), _flat(made)
    differ = [k for k in sorted(wanted.keys() | made.keys()) if wanted.get(k) != made.get(k)]
    if not differ:
        return None
    more = f" and {len(differ) - 3} more" if len(differ) > 3 else ""
    return f"made with another {', '.join(differ[:3])}{more}"


def _flat(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """{"a.b": value} for a nested dict."""
    out: dict[str, Any] = {}
    for k, v in tree.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def complete(output: Path) -> bool:
    return (output / "summary.json").is_file()


def run_job(job: BatchItem) -> dict[str, Any]:
    """Process one log (and score it); never raises for the log's own problems."""
    from dynslam_cli.config import load_config
    from dynslam_formats import ReaderOptions

    row: dict[str, Any] = {"log": job.log, "output": job.output, "status": "done",
                           "error": "", **({"redone": job.redo} if job.redo else {})}
    start = time.perf_counter()
    try:
        from dynslam_cli.job import process_log

        config = load_config(Path(job.config) if job.config else None, job.overrides)
        options = ReaderOptions(**job.reader, **config.laser.reader_options())
        summary, _ = process_log(job.log, Path(job.output), job.force, options, config,
                                 job.format_name, job.snapshots, read_ahead=job.read_ahead)
        row.update(_figures(summary))
        row.update(_scores(job))
    except (DynslamError, ConfigError) as e:
        row.update(status="failed", error=str(e))
    except Exception as e:  # a bug on one log must not stop the batch; it is reported
        row.update(status="failed", error=f"internal error: {type(e).__name__}: {e}")
    row.setdefault("wall_time_s", round(time.perf_counter() - start, 3))
    return row


def _figures(summary: dict[str, Any]) -> dict[str, Any]:
    """A log's row figures from its summary.json."""
    dur, wall = summary["data_duration_s"], summary["wall_time_s"]  # dur None: no clock
    return {"format": summary["input"]["format"], "scans": summary["scans_processed"],
            "data_duration_s": None if dur is None else round(dur, 3), "wall_time_s": wall,
            "x_real_time": round(dur / wall, 1) if wall and dur is not None else None}


def earlier_row(job: BatchItem) -> dict[str, Any]:
    """The row of a log whose output an earlier run completed: status ``skipped``, its
    figures from its summary.json, its scores computed again from its files."""
    row: dict[str, Any] = {"log": job.log, "output": job.output, "status": "skipped",
                           "error": ""}
    try:
        summary = json.loads((Path(job.output) / "summary.json").read_text(encoding="utf-8"))
        row.update(_figures(summary))
        row.update(_scores(job))
    except (OSError, ValueError, KeyError, TypeError) as e:
        row["error"] = f"earlier output unreadable: {e}"
    except DynslamError as e:
        row["error"] = str(e)
    return row


def _scores(job: BatchItem) -> dict[str, Any]:
    """The row's scores (the manifest's truth and relations), as ``dynslam evaluate`` gives
    them."""
    from dynslam_cli.job import score_output

    if not job.truth and not job.relations:
        return {}
    report = score_output(Path(job.output), Path(job.truth) if job.truth else None,
                          Path(job.relations) if job.relations else None)
    out: dict[str, Any] = {}
    if "truth" in report:
        out["ate_rmse_m"] = report["truth"]["trajectory"]["ate_rmse_m"]
        out["odometry_ate_rmse_m"] = report["truth"]["trajectory"]["odometry_ate_rmse_m"]
        out["scores"] = report["truth"]
    if "relations" in report:
        out["relation_translational_m"] = report["relations"]["translational_m"]["mean"]
        out["relation_rotational_deg"] = report["relations"]["rotational_deg"]["mean"]
    return out


def plan(rows: list[dict[str, str | None]], outroot: Path, force: bool,
         overrides: dict[str, dict[str, Any]], reader: dict[str, Any],
         default_config: str | None, format_name: str | None = None,
         snapshots: float | None = None) -> tuple[list[BatchItem], list[dict[str, Any]]]:
    """Jobs to run, and rows for logs skipped because their output is complete and was
    made from the same input with the same options and configuration (a job redoing an
    output made otherwise says why in ``BatchItem.redo``). Every path is absolute: a Dask worker
    resolves relative ones in its own working folder. A row repeating an earlier row's log
    and configuration is dropped."""
    def absolute(path: str | None) -> str | None:
        return os.path.abspath(path) if path else None

    runs: dict[tuple[str, str | None], dict[str, str | None]] = {}
    for row in rows:
        key = (os.path.abspath(str(row["log"])), absolute(row.get("config") or default_config))
        runs.setdefault(key, row)
    names = output_names(list(runs))
    jobs, skipped = [], []
    for ((log, config), row), name in zip(runs.items(), names, strict=True):
        out = (outroot / name).absolute()
        job = BatchItem(log, str(out), config, absolute(row.get("truth")),
                  absolute(row.get("relations")), overrides, force or out.exists(), reader,
                  format_name, snapshots)
        if complete(out) and not force:
            reason = stale_reason(job)
            if reason is None:
                skipped.append(earlier_row(job))
                continue
            job = replace(job, redo=reason)
        jobs.append(job)
    return jobs, skipped


def run_local(jobs: list[BatchItem], workers: int) -> Iterator[dict[str, Any]]:
    """Results as they finish, on ``workers`` local processes (1: in this process). When
    the caller is interrupted (Ctrl-C, SIGTERM), jobs not started are dropped and running
    ones are ended: their workers get SIGTERM, remove their temporary folders and exit."""
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            yield run_job(job)
        return
    import multiprocessing

    pool = multiprocessing.Pool(min(workers, len(jobs)), _quiet_worker)
    try:
        yield from pool.imap_unordered(run_job, [replace(job, read_ahead=False)
                                                 for job in jobs])
    finally:
        pool.terminate()  # after the last result a no-op; on an interruption, the stop
        pool.join()


def _quiet_worker() -> None:
    """A batch worker leaves stopping to the batch: Ctrl-C at the terminal reaches it too,
    and is ignored; the SIGTERM the batch sends ends it as ``exit`` would, so the job's
    temporary output folder is removed on the way out."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_on_term)


def _exit_on_term(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)


def run_dask(jobs: list[BatchItem], client: Any) -> Iterator[dict[str, Any]]:
    """Results as they finish, on a Dask distributed cluster (workers write to OUTROOT,
    which must be storage they share with this machine). Interrupted, the jobs not yet
    finished are cancelled."""
    from dask.distributed import as_completed

    futures = client.map(run_job, jobs, pure=False)
    try:
        for f in as_completed(futures):
            yield f.result()
    finally:
        client.cancel(futures)


def write_summary(outroot: Path, rows: list[dict[str, Any]]) -> None:
    """batch.csv and batch.json, each written to a temporary file and renamed."""
    rows = sorted(rows, key=lambda r: r["log"])
    _atomic_write(outroot / "batch.json", json.dumps(rows, indent=2, sort_keys=True) + "\n")
    buf = io.StringIO()
    w = csv.DictWriter(buf, CSV_FIELDS, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow(r)
    _atomic_write(outroot / "batch.csv", buf.getvalue())


def _atomic_write(path: Path, text: str) -> None:
    from dynslam_formats.outdir import with_umask

    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    os.chmod(tmp, with_umask(0o666))
    os.replace(tmp, path)


def run_batch(rows: list[dict[str, str | None]], outroot: Path, force: bool,
              overrides: dict[str, dict[str, Any]], reader: dict[str, Any],
              default_config: str | None, execute: Callable[[list[BatchItem]],
                                                            Iterable[dict[str, Any]]],
              on_done: Callable[[dict[str, Any]], None] | None = None,
              format_name: str | None = None, snapshots: float | None = None
              ) -> list[dict[str, Any]]:
    """Plan, run what is missing through ``execute``, write the summary (also when
    interrupted: for the logs finished by then); returns all rows.
    ``reader``: ReaderOptions fields for every log; ``format_name`` and ``snapshots`` as for
    ``dynslam process``."""
    outroot.mkdir(parents=True, exist_ok=True)
    jobs, results = plan(rows, outroot, force, overrides, reader, default_config, format_name,
                         snapshots)
    for r in results:
        if on_done:
            on_done(r)
    running = iter(execute(jobs))
    try:
        for r in running:
            results.append(r)
            if on_done:
                on_done(r)
    finally:  # interrupted: stop the jobs still running, list what finished
        if isinstance(running, Generator):
            running.close()
        write_summary(outroot, results)
    return results

