"""The command line. Only this module knows about terminals: progress bars, colours, exit
codes. Every user error becomes one line on stderr and exit code 1 (click's usage errors: 2).
Heavy modules are imported inside the commands so ``dynslam --help`` starts fast.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from dynslam_cli import __version__

LOG_NAMES = {"carmen": ".log", "player": ".player.log", "rosbag1": ".bag", "rosbag2": "",
             "rosbag2-mcap": "", "mcap": ".mcap"}


def _fail(message: str) -> None:
    click.echo(f"dynslam: error: {message}", err=True)
    sys.exit(1)


class Terminated(BaseException):
    """SIGTERM (a CI job's time limit, ``kill``): stop as for Ctrl-C, cleaning up."""


def _terminate(signum: int, frame: object) -> None:
    raise Terminated


def _guarded(work: Callable[[], Any]) -> Any:
    """Run ``work``; known errors become one line on stderr and exit code 1; Ctrl-C (130)
    and SIGTERM (143) leave no output folder or temporary files behind."""
    from dynslam_cli.errors import DynslamError, printable

    signal.signal(signal.SIGTERM, _terminate)
    # Damaged input is reported as counts and skips; numpy's floating-point warnings about
    # it ("overflow encountered in cast") are not for the user's terminal.
    warnings.filterwarnings("ignore", message=r".*encountered in", category=RuntimeWarning)
    try:
        if signal.getsignal(signal.SIGINT) not in (signal.SIG_IGN, signal.default_int_handler):
            signal.signal(signal.SIGINT, signal.default_int_handler)  # (see dynslam_cli.run)
        return work()
    except DynslamError as e:
        _fail(str(e))
    except KeyboardInterrupt:
        click.echo("dynslam: interrupted; no output written", err=True)
        sys.exit(130)
    except Terminated:
        click.echo("dynslam: terminated; no output written", err=True)
        sys.exit(143)
    except BrokenPipeError:
        sys.exit(1)
    except OSError as e:  # what the file system refused, where no closer check said it
        _fail(f"{printable(str(e.filename)) + ': ' if e.filename else ''}"
              f"{e.strerror or e}")
    except MemoryError as e:  # numpy's names the array it could not allocate
        _fail(f"out of memory ({str(e).splitlines()[0] if str(e) else 'MemoryError'}); "
              "a coarser --resolution or a smaller part of the log needs less")


def _options(*decorators: Callable[[Any], Any]) -> Callable[[Any], Any]:
    """One decorator applying click options in the order listed (shared by commands)."""
    def apply(f: Any) -> Any:
        for decorate in reversed(decorators):
            f = decorate(f)
        return f
    return apply


reader_options = _options(  # how to read a log: process, batch (every log), info
    click.option("--format", "format_name", metavar="NAME",
                 help="Log format instead of detecting it: carmen, player, ros, mcap."),
    click.option("--laser", default="front", show_default=True, metavar="WHICH",
                 help="Which laser: Carmen front|rear|3|4; Player a device index."),
    click.option("--topic", metavar="TOPIC", help="ROS: the sensor_msgs/LaserScan topic."),
    click.option("--odom-topic", metavar="TOPIC", help="ROS: the nav_msgs/Odometry topic."),
    click.option("--flaser-fov", type=float, metavar="DEG",
                 help="Field of view of old FLASER records (degrees) instead of CARMEN's "
                      "rule."),
    click.option("--beam-step", type=float, metavar="DEG",
                 help="The angle between two beams (degrees) where the log states it wrong "
                      "(a converter's fov/(n-1) for a laser's fov/n); the first beam stays. "
                      "Without it, beams that look spread so are checked against the scans "
                      "([laser] check_beam_step)."),
)

run_options = _options(  # what to compute and which part of the log: process, batch
    click.option("--resolution", type=click.FloatRange(min=0, min_open=True), metavar="M",
                 help="Grid cell size in metres [default: 0.05]."),
    click.option("--config", "config_file", type=click.Path(path_type=Path),
                 help="TOML file with algorithm parameters (print them all: dynslam config); "
                      "in batch, for logs the manifest gives none."),
    click.option("--localization", type=click.Choice(["ekf", "odometry"]),
                 help="ekf: corner EKF-SLAM with scan-matched motion (default); odometry: the "
                      "log's odometry alone (paper Fig. 3a ablation)."),
    click.option("--no-dynamic", is_flag=True,
                 help="One ordinary occupancy grid instead of S and D (paper Fig. 3b "
                      "ablation)."),
    click.option("--snapshots", type=click.FloatRange(min=0, min_open=True), metavar="SECONDS",
                 help="Also write the S ∪ D picture every SECONDS of log time into "
                      "snapshots/ and snapshots/evolution.gif."),
    click.option("--record", metavar="NAME.mcap",
                 help="Also write a recording of the run for Foxglove and RViz (MCAP, ROS 2 "
                      "messages: /scan, /tf, /map, /dynamic_map, /path, /landmarks ...) as "
                      "NAME.mcap in the output folder, or at a path (process: "
                      "~/runs/today.mcap; --force replaces only a recording of dynslam's)."),
    click.option("--record-period", type=click.FloatRange(min=0, min_open=True),
                 metavar="SECONDS",
                 help="In the recording, send the maps, paths and landmarks at most every "
                      "SECONDS of log time [default: 5]."),
    click.option("--start", "start_s", type=click.FloatRange(min=0), metavar="SECONDS",
                 help="Leave out the scans of the first SECONDS (log time after the first "
                      "scan)."),
    click.option("--end", "end_s", type=click.FloatRange(min=0), metavar="SECONDS",
                 help="Stop SECONDS of log time after the first scan."),
    click.option("--max-scans", type=click.IntRange(min=1), metavar="N",
                 help="Stop after N scans (a quick look at a long log)."),
)


# The configuration keys the command-line options set: a value the configuration refuses is
# the option's (a usage error, exit 2), not the configuration file's.
OPTION_KEYS = {"map.resolution_m": "--resolution", "laser.fov_deg": "--flaser-fov",
               "laser.beam_step_deg": "--beam-step",
               "record.period_s": "--record-period", "record.file": "--record"}


def _load(config_file: Path | None, overrides: dict[str, dict[str, Any]]) -> Any:
    """The effective configuration; an override out of range is a usage error that names
    its option."""
    from dynslam_cli.config import load_config
    from dynslam_cli.errors import ConfigError

    try:
        return load_config(config_file, overrides)
    except ConfigError as e:
        for key, option in OPTION_KEYS.items():
            section, name = key.split(".")
            if name in overrides.get(section, {}) and str(e).startswith(key):
                raise click.BadParameter(str(e).removeprefix(key).strip(" :"),
                                         param_hint=f"'{option}'") from None
        raise


def _overrides(resolution: float | None, flaser_fov: float | None, beam_step: float | None,
               no_dynamic: bool, localization: str | None, record: str | None = None,
               record_period: float | None = None) -> dict[str, dict[str, Any]]:
    """Configuration overrides from the command-line options."""
    overrides: dict[str, dict[str, Any]] = {}
    recording = {k: v for k, v in (("file", record), ("period_s", record_period))
                 if v is not None}
    if recording:
        overrides["record"] = recording
    if resolution is not None:
        overrides["map"] = {"resolution_m": resolution}
    laser = {k: v for k, v in (("fov_deg", flaser_fov), ("beam_step_deg", beam_step))
             if v is not None}
    if laser:
        overrides["laser"] = laser
    if no_dynamic:
        overrides["dynamic"] = {"enabled": False}
    if localization is not None:
        overrides["ekf"] = {"localization": localization}
    return overrides


def _reader(laser: str, topic: str | None, odom_topic: str | None, start_s: float | None,
            end_s: float | None, max_scans: int | None) -> dict[str, Any]:
    """ReaderOptions fields from the command-line options (a dict: it travels to workers)."""
    if start_s is not None and end_s is not None and end_s <= start_s:
        raise click.BadParameter(f"--end {end_s:g} is not after --start {start_s:g}",
                                 param_hint="--end")
    return {"laser": laser, "topic": topic, "odom_topic": odom_topic, "start_s": start_s,
            "end_s": end_s, "max_scans": max_scans}


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="dynslam")
def main() -> None:
    """dynslam: 2D laser SLAM in dynamic environments, over recorded robot logs.

    Builds a static map S and a dynamic map D (Wolf & Sukhatme 2005), a corner landmark map
    (EKF-SLAM, Table 3) and the corrected trajectory from a robot's log: Carmen / Radish /
    Freiburg logs and Player writelogs (text, plain or .gz, .bz2, .xz), ROS 1 bags, ROS 2
    bags (a folder or .db3) and MCAP files (dynslam info LOG tells what one holds).

    \b
    Start with:
      dynslam process samples/hall/hall.log        # writes ./hall_dynslam/
      dynslam COMMAND --help                      # every option, with examples
    """


