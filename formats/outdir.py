"""The output folder contract, written atomically.

Everything goes into a hidden temporary folder beside the target, which is renamed into place
only when complete: a failed or interrupted run leaves no half-written map behind.
"""

from __future__ import annotations

import errno
import glob
import json
import os
import shutil
import socket
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from dynslam_cli.errors import OutputError
from dynslam_cli.result import SlamResult
from dynslam_cli.sections import MapConfig
from dynslam_formats.changes import write_changes
from dynslam_formats.landmarks import write_landmarks
from dynslam_formats.mapfile import write_map
from dynslam_formats.picture import write_picture
from dynslam_formats.tum import evo_ready, write_tum

OUTPUT_FILES = ("static.pgm", "static.yaml", "static_prob.png", "static_prob.yaml",
                "dynamic.pgm", "dynamic.yaml", "map.png", "landmarks.csv", "changes.csv",
                "trajectory.tum", "summary.json")


def check_target(target: Path, force: bool, log: str | None = None,
                 ours: Callable[[Path], bool] | None = None) -> None:
    """Refuse an output folder that would hurt the user: an existing one unless ``force``,
    and even then only dynslam's own (``ours``, by default: it holds dynslam's
    summary.json); never the current folder or one that holds it, the root, or a folder that
    holds the input log."""
    where = target.resolve()
    here = Path.cwd().resolve()
    if where == here or where in here.parents:  # (the root holds every folder)
        raise OutputError(f"{target}: will not write over the current folder or one that "
                          "holds it; name a new folder with -o")
    if log is not None and log != "-" and where in Path(log).resolve().parents:
        raise OutputError(f"{target}: holds the input log {log}; name another folder with -o")
    if target.is_symlink():
        raise OutputError(f"{target}: is a symbolic link; name the folder itself with -o")
    if not target.exists():
        return
    if not target.is_dir():  # (--force would not help: it replaces only folders)
        raise OutputError(f"{target}: exists and is not a folder; name a folder with -o")
    if not force:
        raise OutputError(f"{target}: output folder exists; use --force to replace it")
    if not (ours or is_dynslam_output)(target):
        raise OutputError(f"{target}: not a folder dynslam wrote; --force replaces only "
                          "dynslam's own output")


def is_dynslam_output(folder: Path) -> bool:
    """Whether ``folder`` holds a summary.json that dynslam wrote."""
    summary = _json(folder / "summary.json")
    tool = summary.get("tool") if isinstance(summary, dict) else None
    return isinstance(tool, dict) and tool.get("name") == "dynslam"


def is_simulation(folder: Path) -> bool:
    """Whether ``folder`` holds a truth.json that ``dynslam simulate`` wrote."""
    truth = _json(folder / "truth.json")
    return isinstance(truth, dict) and {"world", "walls", "poses", "hits"} <= truth.keys()


def with_umask(mode: int) -> int:
    """``mode`` as the user's umask lets an ordinary new file or folder have it (mkstemp and
    mkdtemp make theirs private)."""
    umask = os.umask(0)
    os.umask(umask)
    return mode & ~umask


def _json(path: Path) -> object:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


WRITE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS)  # writing failed
OWNER_FILE = ".dynslam-run"  # in a temporary folder while a run writes it: "pid host"


def _owner_gone(folder: Path) -> bool:
    """Whether the run that made this temporary folder has ended (killed, power cut): its
    owner file names a process of this host that no longer exists, or it has no owner file
    and holds nothing but output files (from before owner files, or killed at its birth)."""
    try:
        pid, host = (folder / OWNER_FILE).read_text(encoding="utf-8").split()
    except FileNotFoundError:
        allowed = {*OUTPUT_FILES, "snapshots", "truth.json"}
        return all(p.name in allowed or p.suffix in (".log", ".bag", ".mcap", ".db3")
                   for p in folder.iterdir())
    except (OSError, ValueError):
        return False
    if host != socket.gethostname():
        return False  # another machine's (shared storage): not ours to judge
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except (OSError, ValueError):
        return False
    return False


def clean_stale(target: Path) -> list[Path]:
    """Remove the temporary folders an interrupted run of ``target`` left beside it
    (``.NAME.XXXX.partial``, ``.NAME.XXXX.old``) whose run has ended; returns them."""
    parent = target.absolute().parent
    removed = []
    for folder in sorted(parent.glob(f".{glob.escape(target.name)}.*.partial")):
        if folder.is_dir() and not folder.is_symlink() and _owner_gone(folder):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    for trash in sorted(parent.glob(f".{glob.escape(target.name)}.*.old")):
        inner = trash / target.name
        if (trash.is_dir() and not trash.is_symlink()
                and [p.name for p in trash.iterdir()] == [target.name]
                and (is_dynslam_output(inner) or is_simulation(inner))):
            shutil.rmtree(trash, ignore_errors=True)
            removed.append(trash)
    return removed