@main.command()
@click.argument("log", type=click.Path(allow_dash=True, readable=False))  # checked by the reader
@click.option("-o", "--output", type=click.Path(path_type=Path),
              help="Output folder [default: ./<log stem>_dynslam].")
@click.option("--force", is_flag=True,
              help="Replace an existing output folder (only one dynslam wrote).")
@reader_options
@run_options
@click.option("--no-read-ahead", is_flag=True,
              help="Read the log and match scans in this process too (by default a second "
                   "process does that ahead of the filter, on another core; the results are "
                   "the same).")
@click.option("--prior", type=click.Path(file_okay=False, path_type=Path), metavar="DIR",
              help="An earlier session's output folder: the log is placed in its static map "
                   "(searched over the whole map and every heading) and mapped on from it, "
                   "in its frame, so the two folders overlay cell for cell. A log that "
                   "cannot be placed, or fits two places alike, is an error.")
@click.option("--initial-pose", metavar="X,Y,DEGREES", callback=lambda c, p, v: _pose(v),
              help="With --prior: where the log starts in the prior map (metres, metres, "
                   "degrees), for a place that looks like another; searched within "
                   "[prior] initial_tolerance_m of it first.")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar or summary line.")
def process(log: str, output: Path | None, force: bool, format_name: str | None, laser: str,
            topic: str | None, odom_topic: str | None, flaser_fov: float | None,
            beam_step: float | None, resolution: float | None, config_file: Path | None,
            localization: str | None, no_dynamic: bool, snapshots: float | None,
            record: str | None, record_period: float | None, start_s: float | None,
            end_s: float | None, max_scans: int | None, no_read_ahead: bool,
            prior: Path | None, initial_pose: tuple[float, float, float] | None,
            quiet: bool) -> None:
    """Run SLAM over LOG and write maps, landmarks and trajectory.

    LOG is a Carmen log (.log, .clf, .gfs.log; plain, .gz, .bz2 or .xz), a Player
    writelog, a ROS1 .bag, a ROS2 bag folder, .db3 or .mcap, or - for standard input (text
    logs).

    \b
    Writes into the output folder (atomically: all or nothing):
      static.pgm/.yaml    static map S (map_server/nav2, trinary: free,
                          unknown, occupied as map_saver writes them)
      static_prob.png/.yaml  S's probabilities (scale mode, unknown transparent)
      dynamic.pgm/.yaml   dynamic map D (trinary, same size and origin)
      map.png             picture of S ∪ D with the trajectory, events numbered
      changes.csv         what changed: id,kind (appeared, vacated, moving;
                          with --prior added_ and removed_since_prior),
                          first_s,last_s,x,y,size_m2,scans,landmarks
      landmarks.csv       id,x,y,kind,class,observations,cov_xx,cov_xy,cov_yy
      trajectory.tum      one robot pose per scan (TUM, for evo)
      summary.json        counts, skips, timing, effective configuration
      NAME.mcap           with --record: the run to play back in Foxglove or RViz
    The output folder's path is printed on stdout.

    \b
    Examples:
      dynslam process mit-csail.clf
      dynslam process intel.log.gz -o out/intel --resolution 0.1
      zcat run3.log.gz | dynslam process - -o run3 --quiet
      dynslam process robot.log --laser rear --config tuned.toml --force
      dynslam process lasers.bag --topic /left_scan
      dynslam process long.bag --start 600 --end 900    # ten to fifteen minutes in
      dynslam process mit-csail.clf --record run.mcap   # then open it in Foxglove
      dynslam process today.log --prior yesterday_dynslam   # in yesterday's map
    """
    from dynslam_cli.job import default_output

    if initial_pose is not None and prior is None:
        raise click.BadParameter("needs --prior (a pose in which map?)",
                                 param_hint="'--initial-pose'")

    target = output if output is not None else default_output(log)
    overrides = _overrides(resolution, flaser_fov, beam_step, no_dynamic, localization, record,
                           record_period)

    def work() -> None:
        from dynslam_formats import ReaderOptions
        from dynslam_formats.outdir import check_target

        config = _load(config_file, overrides)
        check_target(target, force, log)
        options = ReaderOptions(**_reader(laser, topic, odom_topic, start_s, end_s, max_scans),
                                **config.laser.reader_options())
        session = None
        if prior is not None:
            from dynslam_cli.job import open_prior
            from dynslam_cli.types import Pose2D

            start = (None if initial_pose is None else
                     Pose2D(initial_pose[0], initial_pose[1], math.radians(initial_pose[2])))
            session = open_prior(prior, config, start)
        summary = _process(log, target, force, format_name, options, config, quiet,
                           snapshots, not no_read_ahead, session)
        if not quiet:
            s = summary
            data = (f"{s['data_duration_s']:.1f} s of data" if s["data_duration_s"] is not None
                    else "data without time")
            click.echo(f"dynslam: {s['scans_processed']} scans, {data} in "
                       f"{s['wall_time_s']:.2f} s → {target}", err=True)
        click.echo(str(target))

    _guarded(work)


def _pose(text: str | None) -> tuple[float, ...] | None:
    """X,Y,DEGREES as three finite numbers."""
    return None if text is None else _numbers(text, 3, "X,Y,DEGREES (three numbers)")


def _process(log: str, target: Path, force: bool, format_name: str | None, options: Any,
             config: Any, quiet: bool, snapshot_every: float | None,
             read_ahead: bool, prior: Any = None) -> dict[str, Any]:
    from dynslam_cli.job import process_log

    if quiet or not sys.stderr.isatty():  # no progress bar (and no tqdm import)
        summary, stats = process_log(log, target, force, options, config, format_name,
                                     snapshot_every, read_ahead=read_ahead, prior=prior)
    else:
        tqdm = _progress_bar()
        name = Path(log).name
        with tqdm(unit="B", unit_scale=True, desc=name, file=sys.stderr, leave=False) as bar:

            def on_progress(done: int, total: int, scans: int) -> None:
                if total and bar.total != total:
                    bar.total = total
                bar.set_postfix_str(f"{scans} scans", refresh=False)
                bar.update(done - bar.n)

            def on_phase(what: str, done: int, total: int) -> None:
                label = f"{name}: {what}"
                if bar.desc != label:  # a new phase: a bar of its own (scans), or a spinner
                    bar.unit, bar.unit_scale = "scan", False
                    bar.reset()
                    bar.total = total or None  # (reset keeps the old total when given none)
                    bar.bar_format = None if total else "{desc} ({elapsed})"
                    bar.set_description_str(label, refresh=False)
                    bar.set_postfix_str("", refresh=False)
                bar.update(done - bar.n)
                bar.refresh()

            summary, stats = process_log(log, target, force, options, config, format_name,
                                         snapshot_every, on_progress, read_ahead, on_phase,
                                         prior)
    _report_warnings(summary["input"]["path"], stats)
    return summary