@contextmanager
def atomic_output_dir(target: Path, force: bool, log: str | None = None,
                      ours: Callable[[Path], bool] | None = None) -> Iterator[Path]:
    """Yield a temporary folder; on success it replaces ``target``, on failure it vanishes.
    ``log`` (the input) and ``ours`` as for :func:`check_target`."""
    check_target(target, force, log, ours)
    parent = target.absolute().parent
    made = [p for p in (parent, *parent.parents) if not p.exists()]  # to remove on failure
    tmp = None
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stale = clean_stale(target)
        if stale:
            sys.stderr.write(f"dynslam: removed {len(stale)} temporary folder(s) an interrupted "
                             f"run of {target} left behind\n")
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=parent))
        (tmp / OWNER_FILE).write_text(f"{os.getpid()} {socket.gethostname()}\n",
                                      encoding="utf-8")
        tmp.chmod(with_umask(0o777))
    except OSError as e:
        _undo(tmp, made)
        raise OutputError(f"{target}: cannot create output folder: {e.strerror}") from None
    try:
        yield tmp
        (tmp / OWNER_FILE).unlink()
        check_target(target, force, log, ours)
        try:
            if target.exists():
                trash = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old",
                                              dir=parent))
                os.replace(target, trash / target.name)
                os.replace(tmp, target)
                shutil.rmtree(trash, ignore_errors=True)
            else:
                os.replace(tmp, target)
        except OSError as e:
            raise OutputError(f"{target}: cannot put the output in place: {e.strerror}"
                              ) from None
    except OSError as e:
        _undo(tmp, made)
        if e.errno in WRITE_ERRNOS or str(e.filename or "").startswith(str(tmp)):
            raise OutputError(f"{target}: cannot write the output: {e.strerror}") from None
        raise
    except BaseException:
        _undo(tmp, made)
        raise


def recording_destination(name: str, target: Path) -> Path | None:
    """Where ``--record NAME`` goes: None for a bare file name (into the output folder
    ``target``, with the other files), else the path itself, ``~`` expanded (a path into
    ``target`` is that bare name)."""
    path = Path(name).expanduser()
    if path.name == name or path.absolute().parent == target.absolute():
        return None
    return path


def is_dynslam_recording(path: Path) -> bool:
    """Whether ``path`` is an MCAP file dynslam wrote (its header names the library)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            return make_reader(f).get_header().library.startswith("dynslam ")
    except Exception:  # anything unreadable is not ours
        return False


@contextmanager
def atomic_output_file(target: Path, force: bool, log: str | None = None) -> Iterator[Path]:
    """Yield a temporary file beside ``target``; on success it replaces ``target``, on
    failure it vanishes, with the folders made for it. An existing ``target`` is refused
    unless ``force``, and even then unless dynslam wrote it (a recording); the input log
    never."""
    if log is not None and log != "-" and target.resolve() == Path(log).resolve():
        raise OutputError(f"{target}: is the input log; name another file")
    if target.is_dir():
        raise OutputError(f"{target}: is a folder; name a file")
    if target.exists() and not force:
        raise OutputError(f"{target}: exists; use --force to replace it")
    if target.exists() and not is_dynslam_recording(target):
        raise OutputError(f"{target}: not a recording dynslam wrote; --force replaces only "
                          "dynslam's own")
    parent = target.absolute().parent
    made = [p for p in (parent, *parent.parents) if not p.exists()]
    tmp = None
    try:
        parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".partial", dir=parent)
        os.close(fd)
        tmp = Path(name)
        yield tmp
        tmp.chmod(with_umask(0o666))
        os.replace(tmp, target)
    except OSError as e:
        _undo_file(tmp, made)
        raise OutputError(f"{target}: cannot write: {e.strerror}") from None
    except BaseException:
        _undo_file(tmp, made)
        raise


def _undo_file(tmp: Path | None, made: list[Path]) -> None:
    if tmp is not None:
        tmp.unlink(missing_ok=True)
    _undo(None, made)


def _undo(tmp: Path | None, made: list[Path]) -> None:
    """Remove the temporary folder and the parent folders this run created (if empty)."""
    if tmp is not None:
        shutil.rmtree(tmp, ignore_errors=True)
    for folder in made:  # innermost first
        try:
            folder.rmdir()
        except OSError:
            break


def write_results(folder: Path, result: SlamResult, m: MapConfig,
                  summary: dict[str, Any]) -> None:
    """Write every file of the output contract into ``folder``, the maps by ``m``'s
    thresholds (an OSError, such as a full disk, becomes an :class:`OutputError` in
    :func:`atomic_output_dir`)."""
    write_map(folder, "static", result.static, m.free_threshold, m.occupied_threshold,
              probabilities=True)
    write_map(folder, "dynamic", result.dynamic, m.free_threshold, m.occupied_threshold)
    summary.setdefault("map", {})["picture_pixels_per_cell"] = write_picture(
        folder / "map.png", result.static, result.dynamic, result.trajectory, result.landmarks,
        m.occupied_threshold, result.changes)
    with open(folder / "landmarks.csv", "w", encoding="utf-8", newline="") as f:
        write_landmarks(f, result.landmarks)
    with open(folder / "changes.csv", "w", encoding="utf-8", newline="") as f:
        write_changes(f, result.changes)
    with open(folder / "trajectory.tum", "w", encoding="utf-8", newline="\n") as f:
        write_tum(f, evo_ready(result.trajectory))
    (folder / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n",
                                         encoding="utf-8")