def _progress_bar() -> Any:
    """tqdm, without its monitor thread: a process with a second thread does not fork a
    read-ahead process (dynslam_cli.readahead.can_fork)."""
    from tqdm import tqdm

    tqdm.monitor_interval = 0
    return tqdm


def _report_warnings(name: str, stats: Any) -> None:
    for kind, counter in (("skipped", stats.skipped), ("warning", stats.warnings)):
        for reason, count in sorted(counter.items()):
            line = stats.first_line.get(reason, 0)
            where = f"{name}:{line}" if line else name
            click.echo(f"dynslam: {kind}: {where}: {reason} (×{count})", err=True)


@main.command()
@click.argument("logs", nargs=-1)
@click.option("-o", "--output", "outroot", type=click.Path(file_okay=False, path_type=Path),
              required=True, help="Folder that gets one output folder per log.")
@click.option("--manifest", type=click.Path(path_type=Path),
              help="CSV (log,config,truth,relations) or TOML ([[log]] path=...) list of logs.")
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=os.cpu_count() or 1,
              show_default=True, help="Local worker processes.")
@click.option("--scheduler", metavar="tcp://HOST:PORT",
              help="Run on this Dask distributed scheduler (Dask: pip install '.[dask]' in "
                   "dynslam's source folder); OUTROOT must be storage the workers share.")
@click.option("--force", is_flag=True, help="Redo logs whose output is already complete.")
@reader_options
@run_options
@click.option("-q", "--quiet", is_flag=True, help="No progress bar or table.")
def batch(logs: tuple[str, ...], outroot: Path, manifest: Path | None, jobs: int,
          scheduler: str | None, force: bool, format_name: str | None, laser: str,
          topic: str | None, odom_topic: str | None, flaser_fov: float | None,
          beam_step: float | None, resolution: float | None, config_file: Path | None,
          localization: str | None, no_dynamic: bool, snapshots: float | None, record: str | None,
          record_period: float | None, start_s: float | None,
          end_s: float | None, max_scans: int | None, quiet: bool) -> None:
    """Process many logs: LOGS are files, folders (searched for logs) or globs.

    One output folder per log under OUTROOT (the same contract as 'process'; names made
    unique when two logs share a stem). Resumable: logs whose output is complete and
    was made with the same input, options and configuration are skipped unless --force
    (an output made otherwise is redone), so rerunning an interrupted batch does only what
    is missing. A failing log is recorded and the others go on; the exit code is 1 if any
    failed. Ctrl-C or SIGTERM keeps the finished logs and lists them in batch.csv.
    OUTROOT/batch.csv and batch.json list per log: status, scans, data duration, wall time,
    × real time, and scores where the manifest gives truth or relations.

    \b
    Examples:
      dynslam batch data/*.clf -o out/ --jobs 2
      dynslam batch --manifest runs.csv -o out/
      dynslam batch radish/ -o out/ --scheduler tcp://10.0.0.5:8786
    """
    if not logs and manifest is None:
        raise click.UsageError("give logs or --manifest")
    if record is not None and Path(record).name != record:
        raise click.BadParameter("in batch, a file name: each log's output folder gets its "
                                 "own recording", param_hint="'--record'")
    overrides = _overrides(resolution, flaser_fov, beam_step, no_dynamic, localization, record,
                           record_period)
    reader = _reader(laser, topic, odom_topic, start_s, end_s, max_scans)

    def work() -> None:
        from dynslam_cli.batch import expand_logs, read_manifest, run_batch, run_dask, run_local

        _load(config_file, overrides)  # fail early
        rows = [{"log": log, "config": None, "truth": None, "relations": None}
                for log in expand_logs(logs)]
        if manifest is not None:
            rows += read_manifest(manifest)
        client = _dask_client(scheduler) if scheduler else None
        execute = ((lambda js: run_dask(js, client)) if client is not None
                   else (lambda js: run_local(js, jobs)))
        tqdm = _progress_bar()
        finished: list[dict[str, Any]] = []

        def on_done(row: dict[str, Any]) -> None:
            finished.append(row)
            bar.update(1)

        try:
            with tqdm(total=len(rows), unit="log", disable=quiet or None,
                      file=sys.stderr) as bar:
                results = run_batch(rows, outroot, force, overrides, reader,
                                    str(config_file) if config_file else None, execute,
                                    on_done, format_name, snapshots)
        except (KeyboardInterrupt, Terminated) as e:
            _batch_report(finished, quiet=True)
            stopped = "interrupted" if isinstance(e, KeyboardInterrupt) else "terminated"
            click.echo(f"dynslam: {stopped}: the finished logs' outputs are kept and listed "
                       f"in {outroot / 'batch.csv'}; the others are not written", err=True)
            sys.exit(130 if isinstance(e, KeyboardInterrupt) else 143)
        finally:
            if client is not None:
                client.close()
        _batch_report(results, quiet)
        if any(r["status"] == "failed" for r in results):
            sys.exit(1)

    _guarded(work)


def _dask_client(address: str) -> Any:
    from dynslam_cli.errors import DynslamError

    try:
        from dask.distributed import Client
    except ImportError:
        raise DynslamError("--scheduler needs Dask: pip install '.[dask]' in dynslam's source "
                           "folder (or the wheel with its extra: 'dynslam-*.whl[dask]')") from None
    try:
        return Client(address, timeout="10s")
    except ValueError as e:  # an address Dask cannot parse (tcp://host without its port)
        raise DynslamError(f"--scheduler {address}: {e}; give tcp://HOST:PORT") from None
    except (OSError, TimeoutError) as e:
        raise DynslamError(f"cannot reach the Dask scheduler at {address}: {e}") from None


def _batch_report(results: list[dict[str, Any]], quiet: bool) -> None:
    done = [r for r in results if r["status"] == "done"]
    skipped = [r for r in results if r["status"] == "skipped"]
    failed = [r for r in results if r["status"] == "failed"]
    for r in failed:
        click.echo(f"dynslam: failed: {r['error']}", err=True)
    for r in results:
        if r.get("redone"):
            click.echo(f"dynslam: redone {r['log']}: its earlier output was {r['redone']}",
                       err=True)
    if not quiet:
        for r in sorted(results, key=lambda r: r["log"]):
            xrt = r.get("x_real_time")
            click.echo(f"{r['status']:<8} {r.get('scans', ''):>6} "
                       f"{(str(xrt) + '×') if xrt else '':>8}  {r['log']}", err=True)
    if not done and not failed:
        click.echo(f"dynslam: nothing to do: all {len(skipped)} outputs are complete "
                   "(--force redoes them)", err=True)
    else:
        click.echo(f"dynslam: {len(done)} done, {len(skipped)} skipped, {len(failed)} failed",
                   err=True)


@main.command()
@click.argument("log", type=click.Path(allow_dash=True, readable=False))  # checked by the reader
@reader_options
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
def info(log: str, format_name: str | None, laser: str, topic: str | None,
         odom_topic: str | None, flaser_fov: float | None, beam_step: float | None,
         as_json: bool) -> None:
    """Describe what LOG holds before processing it.

    Format, record types or topics with message counts, scans, beams, field of view, max
    range, duration, and whether it carries odometry. A bag with several laser topics is
    described topic by topic: 'process' needs --topic to choose one.

    \b
    Examples:
      dynslam info mit-csail.clf
      dynslam info people.bag --json | jq .scans
    """

    def work() -> None:
        import json

        from dynslam_formats import ReaderOptions, describe_log

        d = describe_log(log, ReaderOptions(laser=laser, topic=topic, odom_topic=odom_topic,
                                            fov_deg=flaser_fov, beam_step_deg=beam_step),
                         format_name)
        click.echo(json.dumps(d, indent=2, sort_keys=True) if as_json else _table(d))

    _guarded(work)


@main.command("config")
@click.option("--config", "config_file", type=click.Path(path_type=Path),
              help="Print this file's effective values (defaults filled in) instead.")
def config_command(config_file: Path | None) -> None:
    """Print every algorithm parameter as TOML, with its unit and meaning.

    The output is a valid --config file: save it, keep the lines you change.

    \b
    Examples:
      dynslam config > dynslam.toml
      dynslam process log.clf --config dynslam.toml
      dynslam config --config tuned.toml     # what tuned.toml amounts to
    """

    def work() -> None:
        from dynslam_cli.config import load_config, to_toml

        click.echo(to_toml(load_config(config_file)), nl=False)

    _guarded(work)


@main.command()
@click.argument("world", type=click.Choice(["corridors", "arena", "hall", "crowd", "office",
                                            "wards"]))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="Folder to write <world>.log and truth.json into.")
@click.option("--duration", type=click.FloatRange(min=1), default=600, show_default=True,
              help="Seconds of simulated time.")
@click.option("--rate", type=click.FloatRange(min=0.5, max=100), default=10, show_default=True,
              help="Scans per second.")
@click.option("--seed", type=int, default=0, show_default=True, help="Makes the run reproducible.")
@click.option("--odometry-noise", type=click.FloatRange(min=0), default=1.0, show_default=True,
              help="Scale of the odometry error model; 0 = odometry equals the truth.")
@click.option("--walkers", type=click.IntRange(2, 10), help="Moving robots in 'hall' [default: 4].")
@click.option("--stop-and-go", type=click.FloatRange(min=0), default=0, metavar="SECONDS",
              help="Walkers (hall's robots, crowd's people) stand still SECONDS after every "
                   "4 m they walk, then walk on.")
@click.option("--beams", type=click.IntRange(min=2), default=181, show_default=True,
              help="Beams per scan.")
@click.option("--fov", type=click.FloatRange(1, 360), default=180, show_default=True,
              help="Field of view (degrees).")
@click.option("--max-range", type=click.FloatRange(min=0.5), default=8.0, show_default=True,
              help="Laser max range (metres).")
@click.option("--range-noise", type=click.FloatRange(min=0), default=0.01, show_default=True,
              help="Range noise standard deviation (metres).")
@click.option("--record", type=click.Choice(["flaser", "robotlaser1"]), default="flaser",
              show_default=True, help="Carmen laser record to write (with ODOM lines).")
@click.option("--format", "log_format", default="carmen", show_default=True,
              type=click.Choice(["carmen", "player", "rosbag1", "rosbag2", "rosbag2-mcap",
                                 "mcap"]),
              help="Log format: Carmen text, Player 0.3 text, ROS1 .bag, ROS2 bag folder "
                   "(sqlite3 or mcap storage), or a plain MCAP file of ROS1 messages.")
@click.option("--sessions", type=click.IntRange(1, 50), default=1, show_default=True,
              help="Runs of the same world, a day apart: five fixtures stand in it, and three "
                   "change between one session and the next (one taken away, one moved, one "
                   "brought in); boxes stand still. Written to session1/, session2/, ...")
@click.option("--force", is_flag=True, help="Replace an existing output folder.")
def simulate(world: str, output: Path, duration: float, rate: float, seed: int,
             odometry_noise: float, walkers: int | None, stop_and_go: float, beams: int,
             fov: float, max_range: float, range_noise: float, record: str, log_format: str,
             sessions: int, force: bool) -> None:
    """Simulate a dynamic WORLD and write its log plus the ground truth.

    \b
    Worlds (after the paper, Sec. 5):
      corridors  corridor ring; two boxes moved 20 times, always out of view
      arena      12 m room with pillars; boxes moved 20 times in front of the robot
      hall       19 m × 11 m hall, 2-10 walking robots, boxes moved out of view
      crowd      14 m × 10 m open space, three people walking round the robot
      office     50 m corridor into a 24 m hall: few corners (hard); a box moved
      wards      corridor ring with a door every 4 m: look-alike places (hard)

    \b
    Examples:
      dynslam simulate corridors -o sim/corridors --duration 900 --seed 1
      dynslam simulate hall -o sim/hall --walkers 8 --odometry-noise 0
      dynslam simulate crowd -o sim/crowd && dynslam process sim/crowd/crowd.log

    \b
    Two days in the hall: place the second in the first's map, score what changed:
      dynslam simulate hall -o sim/days --sessions 2
      dynslam process sim/days/session1/hall.log -o day1
      dynslam process sim/days/session2/hall.log -o day2 --prior day1
      dynslam evaluate day2 --truth sim/days/session2/truth.json
    Each later session starts elsewhere on the route, with its odometry at 0,0,0; its
    truth.json lists the fixtures' changes (prior_changes) in the first session's frame.
    """

    def work() -> None:
        from dynslam_cli.simulate import (
            LaserModel,
            OdometryNoise,
            build_world,
            furnish,
            next_session,
        )
        from dynslam_cli.simulate import simulate as run_simulation
        from dynslam_cli.types import Pose2D
        from dynslam_formats.outdir import atomic_output_dir
        from dynslam_formats.simlogs import stamp_offset, write_simulated
        from dynslam_formats.truth import write_truth

        laser = LaserModel(beams=beams, fov_deg=fov, max_range_m=max_range, noise_m=range_noise)
        noise = OdometryNoise().scaled(odometry_noise)
        the_world = build_world(world, seed, walkers)
        for walker in the_world.walkers:
            walker.pause_s = stop_and_go
        spots = furnish(the_world, seed) if sessions > 1 else []
        name = f"{world}{LOG_NAMES[log_format]}"
        with atomic_output_dir(output, force, ours=_simulated) as tmp:
            for k in range(1, sessions + 1):
                changes = next_session(the_world, spots, k, seed) if k > 1 else []
                steps, truth = run_simulation(the_world, duration, rate, seed + k - 1, laser,
                                              noise, None if k == 1 else Pose2D(0, 0, 0))
                truth.session, truth.prior_changes = k, changes
                folder = tmp if sessions == 1 else tmp / f"session{k}"
                folder.mkdir(exist_ok=True)
                n = write_simulated(log_format, folder / name, steps, laser, record, world)
                truth.stamp_offset_s = stamp_offset(log_format)
                write_truth(folder / "truth.json", truth)
                where = output if sessions == 1 else output / f"session{k}"
                click.echo(f"dynslam: {n} scans, {len(truth.events)} relocations, "
                           f"{len(changes)} fixtures changed → {where}", err=True)
                click.echo(str(where / name))

    _guarded(work)


@main.command()
@click.argument("target", type=click.Path(path_type=Path))
@click.option("--truth", type=click.Path(path_type=Path),
              help="truth.json from 'dynslam simulate' (TARGET is an output folder).")
@click.option("--relations", type=click.Path(path_type=Path),
              help="Kümmerle et al. relations file (TARGET is a folder or a .tum file).")
@click.option("--relations-frame", "frame", metavar="X,Y", default="0,0",
              callback=lambda _c, _p, v: _point(v), show_default=True,
              help="Where on the robot the relations' poses are, metres in the "
                   "trajectory's frame (the laser's mount, if they are of the laser).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
def evaluate(target: Path, truth: Path | None, relations: Path | None,
             frame: tuple[float, float], as_json: bool) -> None:
    """Score an output folder (or trajectory) against ground truth.

    \b
    With --truth: trajectory ATE after SE(2) alignment (and raw odometry's), static map
    precision / recall / ghost rate, dynamic map precision, moved objects detected, vacated
    places cleared, landmarks on true corners; change events (changes.csv) matched to the
    true ones within 0.3 m: precision and recall of appeared and vacated, moving tracks in
    the walkers' loops. For a later session (simulate --sessions) run with --prior: its
    trajectory's error in the prior's frame (not aligned), and removed_since_prior and
    added_since_prior against the fixtures changed since the session before.
    With --relations: the Kümmerle et al. (2009) relation metric (translational m,
    rotational deg, mean ± std, plus squared errors and matched/unmatched counts), and
    fitted_frame: the point on the robot whose relations match best, and the error there
    (a relations file of another frame than the trajectory's shows as a large offset:
    give it with --relations-frame if it is known).

    \b
    Examples:
      dynslam evaluate hall_dynslam --truth samples/hall/truth.json
      dynslam evaluate mit_dynslam/trajectory.tum --relations mit-csail.relations --json
    """
    if truth is None and relations is None:
        raise click.UsageError("give --truth or --relations")

    def work() -> None:
        import json

        from dynslam_cli.job import score_output

        report = score_output(target, truth, relations, frame)
        if as_json:
            click.echo(json.dumps(report, indent=2, sort_keys=True))
        else:
            click.echo(_table(report))

    _guarded(work)


def _simulated(folder: Path) -> bool:
    """Whether ``folder`` is what ``dynslam simulate`` wrote (with or without --sessions)."""
    from dynslam_formats.outdir import is_simulation

    return is_simulation(folder) or is_simulation(folder / "session1")


def _point(text: str) -> tuple[float, ...]:
    """"X,Y" (metres) as two finite floats; else click's usage error."""
    return _numbers(text, 2, "X,Y (two numbers, metres)")


def _numbers(text: str, count: int, form: str) -> tuple[float, ...]:
    """``count`` comma-separated finite numbers; else click's usage error saying they must
    be ``form``."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(map(math.isfinite, values)):
        raise click.BadParameter(f"{text!r} is not {form}")
    return values


def _table(report: dict[str, Any], indent: str = "") -> str:
    """Nested dict → aligned 'key  value' lines."""
    lines = []
    for key, value in report.items():
        if isinstance(value, dict) and not value:
            lines.append(f"{indent}{key:<{max(1, 30 - len(indent))}} none")
        elif isinstance(value, dict):
            lines.append(f"{indent}{key}")
            lines.append(_table(value, indent + "  "))
        else:
            if isinstance(value, float):
                value = f"{value:.4f}"
            elif value is None:
                value = "n/a"
            lines.append(f"{indent}{key:<{max(1, 30 - len(indent))}} {value}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
